"""Painting a CT phantom: the scanner's grid, objects with partial volume, metal streaks, blur and noise.

Every object is a signed distance (mm, negative inside) evaluated at the voxel centres in RAS, turned into a
partial-volume fraction by a linear ramp one voxel wide, and blended over what is already painted (later objects
on top). Then the scanner blurs (Gaussian point spread, ``PSF_SIGMA_MM``) and adds Gaussian noise.

**Metal streaks** (``add_metal_streaks``) are a simple model, not a reconstruction. A CT's streaks lie in its scan
planes; here every slice (the grid's k axis) that cuts a metal object gets straight streaks through the metal's
cross-section in that slice: the first along the direction in which the metal is longest (most photon
starvation: dark), or towards a given point; the others evenly spread over 180 degrees, alternating bright and
dark. A streak has a Gaussian profile across (``STREAK_WIDTH_MM``) and an amplitude of ``STREAK_HU`` per 10 mm of
metal crossed, at most 3 times that, falling off as ``1 / (1 + d / STREAK_DECAY_MM)`` with the distance ``d`` from
the metal; inside the metal it is not added.
"""

from dataclasses import dataclass

import numpy as np

from ..core.transforms import apply_transform
from ..image.volume_io import CTVolume

#: Scanner point spread (Gaussian sigma, mm).
PSF_SIGMA_MM = 0.35
#: Materials (HU). The reference body's posts and frame come in three materials; steel is clipped to the top of a
#: 12-bit CT scale, as most scanners store it.
MATERIALS_HU = {
    "air": -1000.0,
    "soft_tissue": 40.0,
    "marrow": -40.0,
    "cancellous": 300.0,
    "cortex": 1400.0,
    "marker": 700.0,
    "plastic": 150.0,
    "dense-polymer": 1000.0,
    "aluminium": 2500.0,
    "carbon": 160.0,
    "steel": 3071.0,
}
#: Reference-body materials a user may choose for the posts and the frame.
BODY_MATERIALS = ("plastic", "dense-polymer", "aluminium")
#: The streak model's constants (see the module docstring).
STREAK_HU = 200.0
STREAK_WIDTH_MM = 0.8
STREAK_DECAY_MM = 10.0
STREAK_COUNT = 6

#: The carbon-fibre bracket from the bone to the frame's hub, and the steel pin that fixes it to the bone (mm).
BRACKET_RADIUS_MM = 4.0
PIN_RADIUS_MM = 2.5
PIN_OUTSIDE_MM = 15.0
PIN_INSIDE_MM = 30.0

#: The default scanner grid: i, j, k point L, P, S (an LPS-aligned grid).
LPS_DIRECTION = np.diag([-1.0, -1.0, 1.0])


@dataclass(frozen=True)
class ReferenceBodyModel:
    """How a reference body looks in CT: NDI marker spheres on posts joined by a frame.

    Each post stands ``post_length_mm`` from its sphere's centre along the tool's +x axis (the markers' normal);
    the frame joins the posts' feet to the hub, where the bracket holds the body. Materials are keys of
    ``MATERIALS_HU``: plastic stays below a 200 HU bone threshold, dense polymer and aluminium do not, so then
    spheres, posts and frame form one bright object. Any key of ``MATERIALS_HU`` is accepted ('marker' makes a
    post as bright as the spheres).
    """

    post_material: str = "plastic"
    frame_material: str = "plastic"
    post_diameter_mm: float = 3.0
    post_length_mm: float = 12.0
    frame_diameter_mm: float = 6.0

    def __post_init__(self):
        for name in ("post_material", "frame_material"):
            if getattr(self, name) not in MATERIALS_HU:
                raise ValueError(f"{name} {getattr(self, name)!r}: use one of {', '.join(BODY_MATERIALS)}")
        for name in ("post_diameter_mm", "post_length_mm", "frame_diameter_mm"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"{name[:-3].replace('_', ' ')} {value} mm: give a positive number of mm")

    def to_dict(self):
        return {
            "post_material": self.post_material,
            "post_hu": MATERIALS_HU[self.post_material],
            "frame_material": self.frame_material,
            "frame_hu": MATERIALS_HU[self.frame_material],
            "post_diameter_mm": self.post_diameter_mm,
            "post_length_mm": self.post_length_mm,
            "frame_diameter_mm": self.frame_diameter_mm,
        }


