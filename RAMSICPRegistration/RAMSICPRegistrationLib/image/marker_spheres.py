"""Automatic marker-sphere centres in the CT (the paper places them by hand and names that its main error).

Real reference bodies often have posts and a frame as bright in CT as the spheres (dense polymer, aluminium), so
spheres, posts and frame form one bright object. Detection therefore does not ask for isolated spheres:

1. **Candidates: where a ball fits.** In every bright object other than the bone, the distance of each voxel
   to the object's edge (Euclidean distance transform, mm) peaks at a sphere's centre with the sphere's radius;
   posts and frame are thinner and peak lower. Local peaks from ``CANDIDATE_DEPTH`` of the radius (a sphere with
   a missing cap still holds a ball that large) to ``CANDIDATE_EXCESS_MM`` above it are candidates, deepest
   first, one per sphere-sized neighbourhood: the erosion half of a morphological opening by a ball, whose
   reconstruction the fit below replaces. The distance map is taken on a grid of about ``CANDIDATE_GRID_MM``
   (the fit refines the centre). A rod's peaks are candidates too, and the fit rejects them. An object cut by
   the edge of the field of view has no edge there, so a cut sphere is still found, and then flagged. A matched
   filter (FFT correlation with a ball-minus-shell template) found the same spheres on every reference body of
   ``benchmarks/bench_marker_candidates.py`` in twice the time. Spheres joined to the bone itself (by a
   bright bracket) are not looked for: the bone's object is left out.
2. **Fit on the sphere's own surface.** Around a candidate, the half-maximum iso-surface (the level half-way
   between the sphere's core and its surroundings, both measured there, so blur does not bias it) gives sub-voxel
   edge points. Only points within ``SHELL_WINDOW_MM`` of the sphere and whose outward normal points away from the
   centre (within ``NORMAL_LIMIT_DEG``) are kept: the post's stub and the frame leave, as their surfaces run
   across the radius. A robust sphere fit (``fit_sphere``) on those points, repeated from the new centre, gives
   the centre, the radius and the residual.
3. **Status**, for every sphere:

   * ``ok``: radius within 0.6 mm of the nominal, RMS residual under 0.2 mm, at least 85 % of its surface seen,
     and wholly inside the field of view;
   * ``partial``: part of the surface is missing (Fig. 4a's defects, or cut by the field of view): its centre
     rests on what remains;
   * ``deformed``: the radius or the residual is off: the sphere is not round in the image.

   A candidate whose fit is far from any sphere (radius off by more than ``NOT_A_SPHERE_MM``, or less than
   ``MIN_COVERAGE`` of a surface) is not a marker and is dropped.

Only ``ok`` spheres feed the coarse registration unless the user accepts the others. Centres are paired with the
tool's markers by their distances (``order_to_tool``, ``match_to_tool``); markers are numbered from 1.
"""

import itertools
import logging
from dataclasses import dataclass, replace

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
#: A candidate centre lies at least this fraction of r deep in its bright object: a sphere whose cap is missing
#: down to near its centre (the phantom's partial sphere, or one cut by the field of view) still holds such a ball.
CANDIDATE_DEPTH = 0.45
#: ... and at most r + this (mm); deeper points lie in something thicker than a sphere.
CANDIDATE_EXCESS_MM = 1.5
#: The distance map is computed on a grid about this fine (mm), whatever the CT's voxels: the fit refines.
CANDIDATE_GRID_MM = 1.0
#: An object whose bounding box holds fewer voxels than this fraction of a sphere is too small to be one.
MIN_SPHERE_VOLUME = 0.3
#: Inside a marker sphere, at 0.75 r from its centre, at least this fraction is bright, even with a cap missing
#: (0.46 for a hemisphere); around a 6 mm rod about 0.35. A cheap look that spares the fit most rods.
FILLED_INSIDE = 0.4
#: Around a marker sphere, 2 mm beyond its surface, only its post and perhaps the frame are bright: a candidate
#: whose surroundings are brighter than this fraction lies inside something bigger (a bone fragment, a vessel).
CLEAR_AROUND = 0.5
#: Edge points farther than this from the sphere's surface (mm) are not the sphere's.
SHELL_WINDOW_MM = 1.5
#: Edge points whose outward normal turns more than this from the radial direction are posts or frame.
NORMAL_LIMIT_DEG = 30.0
#: A fit whose radius is off by more than this (mm), or that sees less than MIN_COVERAGE, is not a marker sphere
#: (rods of the frame fit spheres about 1.5 mm too small; the phantom's deformed sphere is 0.4 mm too large).
NOT_A_SPHERE_MM = 1.0
MIN_COVERAGE = 0.35
STATUSES = ("ok", "partial", "deformed")


