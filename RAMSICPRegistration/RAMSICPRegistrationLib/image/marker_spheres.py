"""Automatic marker-sphere centres in the CT (the paper places them by hand and names that its main error).

Candidates are the bright islands of the segmentation whose volume and shape fit an 11.5 mm sphere. Each is
fitted by least squares to its own half-maximum iso-surface (the level half-way between the sphere and what
surrounds it, so blur does not bias it), with outlier rejection, and given a status:

* ``ok``: radius within 0.6 mm of the nominal, RMS residual under 0.2 mm, at least 85 % of its surface seen;
* ``partial``: part of the surface is missing (Fig. 4a's defects): the centre rests on the part that remains;
* ``deformed``: the radius or the residual is off: the sphere is not round in the image.

Only ``ok`` spheres feed the coarse registration unless the user accepts the others. Detected centres are put
in the order of the tool's markers by their distances (``order_to_tool``).
"""

import itertools
import logging
from dataclasses import dataclass

import numpy as np
from scipy import ndimage, optimize

from ..core.paired_point import rigid_procrustes
from ..core.transforms import apply_transform
from ..io.ndi_tools import MARKER_DIAMETER_MM
from .ct_segmentation import iso_surface

logger = logging.getLogger(__name__)

RADIUS_TOLERANCE_MM = 0.6
RESIDUAL_LIMIT_MM = 0.2
COVERAGE_LIMIT = 0.85


@dataclass(frozen=True)
class MarkerSphere:
    """One fitted sphere: centre (3,) RAS mm, radius and RMS residual (mm), surface coverage (0..1), status.

    ``label`` is its connected component in the BoneSegmentation's labels.
    """

    centre: np.ndarray
    radius_mm: float
    residual_mm: float
    coverage: float
    status: str
    surface_points: int
    label: int

    def to_dict(self):
        return {
            "centre": self.centre.tolist(),
            "radius_mm": self.radius_mm,
            "residual_mm": self.residual_mm,
            "coverage": self.coverage,
            "status": self.status,
            "surface_points": self.surface_points,
        }


@dataclass(frozen=True)
class MarkerDetection:
    """All sphere candidates found, and the warnings about them."""

    spheres: tuple
    warnings: tuple

    @property
    def ok_centres(self):
        """(K, 3) centres of the spheres with status 'ok'."""
        return np.array([sphere.centre for sphere in self.spheres if sphere.status == "ok"]).reshape(-1, 3)


def detect_marker_spheres(volume, segmentation, expected=4, diameter_mm=MARKER_DIAMETER_MM):
    """Find and fit the marker spheres among the segmentation's non-bone objects.

    Returns:
        MarkerDetection; its warnings say when fewer or more than ``expected`` spheres were found, or when a
        sphere is partial or deformed, and what to do.
    """
    radius = diameter_mm / 2.0
    nominal_volume = 4.0 / 3.0 * np.pi * radius**3
    voxel_mm3 = float(np.prod(volume.spacing))
    spheres, rejected = [], 0
    slices = ndimage.find_objects(segmentation.labels)
    for label in segmentation.object_labels:
        region = slices[label - 1]
        mask = segmentation.labels[region] == label
        size_mm3 = mask.sum() * voxel_mm3
        if not 0.3 * nominal_volume <= size_mm3 <= 2.0 * nominal_volume or _elongation(mask, volume) > 1.8:
            rejected += 1
            continue
        spheres.append(_fit_candidate(volume, segmentation, label, region, radius))
    warnings = []
    for sphere in spheres:
        if sphere.status != "ok":
            warnings.append(
                f"the sphere at ({', '.join(f'{v:.1f}' for v in sphere.centre)}) mm is {sphere.status}: "
                f"radius {sphere.radius_mm:.2f} mm, residual {sphere.residual_mm:.2f} mm, "
                f"{100 * sphere.coverage:.0f} % of its surface seen; check it in the CT and move its "
                "centre by hand, or leave it out of the coarse registration"
            )
    good = sum(sphere.status == "ok" for sphere in spheres)
    if len(spheres) != expected:
        warnings.append(
            f"found {len(spheres)} marker-sphere candidates ({rejected} other objects rejected by size or "
            f"shape), expected {expected}: check that the reference body is in the field of view and the "
            "threshold is below the spheres' brightness, or place the missing centres by hand"
        )
    elif good < expected:
        warnings.append(f"only {good} of {expected} spheres are clean; the coarse registration needs at least 3")
    for warning in warnings:
        logger.info("marker detection: %s", warning)
    return MarkerDetection(spheres=tuple(spheres), warnings=tuple(warnings))


