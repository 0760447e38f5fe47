"""CT phantoms: a C-arm-CT-like volume of a real bone with its reference body, and the ground truth.

The paper's C-arm CT has 0.5 mm pixels and 0.625 mm slices. The phantom renders, with partial volume at every
boundary (signed distances, not voxel labels):

* the bone from a real mesh: a cortical shell around fatty marrow in the shaft and cancellous bone in the
  epiphysis of a long bone, or around cancellous bone throughout a flat bone (``ANATOMY``);
* soft tissue around the bone, air elsewhere;
* the reference body: 4 marker spheres (11.5 mm) at the NDI tool geometry, on plastic posts and a plastic frame
  joined to the bone by a carbon-fibre bracket. Plastic and carbon stay below the bone threshold, as in CT of
  real passive tools; the spheres' reflective coating makes them bright;

then blurs with the scanner's point spread and adds Gaussian noise. Every value is a documented constant below;
the phantom is deterministic under its seed. Optionally one sphere is partial (a cap missing) and one deformed
(stretched), like the defects of the paper's Fig. 4a.
"""

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from ..core.transforms import apply_transform
from ..image.volume_io import CTVolume
from ..io.ndi_tools import MARKER_DIAMETER_MM
from ..io.vtk_arrays import poly_data
from .virtual_patient import sample_surface

logger = logging.getLogger(__name__)

PAPER_SPACING_MM = (0.5, 0.5, 0.625)
HU = {
    "air": -1000.0,
    "soft_tissue": 40.0,
    "marrow": -40.0,
    "cancellous": 300.0,
    "cortex": 1400.0,
    "marker": 700.0,
    "plastic": 110.0,
    "carbon": 160.0,
}
#: Per kind of bone (``VirtualPatient.anatomy``): cortical shell (mm), how far below the top the interior is
#: cancellous bone rather than marrow (mm), and how far below the planned cut the field of view reaches (mm).
#: An ilium's cortical tables are thinner than a tibial shaft's and hold cancellous bone between them.
ANATOMY = {
    "long-bone": {"cortex_mm": 2.5, "cancellous_below_top_mm": 60.0, "below_cut_mm": 110.0},
    "flat-bone": {"cortex_mm": 1.5, "cancellous_below_top_mm": np.inf, "below_cut_mm": 100.0},
}
SOFT_TISSUE_MM = 15.0
PSF_SIGMA_MM = 0.35
NOISE_HU = 25.0
POST_LENGTH_MM = 12.0
POST_RADIUS_MM = 1.5
FRAME_RADIUS_MM = 3.0
BRACKET_RADIUS_MM = 4.0


@dataclass(frozen=True)
class PhantomTruth:
    """Ground truth of a CT phantom, all in the image's RAS frame (mm)."""

    reference_to_image: np.ndarray
    marker_centres: np.ndarray  # (4, 3) true sphere centres
    marker_radius_mm: float
    marker_defects: dict  # marker number -> 'partial' or 'deformed'
    bone_vertices: np.ndarray
    bone_triangles: np.ndarray
    settings: dict = field(default_factory=dict)

    def to_dict(self):
        return {
            "reference_to_image": self.reference_to_image.tolist(),
            "marker_centres": self.marker_centres.tolist(),
            "marker_radius_mm": self.marker_radius_mm,
            "marker_defects": {str(k): v for k, v in self.marker_defects.items()},
            **self.settings,
        }