@dataclass(frozen=True)
class MarkerSphere:
    """One fitted sphere: centre (3,) RAS mm, radius and RMS residual (mm), surface coverage (0..1), status.

    ``note`` says in words why a sphere is not ``ok``; ``label`` is the label of its voxels in the
    BoneSegmentation's labels (the bright object it belongs to, or its own voxels after ``label_sphere_voxels``);
    ``number`` is the tool marker it was paired with (1-based; 0 until paired, or when it cannot be).
    """

    centre: np.ndarray
    radius_mm: float
    residual_mm: float
    coverage: float
    status: str
    surface_points: int
    label: int
    note: str = ""
    number: int = 0

    def to_dict(self):
        return {
            "number": self.number,
            "centre": self.centre.tolist(),
            "radius_mm": self.radius_mm,
            "residual_mm": self.residual_mm,
            "coverage": self.coverage,
            "status": self.status,
            "note": self.note,
            "surface_points": self.surface_points,
        }


@dataclass(frozen=True)
class MarkerDetection:
    """All marker spheres found, the number of other candidates rejected, and the warnings about them."""

    spheres: tuple
    warnings: tuple
    rejected: int = 0

    @property
    def ok_centres(self):
        """(K, 3) centres of the spheres with status 'ok'."""
        return np.array([sphere.centre for sphere in self.spheres if sphere.status == "ok"]).reshape(-1, 3)


def detect_marker_spheres(volume, segmentation, expected=4, diameter_mm=MARKER_DIAMETER_MM):
    """Find and fit the marker spheres in the segmentation's bright objects other than the bone.

    Args:
        volume: the CTVolume that was segmented (its geometry).
        segmentation: BoneSegmentation (its ``smoothed`` image and object labels).
        expected: how many spheres the reference body has.
        diameter_mm: the spheres' diameter.

    Returns:
        MarkerDetection; its warnings say when fewer or more than ``expected`` spheres were found, or when a
        sphere is partial or deformed, and what to do.
    """
    radius = diameter_mm / 2.0
    spheres, rejected = [], 0
    for centre, label, plausible in _candidates(volume, segmentation, radius):
        sphere = _fit_candidate(volume, segmentation.smoothed, centre, radius, label) if plausible else None
        if sphere is None:
            rejected += 1
        else:
            spheres.append(sphere)
    spheres = _without_duplicates(spheres, radius)
    warnings = [sphere_warning(sphere) for sphere in spheres if sphere.status != "ok"]
    good = sum(sphere.status == "ok" for sphere in spheres)
    if len(spheres) != expected:
        warnings.append(
            f"found {len(spheres)} marker-sphere candidates ({rejected} other bright spots rejected by their "
            f"shape), expected {expected}: check that the reference body is in the field of view and the "
            "threshold is below the spheres' brightness, or place the missing centres by hand"
        )
    elif good < expected:
        warnings.append(f"only {good} of {expected} spheres are clean; the coarse registration needs at least 3")
    for warning in warnings:
        logger.info("marker detection: %s", warning)
    return MarkerDetection(spheres=tuple(spheres), warnings=tuple(warnings), rejected=rejected)


def sphere_warning(sphere):
    """What to tell the user about a sphere that is not ``ok``: which one, what is wrong, what to do."""
    where = f"({', '.join(f'{v:.1f}' for v in sphere.centre)}) mm"
    name = f"marker {sphere.number} at {where}" if sphere.number else f"the sphere at {where}"
    return (
        f"{name} is {sphere.status}: {sphere.note}; check it in the CT and move its centre by hand, or leave it "
        "out of the coarse registration"
    )


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


