"""A small CT phantom of a reference body beside a bone shaft: the marker-sphere variants with known answers.

Faster to render than the tibia phantom (no mesh), so every variant of the reference body can be tested: posts
and frame of plastic, dense polymer or aluminium, a steel pin with streaks, low-dose noise, a turned scanner
grid, a field of view that cuts a sphere, damaged spheres. The scene, in RAS mm:

* the shaft: a straight tube along z through (0, 0), outer radius ``SHAFT_RADIUS_MM``, cortex
  ``SHAFT_CORTEX_MM`` thick, fatty marrow inside, wrapped in ``SOFT_TISSUE_MM`` of soft tissue, in air (its
  surface is known exactly, for the IPC; streaks over the soft tissue can raise it above the bone threshold);
* the NDI reference body (8700339 by default) 75 mm lateral (+x) and 45 mm anterior (+y) of the shaft axis,
  its markers facing anterior turned by 20 degrees about z, its long axis along z, as in the virtual patient;
* a carbon-fibre bracket from the frame's hub to the shaft, and with ``metal='pin'`` a 5 mm steel pin along the
  bracket through the shaft.
"""

from dataclasses import dataclass

import numpy as np

from ..core.transforms import apply_transform, make_transform, rotation_about_axis
from ..io.ndi_tools import DEFAULT_REFERENCE_TOOL, MARKER_DIAMETER_MM, tool_marker_geometry
from .ct_painting import (
    LPS_DIRECTION,
    MATERIALS_HU,
    ReferenceBodyModel,
    blend,
    check_defects,
    check_noise,
    paint_mounted_body,
    reference_body_feet,
    scan,
    scanner_grid,
    sphere_extremes,
)
from .ct_phantom import PAPER_SPACING_MM, cut_through_sphere

SHAFT_RADIUS_MM = 12.0
SHAFT_CORTEX_MM = 2.5
SOFT_TISSUE_MM = 15.0
BODY_OFFSET_MM = (75.0, 45.0)
BODY_TURN_DEG = 20.0


@dataclass(frozen=True)
class ReferenceBodyTruth:
    """Known answers of a reference-body phantom (RAS mm): marker centres in the tool's order (1 to K)."""

    marker_centres: np.ndarray
    reference_to_image: np.ndarray
    shaft_radius_mm: float
    shaft_z_mm: tuple  # (lowest, highest) z of the shaft
    metal: object = None
    cut_marker: int = None


def make_reference_body_phantom(
    body=None,
    seed=0,
    spacing=PAPER_SPACING_MM,
    noise_hu=25.0,
    direction=LPS_DIRECTION,
    defects=None,
    metal=None,
    cut_marker=None,
    tool_id=DEFAULT_REFERENCE_TOOL,
    margin_mm=8.0,
):
    """Render the reference body beside a bone shaft (see the module docstring).

    Args:
        body: ReferenceBodyModel (plastic posts and frame by default).
        noise_hu: image noise (HU); 40-60 for a low-dose scan.
        direction: (3, 3) RAS directions of the grid's i, j, k axes; LPS-aligned by default.
        defects: {marker number (1 to K): 'partial' | 'deformed'}.
        metal: None, 'pin' (a steel pin along the bracket through the shaft), or a MetalRod.
        cut_marker: number of the sphere (1 to K) the field of view cuts.

    Returns:
        (CTVolume, ReferenceBodyTruth).
    """
    body = body or ReferenceBodyModel()
    markers_reference = tool_marker_geometry(tool_id)
    check_noise(noise_hu)
    defects = check_defects(defects, len(markers_reference))
    radius = MARKER_DIAMETER_MM / 2.0
    pose = body_pose(markers_reference)
    markers = apply_transform(pose, markers_reference)
    feet, hub = reference_body_feet(pose, markers_reference, body)
    z_range = (markers[:, 2].min() - radius - margin_mm, markers[:, 2].max() + radius + margin_mm)
    shaft_extremes = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in z_range]) * (
        SHAFT_RADIUS_MM,
        SHAFT_RADIUS_MM,
        1.0,
    )
    volume = scanner_grid(
        np.vstack((shaft_extremes, sphere_extremes(markers, radius, direction))), spacing, direction, margin_mm
    )
    if cut_marker is not None:
        volume = cut_through_sphere(volume, markers, radius, cut_marker)
    _paint_shaft(volume, z_range)
    towards_hub = np.array([hub[0], hub[1], 0.0]) / np.hypot(hub[0], hub[1])
    anchor = np.array([0.0, 0.0, hub[2]]) + SHAFT_RADIUS_MM * towards_hub
    metal = paint_mounted_body(volume, pose, markers_reference, body, radius, defects, anchor, metal)
    truth = ReferenceBodyTruth(
        marker_centres=markers,
        reference_to_image=pose,
        shaft_radius_mm=SHAFT_RADIUS_MM,
        shaft_z_mm=z_range,
        metal=metal,
        cut_marker=cut_marker,
    )
    return scan(volume, noise_hu, seed), truth


def body_pose(markers_reference):
    """ReferenceToImage of the body beside the shaft: markers facing anterior turned 20 degrees, long axis on z."""
    x_axis = rotation_about_axis((0.0, 0.0, 1.0), np.radians(BODY_TURN_DEG)) @ np.array([0.0, 1.0, 0.0])
    z_axis = np.array([0.0, 0.0, 1.0])
    rotation = np.column_stack((x_axis, np.cross(z_axis, x_axis), z_axis))
    centre = np.array([BODY_OFFSET_MM[0], BODY_OFFSET_MM[1], 0.0])
    return make_transform(rotation, centre - rotation @ markers_reference.mean(axis=0))


def _paint_shaft(volume, z_range):
    """Soft tissue, then the tube: cortex from SHAFT_RADIUS_MM - SHAFT_CORTEX_MM to SHAFT_RADIUS_MM, marrow inside."""
    outer = SHAFT_RADIUS_MM + SOFT_TISSUE_MM
    box, ras = volume.voxels_within(
        np.array([-outer - 2.0, -outer - 2.0, z_range[0] - 2.0]),
        np.array([outer + 2.0, outer + 2.0, z_range[1] + 2.0]),
    )
    if box is None:
        return
    from_axis = np.hypot(ras[..., 0], ras[..., 1])
    beyond_ends = np.maximum(z_range[0] - ras[..., 2], ras[..., 2] - z_range[1])
    blend(volume, box, np.maximum(from_axis - outer, beyond_ends), MATERIALS_HU["soft_tissue"])
    blend(volume, box, np.maximum(from_axis - SHAFT_RADIUS_MM, beyond_ends), MATERIALS_HU["cortex"])
    inner = SHAFT_RADIUS_MM - SHAFT_CORTEX_MM
    blend(volume, box, np.maximum(from_axis - inner, beyond_ends + SHAFT_CORTEX_MM), MATERIALS_HU["marrow"])