def make_ct_phantom(
    patient,
    vertices,
    triangles,
    seed=0,
    spacing=PAPER_SPACING_MM,
    noise_hu=NOISE_HU,
    defects=None,
    margin_mm=12.0,
    below_cut_mm=None,
):
    """Render a CT phantom of a virtual patient.

    Args:
        patient: VirtualPatient (its reference_to_image and markers_reference place the reference body).
        vertices, triangles: the bone mesh in image coordinates (RAS mm).
        seed: fixes the noise.
        spacing: voxel size (mm) along i, j, k; the paper's is 0.5 x 0.5 x 0.625.
        noise_hu: standard deviation of the image noise (HU).
        defects: optional {marker number (0-3): 'partial' | 'deformed'}.
        margin_mm: field of view beyond the markers and the bone region.
        below_cut_mm: how far below the osteotomy cut the field of view reaches (default: ``ANATOMY``'s).

    Returns:
        (CTVolume, PhantomTruth). The volume's i, j, k axes point L, P, S (an LPS-aligned scanner grid).
    """
    defects = dict(defects or {})
    anatomy = ANATOMY[patient.anatomy]
    if below_cut_mm is None:
        below_cut_mm = anatomy["below_cut_mm"]
    spacing = np.asarray(spacing, dtype=np.float64)
    markers = patient.markers_image
    radius = MARKER_DIAMETER_MM / 2.0
    top = vertices[:, 2].max()
    bone_region = vertices[(vertices[:, 2] >= patient.cut_height_mm - below_cut_mm)]
    low = np.minimum(bone_region.min(axis=0), markers.min(axis=0) - radius) - margin_mm
    high = np.maximum(bone_region.max(axis=0), markers.max(axis=0) + radius) + margin_mm
    # The scan ends inside the bone, below the cut, and holds every marker sphere whole.
    low[2] = min(patient.cut_height_mm - below_cut_mm, markers[:, 2].min() - radius)
    high[2] = top + margin_mm
    # LPS-aligned grid: i runs to the left (-x RAS), j to posterior (-y), k superior.
    direction = np.diag([-1.0, -1.0, 1.0])
    shape = np.ceil((high - low) / spacing).astype(int) + 1
    origin = np.array([high[0], high[1], low[2]])
    ijk_to_ras = np.eye(4)
    ijk_to_ras[:3, :3] = direction * spacing
    ijk_to_ras[:3, 3] = origin
    volume = CTVolume(voxels=np.full(tuple(shape), HU["air"], dtype=np.float32), ijk_to_ras=ijk_to_ras)
    logger.info("CT phantom grid %s voxels of %s mm", tuple(shape), spacing.tolist())

    _paint_bone(volume, vertices, triangles, top, anatomy, np.random.default_rng(seed))
    _paint_reference_body(volume, patient, radius, defects)
    sigma_voxels = PSF_SIGMA_MM / spacing
    blurred = ndimage.gaussian_filter(volume.voxels, sigma_voxels, truncate=3.0)
    noise = np.random.default_rng(seed + 1).normal(scale=noise_hu, size=blurred.shape).astype(np.float32)
    voxels = np.round(blurred + noise).astype(np.int16)
    truth = PhantomTruth(
        reference_to_image=patient.reference_to_image.copy(),
        marker_centres=markers.copy(),
        marker_radius_mm=radius,
        marker_defects=defects,
        bone_vertices=vertices,
        bone_triangles=triangles,
        settings={
            "spacing_mm": spacing.tolist(),
            "shape": shape.tolist(),
            "noise_hu": noise_hu,
            "psf_sigma_mm": PSF_SIGMA_MM,
            "hu": HU,
            "anatomy": patient.anatomy,
            "cortex_thickness_mm": anatomy["cortex_mm"],
            "seed": seed,
        },
    )
    return CTVolume(voxels=voxels, ijk_to_ras=ijk_to_ras), truth


def write_phantom(directory, volume, truth):
    """Write a phantom to ``directory``: ``ct.nrrd`` (LPS, int16), ``truth.json`` and ``bone_surface.vtp``.

    ``truth.json`` holds the true marker centres and ``ReferenceToImage`` (RAS mm), the marker radius and
    defects, the rendering settings, and the name of the bone-surface file.
    Returns the paths written, by name.
    """
    import json
    from pathlib import Path

    from ..image.volume_io import save_nrrd
    from ..io.surface_files import write_surface

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    paths = {
        "ct": directory / "ct.nrrd",
        "truth": directory / "truth.json",
        "bone_surface": directory / "bone_surface.vtp",
    }
    save_nrrd(paths["ct"], volume)
    write_surface(paths["bone_surface"], truth.bone_vertices, truth.bone_triangles)
    document = {**truth.to_dict(), "bone_surface_file": paths["bone_surface"].name, "ct_file": paths["ct"].name}
    paths["truth"].write_text(json.dumps(document, indent=2), encoding="utf-8")
    return paths