@dataclass(frozen=True)
class MetalRod:
    """A straight metal rod (a bone pin, a screw, a nail) from ``start`` to ``end`` (RAS mm), with streaks.

    ``streak_towards``: an optional RAS point that the first streak of every slice is aimed at (to put a streak
    across a marker sphere); by default the first streak runs along the metal's longest extent in the slice.
    """

    start: tuple
    end: tuple
    radius_mm: float = 2.5
    material: str = "steel"
    streak_towards: tuple = None

    def to_dict(self):
        return {
            "start": np.asarray(self.start, dtype=float).tolist(),
            "end": np.asarray(self.end, dtype=float).tolist(),
            "radius_mm": self.radius_mm,
            "hu": MATERIALS_HU[self.material],
            "streak_towards": None if self.streak_towards is None else np.asarray(self.streak_towards).tolist(),
        }


def rotated_direction(degrees, axis=(1.0, 2.0, 3.0)):
    """A non-identity direction matrix: the LPS-aligned grid turned by ``degrees`` about ``axis`` (RAS)."""
    from ..core.transforms import rotation_about_axis

    if not np.isfinite(degrees):
        raise ValueError(f"grid rotation {degrees} degrees: give a finite angle")

    return rotation_about_axis(axis, np.radians(degrees)) @ LPS_DIRECTION


def scanner_grid(low_ras_points, spacing, direction=LPS_DIRECTION, margin_mm=12.0):
    """An air-filled CTVolume whose grid (axes ``direction``, voxel ``spacing``) holds the points with a margin.

    Args:
        low_ras_points: (N, 3) RAS points the field of view must contain (mm).
        spacing: (3,) voxel size along i, j, k (mm).
        direction: (3, 3) orthonormal matrix, columns the RAS directions of i, j, k.
        margin_mm: added on every side, along the grid's axes.
    """
    spacing = np.asarray(spacing, dtype=np.float64)
    direction = np.asarray(direction, dtype=np.float64)
    in_grid = np.asarray(low_ras_points, dtype=np.float64) @ direction  # coordinates along i, j, k (mm)
    low = in_grid.min(axis=0) - margin_mm
    high = in_grid.max(axis=0) + margin_mm
    shape = np.ceil((high - low) / spacing).astype(int) + 1
    ijk_to_ras = np.eye(4)
    ijk_to_ras[:3, :3] = direction * spacing
    ijk_to_ras[:3, 3] = direction @ low
    return CTVolume(voxels=np.full(tuple(shape), MATERIALS_HU["air"], dtype=np.float32), ijk_to_ras=ijk_to_ras)


def sphere_extremes(centres, radius, direction=LPS_DIRECTION):
    """(6K, 3) RAS points where spheres (K, 3) reach farthest along the grid's axes (a grid holding them holds them)."""
    along_axes = np.vstack((np.asarray(direction, float).T, -np.asarray(direction, float).T))
    return (np.asarray(centres, float)[:, None, :] + radius * along_axes[None]).reshape(-1, 3)


def fraction_inside(signed_distance_mm, ramp_mm):
    """Partial-volume fraction from a signed distance (negative inside): a linear ramp one voxel wide."""
    return np.clip(0.5 - signed_distance_mm / ramp_mm, 0.0, 1.0)


def blend(volume, box, signed_distance, hu):
    fraction = fraction_inside(signed_distance, float(np.mean(volume.spacing))).astype(np.float32)
    volume.voxels[box] = fraction * hu + (1.0 - fraction) * volume.voxels[box]


def capsule_distance(points, start, end, radius):
    """Signed distance (mm) of (..., 3) points to a capsule (a cylinder with round ends) from start to end."""
    axis = end - start
    t = np.clip(((points - start) @ axis) / (axis @ axis), 0.0, 1.0)
    return np.linalg.norm(points - (start + t[..., None] * axis), axis=-1) - radius


def paint_capsule(volume, start, end, radius, hu):
    start, end = np.asarray(start, dtype=np.float64), np.asarray(end, dtype=np.float64)
    pad = radius + 2.0
    box, ras = volume.voxels_within(np.minimum(start, end) - pad, np.maximum(start, end) + pad)
    if box is not None:
        blend(volume, box, capsule_distance(ras, start, end, radius), hu)