def match_to_tool(centres, tool_markers, usable=None, max_distance_mm=3.0):
    """Which tool marker each detected centre is, when some are missing or flagged.

    The usable centres (all when ``usable`` is None), if there are at least 3, are paired with the tool's markers
    by trying every assignment (the smallest FRE wins); with fewer, all centres are. The others then take the
    free marker nearest to them under that pairing's transform, if within ``max_distance_mm``.

    Args:
        centres: (K, 3) detected centres, K <= number of tool markers.
        tool_markers: (N, 3) the tool's marker geometry.
        usable: optional (K,) booleans.

    Returns:
        (numbers, fre_mm): (K,) tool marker numbers (1-based; 0 where unknown) and the FRE of the pairing
        (None when fewer than 3 centres could be paired: then every number is 0).
    """
    centres = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    tool_markers = np.asarray(tool_markers, dtype=np.float64)
    usable = np.ones(len(centres), dtype=bool) if usable is None else np.asarray(usable, dtype=bool)
    numbers = np.zeros(len(centres), dtype=int)
    basis = np.flatnonzero(usable) if usable.sum() >= 3 else np.arange(len(centres))
    if len(basis) < 3 or len(centres) > len(tool_markers):
        return numbers, None
    best = (None, np.inf, None)
    for assignment in itertools.permutations(range(len(tool_markers)), len(basis)):
        chosen = tool_markers[list(assignment)]
        transform = rigid_procrustes(chosen, centres[basis])
        fre = float(np.sqrt(np.mean(np.sum((apply_transform(transform, chosen) - centres[basis]) ** 2, axis=1))))
        if fre < best[1]:
            best = (assignment, fre, transform)
    assignment, fre, transform = best
    numbers[basis] = np.array(assignment) + 1
    predicted = apply_transform(transform, tool_markers)
    for index in np.setdiff1d(np.arange(len(centres)), basis):
        free = [m for m in range(len(tool_markers)) if m + 1 not in numbers]
        distances = np.linalg.norm(predicted[free] - centres[index], axis=1)
        if len(free) and distances.min() <= max_distance_mm:
            numbers[index] = free[int(np.argmin(distances))] + 1
    return numbers, fre


def sphere_values(spheres):
    """Labelmap value of each sphere: 1 + n for marker n, then the spheres not paired with a marker (2 + the
    highest marker number, ...); 1 is the bone."""
    count = max([sphere.number for sphere in spheres] + [0])
    values = []
    for sphere in spheres:
        count += 0 if sphere.number else 1
        values.append(1 + (sphere.number or count))
    return values


def sphere_labelmap(segmentation, spheres):
    """(I, J, K) labelmap: 1 for the bone, 1 + n for marker n's sphere (``sphere_values``)."""
    return segmentation.labelmap([sphere.label for sphere in spheres], sphere_values(spheres))


def label_sphere_voxels(volume, segmentation, spheres):
    """Give each sphere's own voxels a label of their own in ``segmentation.labels`` (in place), split from the
    posts and frame they touch, so a labelmap shows the spheres and not the whole reference body.

    A sphere that is its own connected component keeps its label. Returns the spheres with their labels.
    """
    labels = segmentation.labels
    next_label = int(labels.max()) + 1
    labelled = []
    for sphere in spheres:
        box, offsets = _box_offsets(volume, sphere.centre, sphere.radius_mm + 1.0)
        if box is None:
            labelled.append(sphere)
            continue
        ball = np.linalg.norm(offsets, axis=-1) <= sphere.radius_mm + 1.0
        local = labels[box]
        own = ball & (local == sphere.label)
        if own.sum() == np.count_nonzero(labels == sphere.label):
            labelled.append(sphere)
            continue
        local[own] = next_label
        labelled.append(replace(sphere, label=next_label))
        next_label += 1
    return tuple(labelled)