def signed_distance_to_mesh(points, vertices, triangles, rng, samples=1_500_000):
    """Signed distance (mm, positive outside) of (N, 3) points near a closed mesh's surface.

    Point-to-plane distance to the nearest of ``samples`` surface samples with their normals (about 0.15 mm
    apart on a tibia): exact to well under 0.01 mm within a few mm of the surface, where it is used.
    """
    surface, normals = sample_surface(vertices, triangles, samples, rng)
    _, nearest = cKDTree(surface).query(points)
    return np.einsum("ij,ij->i", points - surface[nearest], normals[nearest])


def _fraction_inside(signed_distance_mm, ramp_mm):
    """Partial-volume fraction from a signed distance (negative inside): a linear ramp one voxel wide."""
    return np.clip(0.5 - signed_distance_mm / ramp_mm, 0.0, 1.0)


def _paint_bone(volume, vertices, triangles, top, anatomy, rng):
    """Bone with partial volume from exact signed distances near the surface, soft tissue around it."""
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkImagingStencil import vtkImageStencilToImage, vtkPolyDataToImageStencil

    spacing = volume.spacing
    ramp = float(np.mean(spacing))
    vertices_ijk = volume.ras_to_ijk_points(vertices)
    margin = int(np.ceil((SOFT_TISSUE_MM + 3.0) / spacing.min()))
    low = np.maximum(np.floor(vertices_ijk.min(axis=0)).astype(int) - margin, 0)
    high = np.minimum(np.ceil(vertices_ijk.max(axis=0)).astype(int) + margin, np.array(volume.voxels.shape) - 1)
    box = tuple(slice(a, b + 1) for a, b in zip(low, high))
    box_shape = high - low + 1

    # Inside/outside of the closed mesh on the grid, scan-line by scan-line (VTK stencil), in index space.
    stencil = vtkPolyDataToImageStencil()
    stencil.SetInputData(poly_data(vertices_ijk - low, triangles))
    stencil.SetOutputOrigin(0.0, 0.0, 0.0)
    stencil.SetOutputSpacing(1.0, 1.0, 1.0)
    stencil.SetOutputWholeExtent(0, box_shape[0] - 1, 0, box_shape[1] - 1, 0, box_shape[2] - 1)
    to_image = vtkImageStencilToImage()
    to_image.SetInputConnection(stencil.GetOutputPort())
    to_image.SetInsideValue(1)
    to_image.SetOutsideValue(0)
    to_image.SetOutputScalarTypeToUnsignedChar()
    to_image.Update()
    inside = vtk_to_numpy(to_image.GetOutput().GetPointData().GetScalars()).reshape(box_shape[::-1]).transpose(2, 1, 0)
    inside = inside.astype(bool)

    depth = ndimage.distance_transform_edt(inside, sampling=spacing)  # mm from the surface, inside
    outside_distance = ndimage.distance_transform_edt(~inside, sampling=spacing)
    signed = np.where(inside, -depth, outside_distance).astype(np.float32)

    # Near the surface replace the voxel-resolution distance by the exact one: point-to-plane distance to the
    # nearest of 1.5 million surface samples with their normals.
    band = np.abs(signed) < 2.0 * spacing.max()
    signed[band] = signed_distance_to_mesh(volume.ijk_to_ras_points(np.argwhere(band) + low), vertices, triangles, rng)

    box_ras_z = volume.ijk_to_ras[2, 3] + (np.arange(low[2], high[2] + 1) * volume.ijk_to_ras[2, 2])
    cancellous = box_ras_z[None, None, :] > top - anatomy["cancellous_below_top_mm"]
    interior = np.where(cancellous, HU["cancellous"], HU["marrow"])
    cortex = np.clip((anatomy["cortex_mm"] + signed) / ramp + 0.5, 0.0, 1.0)  # 1 in the outer shell
    bone_hu = cortex * HU["cortex"] + (1.0 - cortex) * interior
    tissue = _fraction_inside(signed - SOFT_TISSUE_MM, ramp)
    outside_hu = tissue * HU["soft_tissue"] + (1.0 - tissue) * HU["air"]
    bone = _fraction_inside(signed, ramp)
    volume.voxels[box] = (bone * bone_hu + (1.0 - bone) * outside_hu).astype(np.float32)