def paint_sphere(volume, centre, radius, defect=None, outward=None, hu=MATERIALS_HU["marker"]):
    """A marker sphere; ``defect`` 'partial' (a 4 mm cap missing opposite the post) or 'deformed' (stretched)."""
    pad = 1.3 * radius + 2.0
    box, ras = volume.voxels_within(centre - pad, centre + pad)
    if box is None:
        return
    offset = ras - centre
    if defect == "deformed":
        # Stretched by 20 % across the marker normal: the blurred, bloated look of the paper's Fig. 4a.
        across = np.cross(outward, (0.0, 0.0, 1.0))
        across /= np.linalg.norm(across)
        along = offset @ across
        squeezed = offset + (along / 1.2 - along)[..., None] * across
        signed = np.linalg.norm(squeezed, axis=-1) - radius
    else:
        signed = np.linalg.norm(offset, axis=-1) - radius
    if defect == "partial":
        # A cap 4 mm deep is missing on the side facing away from the post (a defect of the reconstruction).
        unit = outward / np.linalg.norm(outward)
        signed = np.maximum(signed, offset @ unit - (radius - 4.0))
    blend(volume, box, signed, hu)


def reference_body_feet(reference_to_image, markers_reference, model):
    """Feet of the posts (K, 3) and the frame's hub (3,), RAS mm: the posts stand on the tool's +x axis."""
    feet_tool = markers_reference - np.array([model.post_length_mm, 0.0, 0.0])
    feet = apply_transform(reference_to_image, feet_tool)
    return feet, feet.mean(axis=0)


def paint_reference_body(volume, reference_to_image, markers_reference, model, radius, defects):
    """Frame, posts and marker spheres (in that order, later on top). ``defects``: {marker number 1..K: kind}."""
    feet, hub = reference_body_feet(reference_to_image, markers_reference, model)
    markers = apply_transform(reference_to_image, markers_reference)
    for foot in feet:
        paint_capsule(volume, foot, hub, model.frame_diameter_mm / 2.0, MATERIALS_HU[model.frame_material])
    for number, (centre, foot) in enumerate(zip(markers, feet), start=1):
        paint_capsule(volume, centre, foot, model.post_diameter_mm / 2.0, MATERIALS_HU[model.post_material])
        paint_sphere(volume, centre, radius, defects.get(number), outward=centre - foot)


def pin_for_bracket(anchor, hub):
    """The steel pin (MetalRod) that fixes the bracket: from inside the bracket through ``anchor`` (on the bone's
    surface, RAS mm) into the bone, along the line from the frame's ``hub`` to the anchor."""
    towards_hub = (hub - anchor) / np.linalg.norm(hub - anchor)
    return MetalRod(
        start=tuple(anchor + PIN_OUTSIDE_MM * towards_hub),
        end=tuple(anchor - PIN_INSIDE_MM * towards_hub),
        radius_mm=PIN_RADIUS_MM,
    )


def paint_mounted_body(volume, reference_to_image, markers_reference, model, radius, defects, anchor, metal=None):
    """The bracket from ``anchor`` (a point on the bone's surface, RAS mm) to the frame's hub, the reference body,
    and a MetalRod with its streaks (``metal``: None, a MetalRod, or 'pin' for ``pin_for_bracket``).

    The bracket's clamp rests on the bone surface; it does not cut through the cortex. Returns the MetalRod
    painted, or None.
    """
    _, hub = reference_body_feet(reference_to_image, markers_reference, model)
    towards_hub = (hub - anchor) / np.linalg.norm(hub - anchor)
    clamp = anchor + (BRACKET_RADIUS_MM + 0.5) * towards_hub
    paint_capsule(volume, hub, clamp, BRACKET_RADIUS_MM, MATERIALS_HU["carbon"])
    paint_reference_body(volume, reference_to_image, markers_reference, model, radius, defects)
    if metal == "pin":
        metal = pin_for_bracket(anchor, hub)
    if metal is not None:
        box, fraction = paint_metal(volume, metal)
        if box is not None:
            add_metal_streaks(volume, box, fraction, towards=metal.streak_towards)
    return metal


def paint_metal(volume, rod):
    """Paint a MetalRod and return its partial-volume fraction in its index box: (box, fraction) or (None, None)."""
    start, end = np.asarray(rod.start, dtype=np.float64), np.asarray(rod.end, dtype=np.float64)
    pad = rod.radius_mm + 2.0
    box, ras = volume.voxels_within(np.minimum(start, end) - pad, np.maximum(start, end) + pad)
    if box is None:
        return None, None
    signed = capsule_distance(ras, start, end, rod.radius_mm)
    blend(volume, box, signed, MATERIALS_HU[rod.material])
    return box, fraction_inside(signed, float(np.mean(volume.spacing)))