def _candidates(volume, segmentation, radius):
    """(centre (3,) RAS, object label, plausible) of every place in a non-bone object where a near-sphere-sized
    ball fits; ``plausible`` is False where a quick look (``_shaped_like_a_marker``) already rules a sphere out."""
    # The distance map needs no finer grid than about CANDIDATE_GRID_MM: the fit refines the centre.
    step = np.maximum(1, np.floor(CANDIDATE_GRID_MM / volume.spacing)).astype(int)
    spacing = volume.spacing * step
    slices = ndimage.find_objects(segmentation.labels)
    footprint = _ball_footprint(spacing, max(1.0, 1.5 * spacing.max()))  # at least the 18 nearest neighbours
    smallest = MIN_SPHERE_VOLUME * 4.0 / 3.0 * np.pi * radius**3 / float(np.prod(volume.spacing))  # voxels
    found = []
    for label in segmentation.object_labels:
        region = slices[label - 1]
        if np.prod([s.stop - s.start for s in region]) < smallest:
            continue  # even its bounding box cannot hold what is left of a sphere
        low = np.array([max(s.start - 2 * k, 0) for s, k in zip(region, step)])
        high = np.array([min(s.stop + 2 * k, n) for s, k, n in zip(region, step, segmentation.labels.shape)])
        box = tuple(slice(a, b, k) for a, b, k in zip(low, high, step))
        mask = segmentation.labels[box] == label
        # Padding gives the object background around it, except where it meets the edge of the field of view.
        depth = ndimage.distance_transform_edt(mask, sampling=spacing)
        if depth.max() < CANDIDATE_DEPTH * radius:
            continue
        peaks = (depth == ndimage.maximum_filter(depth, footprint=footprint)) & (depth >= CANDIDATE_DEPTH * radius)
        peaks &= depth <= radius + CANDIDATE_EXCESS_MM
        indices = np.argwhere(peaks)
        order = np.argsort(-depth[peaks], kind="stable")
        kept = []
        for index in indices[order]:
            centre = volume.ijk_to_ras_points((index * step + low)[None])[0]
            if all(np.linalg.norm(centre - other) > radius for other in kept):
                kept.append(centre)
        found.extend((c, label, _shaped_like_a_marker(volume, mask, low, step, c, radius)) for c in kept)
    return found


def _shaped_like_a_marker(volume, mask, low, step, centre, radius):
    """A cheap look before the fit: the candidate's object fills at least ``FILLED_INSIDE`` of a sphere of 0.75 r
    around it (a marker sphere does, even with a cap missing; a post or a frame rod does not), and at most
    ``CLEAR_AROUND`` of a sphere 2 mm outside r (a marker sphere has only its post there; a point deep inside a
    bigger object has its object all round)."""
    directions = _fibonacci_directions(100)
    shape = np.array(mask.shape)

    def filled(distance, outside_counts):
        index = np.rint((volume.ras_to_ijk_points(centre + distance * directions) - low) / step).astype(int)
        inside = np.all((index >= 0) & (index < shape), axis=1)
        hits = np.full(len(index), outside_counts)
        hits[inside] = mask[tuple(index[inside].T)]
        return hits.mean()

    # Beyond the crop there is the edge of the field of view or other objects: count it as the sphere inside
    # (a cut sphere), as clear outside.
    return filled(0.75 * radius, True) >= FILLED_INSIDE and filled(radius + 2.0, False) <= CLEAR_AROUND


def _ball_footprint(spacing, radius_mm):
    half = np.maximum(np.ceil(radius_mm / spacing).astype(int), 1)
    grid = np.stack(np.meshgrid(*[np.arange(-h, h + 1) for h in half], indexing="ij"), axis=-1) * spacing
    return np.linalg.norm(grid, axis=-1) <= radius_mm + 1e-9


def _box_offsets(volume, centre, half_mm):
    """Index box around an RAS point reaching ``half_mm`` in every direction, and the voxels' RAS offsets."""
    box, ras = volume.voxels_within(centre - half_mm, centre + half_mm)
    if box is None or min(s.stop - s.start for s in box) < 2:
        return None, None
    return box, ras - centre