def _paint_reference_body(volume, patient, radius, defects):
    """Bracket, frame, posts and marker spheres, painted in that order (later ones on top)."""
    pose = patient.reference_to_image
    markers_tool = patient.markers_reference
    feet_tool = markers_tool - np.array([POST_LENGTH_MM, 0.0, 0.0])  # posts stand on +x, the marker normal
    hub_tool = feet_tool.mean(axis=0)
    feet, hub = apply_transform(pose, feet_tool), apply_transform(pose, hub_tool[None])[0]
    bone_anchor = patient.ipc[np.argmin(np.linalg.norm(patient.ipc - hub, axis=1))]
    towards_hub = (hub - bone_anchor) / np.linalg.norm(hub - bone_anchor)
    # The bracket's clamp rests on the bone surface; it does not cut through the cortex.
    _paint_capsule(volume, hub, bone_anchor + (BRACKET_RADIUS_MM + 0.5) * towards_hub, BRACKET_RADIUS_MM, HU["carbon"])
    for foot in feet:
        _paint_capsule(volume, foot, hub, FRAME_RADIUS_MM, HU["plastic"])
    for number, (centre, foot) in enumerate(zip(patient.markers_image, feet)):
        _paint_capsule(volume, centre, foot, POST_RADIUS_MM, HU["plastic"])
        _paint_sphere(volume, centre, radius, defects.get(number), outward=centre - foot)


def _box_around(volume, low_ras, high_ras):
    corners = np.array(
        [
            [x, y, z]
            for x in (low_ras[0], high_ras[0])
            for y in (low_ras[1], high_ras[1])
            for z in (low_ras[2], high_ras[2])
        ]
    )
    ijk = volume.ras_to_ijk_points(corners)
    low = np.maximum(np.floor(ijk.min(axis=0)).astype(int), 0)
    high = np.minimum(np.ceil(ijk.max(axis=0)).astype(int), np.array(volume.voxels.shape) - 1)
    if (high < low).any():
        return None, None  # the object lies outside the field of view
    box = tuple(slice(a, b + 1) for a, b in zip(low, high))
    grid = np.stack(np.meshgrid(*[np.arange(a, b + 1) for a, b in zip(low, high)], indexing="ij"), axis=-1)
    return box, volume.ijk_to_ras_points(grid.reshape(-1, 3)).reshape(grid.shape)


def _blend(volume, box, signed_distance, hu):
    fraction = _fraction_inside(signed_distance, float(np.mean(volume.spacing))).astype(np.float32)
    volume.voxels[box] = fraction * hu + (1.0 - fraction) * volume.voxels[box]


def _paint_capsule(volume, start, end, radius, hu):
    pad = radius + 2.0
    box, ras = _box_around(volume, np.minimum(start, end) - pad, np.maximum(start, end) + pad)
    if box is None:
        return
    axis = end - start
    t = np.clip(((ras - start) @ axis) / (axis @ axis), 0.0, 1.0)
    signed = np.linalg.norm(ras - (start + t[..., None] * axis), axis=-1) - radius
    _blend(volume, box, signed, hu)


def _paint_sphere(volume, centre, radius, defect, outward):
    pad = 1.3 * radius + 2.0
    box, ras = _box_around(volume, centre - pad, centre + pad)
    if box is None:
        return
    offset = ras - centre
    if defect == "deformed":
        # Stretched by 20 % across the marker normal: the blurred, bloated look of Fig. 4a.
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
    _blend(volume, box, signed, HU["marker"])