def add_metal_streaks(volume, box, metal_fraction, towards=None, count=STREAK_COUNT, amplitude_hu=STREAK_HU):
    """Add streaks in every slice (k) that cuts the metal (see the module docstring for the model).

    Args:
        box: the metal's index box (slices); ``metal_fraction`` its partial-volume fraction there.
        towards: optional RAS point at which the first streak of each slice is aimed.
        amplitude_hu: the streaks' HU per 10 mm of metal crossed (``STREAK_HU`` by default).
    """
    spacing = volume.spacing
    shape = volume.voxels.shape
    i, j = np.meshgrid(np.arange(shape[0]) * spacing[0], np.arange(shape[1]) * spacing[1], indexing="ij")
    target = (
        None if towards is None else volume.ras_to_ijk_points(np.asarray(towards, float)[None])[0, :2] * spacing[:2]
    )
    for k_local in range(metal_fraction.shape[2]):
        section = metal_fraction[:, :, k_local] >= 0.5
        if not section.any():
            continue
        k = box[2].start + k_local
        cells = (np.argwhere(section) + [box[0].start, box[1].start]) * spacing[:2]  # in-plane mm
        centre = cells.mean(axis=0)
        if target is not None:
            first = target - centre
        elif len(cells) > 2:
            first = np.linalg.eigh(np.cov(cells.T))[1][:, -1]
        else:
            first = np.array([1.0, 0.0])
        first_angle = np.arctan2(first[1], first[0])
        extent = np.ptp(cells @ np.array([np.cos(first_angle), np.sin(first_angle)])) + spacing[:2].mean()
        amplitude = amplitude_hu * min(extent / 10.0, 3.0)
        offset_i, offset_j = i - centre[0], j - centre[1]
        distance = np.maximum(np.hypot(offset_i, offset_j) - 0.5 * extent, 0.0)
        decay = 1.0 / (1.0 + distance / STREAK_DECAY_MM)
        streaks = np.zeros(shape[:2], dtype=np.float64)
        for number in range(count):
            angle = first_angle + number * np.pi / count
            across = -offset_i * np.sin(angle) + offset_j * np.cos(angle)
            sign = -1.0 if number % 2 == 0 else 1.0
            streaks += sign * np.exp(-0.5 * (across / STREAK_WIDTH_MM) ** 2)
        full = np.zeros(shape[:2], dtype=np.float32)
        full[box[0], box[1]] = metal_fraction[:, :, k_local]
        volume.voxels[:, :, k] += (amplitude * decay * streaks * (1.0 - full)).astype(np.float32)


def scan(volume, noise_hu, seed):
    """The scanner: Gaussian blur (``PSF_SIGMA_MM``) and Gaussian noise (``noise_hu``), stored as int16 HU."""
    check_noise(noise_hu)
    from scipy import ndimage  # here, not at the top: the command line's --help lists BODY_MATERIALS

    blurred = ndimage.gaussian_filter(volume.voxels, PSF_SIGMA_MM / volume.spacing, truncate=3.0)
    noise = np.random.default_rng(seed).normal(scale=noise_hu, size=blurred.shape).astype(np.float32)
    voxels = np.clip(np.round(blurred + noise), -32768, 32767).astype(np.int16)
    return CTVolume(voxels=voxels, ijk_to_ras=volume.ijk_to_ras)


def check_noise(noise_hu):
    """Raise ValueError unless the noise is a standard deviation (HU, finite, 0 or more)."""
    if not np.isfinite(noise_hu) or noise_hu < 0:
        raise ValueError(f"noise {noise_hu} HU: give a standard deviation of 0 or more (25 by default, 40-60 low dose)")


def check_defects(defects, count):
    """Validate {marker number 1..count: 'partial' | 'deformed'}; returns a plain dict."""
    defects = dict(defects or {})
    for number, kind in defects.items():
        if not isinstance(number, (int, np.integer)) or not 1 <= number <= count:
            raise ValueError(f"marker number {number!r}: markers are numbered 1 to {count}")
        if kind not in ("partial", "deformed"):
            raise ValueError(f"marker {number} defect {kind!r}: use 'partial' or 'deformed'")
    return defects