def _fit_candidate(volume, smoothed, centre, radius, label):
    box, offsets = _box_offsets(volume, centre, radius + 3.5)
    if box is None:
        return None
    image = smoothed[box].astype(np.float64)
    distance = np.linalg.norm(offsets, axis=-1)
    core = distance <= radius - 2.0
    shell = (distance >= radius + 1.5) & (distance <= radius + 3.0)
    if not core.any() or not shell.any():
        return None
    level = 0.5 * (float(np.median(image[core])) + float(np.median(image[shell])))
    vertices, _ = iso_surface(image, level)
    if len(vertices) < 50:
        return None
    low = np.array([s.start for s in box])
    points = volume.ijk_to_ras_points(vertices + low)
    normals = _outward_normals(volume, image, vertices)
    selected = None
    for _ in range(3):
        previous = centre
        offsets_to_centre = points - centre
        distance_to_centre = np.linalg.norm(offsets_to_centre, axis=1)
        radial = offsets_to_centre / np.maximum(distance_to_centre, 1e-9)[:, None]
        selected = (np.abs(distance_to_centre - radius) <= SHELL_WINDOW_MM) & (
            np.einsum("ij,ij->i", radial, normals) >= np.cos(np.radians(NORMAL_LIMIT_DEG))
        )
        if selected.sum() < 50:
            return None
        centre, fitted_radius, rms, keep = fit_sphere(points[selected])
        if abs(fitted_radius - radius) > NOT_A_SPHERE_MM:
            return None
        if np.linalg.norm(centre - previous) < 0.01:
            break  # the window would select the same points again
    inliers = points[selected][keep]
    coverage = _coverage(inliers - centre)
    if coverage < MIN_COVERAGE:
        return None
    status, note = _status(volume, centre, radius, fitted_radius, rms, coverage)
    return MarkerSphere(
        centre=centre,
        radius_mm=fitted_radius,
        residual_mm=rms,
        coverage=coverage,
        status=status,
        surface_points=int(keep.sum()),
        label=int(label),
        note=note,
    )


def _status(volume, centre, radius, fitted_radius, rms, coverage):
    ijk = volume.ras_to_ijk_points(centre[None])[0]
    reach = (radius + 1.0) / volume.spacing + 1.0  # the sphere and its blurred edge, in voxels
    if (ijk - reach < 0).any() or (ijk + reach > np.array(volume.voxels.shape) - 1).any():
        return "partial", f"cut by the edge of the field of view, {100 * coverage:.0f} % of its surface seen"
    round_enough = abs(fitted_radius - radius) <= RADIUS_TOLERANCE_MM and rms <= RESIDUAL_LIMIT_MM
    if round_enough and coverage >= COVERAGE_LIMIT:
        return "ok", ""
    if round_enough:
        return "partial", f"only {100 * coverage:.0f} % of its surface is seen"
    return "deformed", (
        f"radius {fitted_radius:.2f} mm (nominal {radius:.2f} mm), surface {rms:.2f} mm RMS off a sphere"
    )


def _outward_normals(volume, image, vertices):
    """Unit outward normals (M, 3) RAS of iso-surface vertices (box index coordinates): down the gradient."""
    gradients = np.stack(np.gradient(image), axis=0)
    at_vertices = np.stack(
        [ndimage.map_coordinates(gradients[a], vertices.T, order=1, mode="nearest") for a in range(3)], axis=1
    )
    # A gradient per index step becomes a gradient per mm through the inverse transpose of the voxel axes.
    ras_gradient = at_vertices @ np.linalg.inv(volume.ijk_to_ras[:3, :3])
    return -ras_gradient / np.maximum(np.linalg.norm(ras_gradient, axis=1, keepdims=True), 1e-12)


def _without_duplicates(spheres, radius):
    """Two candidates that converged on one sphere: keep the one with more surface points."""
    kept = []
    for sphere in sorted(spheres, key=lambda s: -s.surface_points):
        if all(np.linalg.norm(sphere.centre - other.centre) > radius for other in kept):
            kept.append(sphere)
    return sorted(kept, key=lambda s: tuple(s.centre))


def _algebraic_fit(points):
    # |p|^2 = 2 c.p + (r^2 - |c|^2) is linear in c and the constant.
    design = np.hstack((2.0 * points, np.ones((len(points), 1))))
    solution, *_ = np.linalg.lstsq(design, np.sum(points**2, axis=1), rcond=None)
    centre = solution[:3]
    return centre, float(np.sqrt(max(solution[3] + centre @ centre, 1e-12)))


def _fibonacci_directions(count):
    """(count, 3) unit vectors spread evenly over the sphere (a Fibonacci lattice)."""
    index = np.arange(count) + 0.5
    polar = np.arccos(1.0 - 2.0 * index / count)
    azimuth = np.pi * (1.0 + 5.0**0.5) * index
    return np.column_stack((np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)))


def _coverage(offsets, directions=200, cone_deg=20.0):
    """Fraction of evenly spread directions from the centre that have a surface point within ``cone_deg``."""
    unit = _fibonacci_directions(directions)
    offsets = offsets / np.linalg.norm(offsets, axis=1, keepdims=True)
    return float(np.mean(np.max(unit @ offsets.T, axis=1) >= np.cos(np.radians(cone_deg))))