def fit_sphere(points, inlier_limit_mm=0.1):
    """Least-squares sphere through (N, 3) points, robust to a missing or added part of the surface.

    An algebraic fit starts a geometric fit with a Cauchy loss (scale ``inlier_limit_mm``); points within
    3 robust standard deviations (at least ``inlier_limit_mm``) are the inliers, and a plain least-squares fit
    on them gives the result.

    Returns:
        centre (3,), radius (mm), RMS residual of the inliers (mm), and the boolean inlier mask (N,).
    """
    centre, radius = _algebraic_fit(points)
    robust = optimize.least_squares(
        lambda p: np.linalg.norm(points - p[:3], axis=1) - p[3],
        np.append(centre, radius),
        loss="cauchy",
        f_scale=inlier_limit_mm,
    )
    residuals = np.linalg.norm(points - robust.x[:3], axis=1) - robust.x[3]
    spread = 1.4826 * np.median(np.abs(residuals - np.median(residuals)))
    keep = np.abs(residuals) <= max(3.0 * spread, inlier_limit_mm)
    refined = optimize.least_squares(
        lambda p: np.linalg.norm(points[keep] - p[:3], axis=1) - p[3], robust.x, method="lm"
    )
    centre, radius = refined.x[:3], abs(refined.x[3])
    rms = float(np.sqrt(np.mean((np.linalg.norm(points[keep] - centre, axis=1) - radius) ** 2)))
    return centre, float(radius), rms, keep


def order_to_tool(centres, tool_markers):
    """Order detected centres (K, 3) like the tool's markers (K, 3) by trying every pairing.

    Returns:
        (permutation, fre_mm): ``centres[permutation]`` pairs with ``tool_markers``; the FRE of that pairing.
    """
    if len(centres) != len(tool_markers):
        raise ValueError(f"{len(centres)} centres for {len(tool_markers)} tool markers; detect or place them all")
    best = (None, np.inf)
    for permutation in itertools.permutations(range(len(centres))):
        ordered = centres[list(permutation)]
        fitted = apply_transform(rigid_procrustes(tool_markers, ordered), tool_markers)
        fre = float(np.sqrt(np.mean(np.sum((fitted - ordered) ** 2, axis=1))))
        if fre < best[1]:
            best = (np.array(permutation), fre)
    return best


def _elongation(mask, volume):
    coordinates = np.argwhere(mask) * volume.spacing
    eigenvalues = np.linalg.eigvalsh(np.cov(coordinates.T))
    return float(np.sqrt(eigenvalues[-1] / max(eigenvalues[0], 1e-9)))


def _fit_candidate(volume, segmentation, label, region, radius):
    pad = 4
    low = np.array([max(s.start - pad, 0) for s in region])
    high = np.array([min(s.stop + pad, n) for s, n in zip(region, segmentation.labels.shape)])
    box = tuple(slice(a, b) for a, b in zip(low, high))
    image = segmentation.smoothed[box].copy()
    mask = segmentation.labels[box] == label
    core = ndimage.binary_erosion(mask, iterations=2)
    shell = ndimage.binary_dilation(mask, iterations=4) & ~ndimage.binary_dilation(mask, iterations=2)
    inside = float(np.median(image[core])) if core.any() else float(image[mask].max())
    outside = float(np.median(image[shell]))
    level = 0.5 * (inside + outside)
    image[~ndimage.binary_dilation(mask, iterations=2)] = outside  # neighbours in the box add no surface
    vertices, _ = iso_surface(image, level)
    points = volume.ijk_to_ras_points(vertices + low)
    centre, fitted_radius, rms, keep = fit_sphere(points)
    coverage = _coverage(points[keep] - centre)
    outlier_side = np.median(np.linalg.norm(points[~keep] - centre, axis=1) - fitted_radius) if (~keep).any() else 0.0
    if abs(fitted_radius - radius) <= RADIUS_TOLERANCE_MM and rms <= RESIDUAL_LIMIT_MM and coverage >= COVERAGE_LIMIT:
        status = "ok"
    elif abs(fitted_radius - radius) <= RADIUS_TOLERANCE_MM and rms <= RESIDUAL_LIMIT_MM and outlier_side < 0:
        status = "partial"  # what does not fit lies inside the sphere: a part of it is missing
    else:
        status = "deformed"
    return MarkerSphere(
        centre=centre,
        radius_mm=fitted_radius,
        residual_mm=rms,
        coverage=coverage,
        status=status,
        surface_points=int(keep.sum()),
        label=int(label),
    )


def _algebraic_fit(points):
    # |p|^2 = 2 c.p + (r^2 - |c|^2) is linear in c and the constant.
    design = np.hstack((2.0 * points, np.ones((len(points), 1))))
    solution, *_ = np.linalg.lstsq(design, np.sum(points**2, axis=1), rcond=None)
    centre = solution[:3]
    return centre, float(np.sqrt(max(solution[3] + centre @ centre, 1e-12)))


def _coverage(offsets, directions=200, cone_deg=20.0):
    """Fraction of evenly spread directions from the centre that have a surface point within ``cone_deg``."""
    index = np.arange(directions) + 0.5
    polar = np.arccos(1.0 - 2.0 * index / directions)
    azimuth = np.pi * (1.0 + 5.0**0.5) * index
    unit = np.column_stack((np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)))
    offsets = offsets / np.linalg.norm(offsets, axis=1, keepdims=True)
    return float(np.mean(np.max(unit @ offsets.T, axis=1) >= np.cos(np.radians(cone_deg))))
