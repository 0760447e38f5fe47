"""CT phantoms: a C-arm-CT-like volume of a real bone with its reference body, and the ground truth.

The paper's C-arm CT has 0.5 mm pixels and 0.625 mm slices. The phantom renders, with partial volume at every
boundary (signed distances, not voxel labels; see ``ct_painting``):

* the bone from a real mesh: a cortical shell around fatty marrow in the shaft and cancellous bone in the
  epiphysis of a long bone, or around cancellous bone throughout a flat bone (``ANATOMY``);
* soft tissue around the bone, air elsewhere;
* the reference body (``ReferenceBodyModel``): 4 marker spheres (11.5 mm) at the NDI tool geometry on posts, the
  posts joined by a frame, the frame held by a carbon-fibre bracket that rests on the bone. Posts and frame are
  plastic (below the bone threshold) by default, or dense polymer or aluminium (above it: then spheres, posts and
  frame are one bright object, as on many real tool bodies); the spheres' reflective coating makes them bright;
* optionally a steel pin through the shaft where the bracket is clamped (``fixation_pin``), with the streaks of
  ``ct_painting.add_metal_streaks``;

then blurs with the scanner's point spread and adds Gaussian noise (25 HU; a low-dose scan is 40-60 HU). The
scanner grid is LPS-aligned unless a ``direction`` is given. Optionally a sphere is partial (a cap missing) or
deformed (stretched), like the defects of the paper's Fig. 4a, and the field of view can cut one sphere. Every
value is a documented constant; the phantom is deterministic under its seed. Markers are numbered 1 to 4 in the
tool's order, everywhere.
"""

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from ..image.volume_io import CTVolume
from ..io.atomic_files import atomic_folder, write_json_atomic
from ..io.ndi_tools import MARKER_DIAMETER_MM
from ..io.vtk_arrays import mesh_inside_grid, poly_data, triangle_arrays
from .ct_painting import (
    LPS_DIRECTION,
    MATERIALS_HU,
    PSF_SIGMA_MM,
    ReferenceBodyModel,
    check_defects,
    check_noise,
    fraction_inside,
    paint_mounted_body,
    pin_for_bracket,
    reference_body_feet,
    scan,
    scanner_grid,
    sphere_extremes,
)
from .virtual_patient import sample_surface

logger = logging.getLogger(__name__)

PAPER_SPACING_MM = (0.5, 0.5, 0.625)
#: Materials (HU); ``ct_painting.MATERIALS_HU`` under its old name.
HU = MATERIALS_HU
#: Per kind of bone (``VirtualPatient.anatomy``): cortical shell (mm), how far below the top the interior is
#: cancellous bone rather than marrow (mm), and how far below the planned cut the field of view reaches (mm).
#: An ilium's cortical tables are thinner than a tibial shaft's and hold cancellous bone between them.
ANATOMY = {
    "long-bone": {"cortex_mm": 2.5, "cancellous_below_top_mm": 60.0, "below_cut_mm": 110.0},
    "flat-bone": {"cortex_mm": 1.5, "cancellous_below_top_mm": np.inf, "below_cut_mm": 100.0},
}
SOFT_TISSUE_MM = 15.0
NOISE_HU = 25.0
#: Where the field of view cuts a sphere: this far beyond its centre (mm), so about a third of it is missing.
CUT_BEYOND_CENTRE_MM = 1.5
#: Every file ``write_phantom`` writes, with its frame.
FILE_FRAMES = {
    "ct": "LPS (the NRRD header's 'space'; Slicer converts it to RAS on loading)",
    "truth": "RAS (Slicer's world frame, as every point this program reports), mm",
    "bone_surface": "LPS (the SPACE=LPS tag Slicer writes in model files; read back to RAS)",
    "marker_centres": "LPS in the file (coordinateSystem: LPS, as Slicer writes markups); RAS once loaded",
}


@dataclass(frozen=True)
class PhantomTruth:
    """Ground truth of a CT phantom, all in the image's RAS frame (mm).

    ``marker_defects`` maps a marker number (1 to 4, the tool's order) to 'partial' or 'deformed';
    ``cut_marker`` is the number of the sphere the field of view cuts, or None.
    """

    reference_to_image: np.ndarray
    marker_centres: np.ndarray  # (4, 3) true sphere centres
    marker_radius_mm: float
    marker_defects: dict
    bone_vertices: np.ndarray
    bone_triangles: np.ndarray
    cut_marker: int = None
    settings: dict = field(default_factory=dict)

    def to_dict(self):
        return {
            "coordinate_system": "RAS",
            "units": "mm",
            "reference_to_image": self.reference_to_image.tolist(),
            "marker_centres": self.marker_centres.tolist(),
            "marker_numbers": list(range(1, len(self.marker_centres) + 1)),
            "marker_radius_mm": self.marker_radius_mm,
            "marker_defects": {str(k): v for k, v in sorted(self.marker_defects.items())},
            "cut_marker": self.cut_marker,
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
    body=None,
    metal=None,
    direction=LPS_DIRECTION,
    cut_marker=None,
    progress=None,
):
    """Render a CT phantom of a virtual patient.

    Args:
        patient: VirtualPatient (its reference_to_image and markers_reference place the reference body).
        vertices, triangles: the bone mesh in image coordinates (RAS mm).
        seed: fixes the noise.
        spacing: voxel size (mm) along i, j, k; the paper's is 0.5 x 0.5 x 0.625.
        noise_hu: standard deviation of the image noise (HU); 40-60 for a low-dose scan.
        defects: optional {marker number (1 to 4): 'partial' | 'deformed'}.
        margin_mm: field of view beyond the markers and the bone region, on every side.
        below_cut_mm: how far below the osteotomy cut the bone region reaches (default: ``ANATOMY``'s).
        body: ReferenceBodyModel (plastic posts and frame by default).
        metal: None, a MetalRod, or 'pin' for ``fixation_pin(patient)``: a 5 mm steel pin from inside the
            bracket through the shaft.
        direction: (3, 3) RAS directions of the grid's i, j, k axes (columns); LPS-aligned by default.
        cut_marker: optional marker number (1 to 4) whose sphere the field of view cuts.
        progress: optional callable ``progress(step, done, total)`` called as bone, reference body and scan are
            painted (3 steps).

    Returns:
        (CTVolume, PhantomTruth).
    """
    body = body or ReferenceBodyModel()
    count = len(patient.markers_reference)
    check_noise(noise_hu)
    defects = check_defects(defects, count)
    spacing = np.asarray(spacing, dtype=np.float64)
    markers = patient.markers_image
    radius = MARKER_DIAMETER_MM / 2.0
    top = vertices[:, 2].max()
    anatomy = ANATOMY[patient.anatomy]
    if below_cut_mm is None:
        below_cut_mm = anatomy["below_cut_mm"]
    bone_region = vertices[vertices[:, 2] >= patient.cut_height_mm - below_cut_mm]
    volume = scanner_grid(
        np.vstack((bone_region, sphere_extremes(markers, radius, direction))), spacing, direction, margin_mm
    )
    if cut_marker is not None:
        volume = cut_through_sphere(volume, markers, radius, cut_marker)
    logger.info("CT phantom grid %s voxels of %s mm", volume.voxels.shape, spacing.tolist())
    progress = progress or (lambda step, done, total: None)
    progress("CT phantom", 0, 3)
    _paint_bone(volume, vertices, triangles, top, anatomy, np.random.default_rng(seed))
    progress("CT phantom", 1, 3)
    metal = paint_mounted_body(
        volume,
        patient.reference_to_image,
        patient.markers_reference,
        body,
        radius,
        defects,
        bone_anchor(patient, body),
        metal,
    )
    progress("CT phantom", 2, 3)
    scanned = scan(volume, noise_hu, seed + 1)
    progress("CT phantom", 3, 3)
    truth = PhantomTruth(
        reference_to_image=patient.reference_to_image.copy(),
        marker_centres=markers.copy(),
        marker_radius_mm=radius,
        marker_defects=defects,
        bone_vertices=vertices,
        bone_triangles=triangles,
        cut_marker=cut_marker,
        settings={
            "spacing_mm": spacing.tolist(),
            "shape": list(scanned.voxels.shape),
            "direction": np.asarray(direction, dtype=float).tolist(),
            "noise_hu": noise_hu,
            "psf_sigma_mm": PSF_SIGMA_MM,
            "hu": dict(HU),
            "anatomy": patient.anatomy,
            "cortex_thickness_mm": anatomy["cortex_mm"],
            "reference_body": body.to_dict(),
            "metal": None if metal is None else metal.to_dict(),
            "seed": seed,
        },
    )
    return scanned, truth


def bone_anchor(patient, body=None):
    """Where the bracket meets the bone (RAS mm): the IPC point nearest the frame's hub."""
    _, hub = reference_body_feet(patient.reference_to_image, patient.markers_reference, body or ReferenceBodyModel())
    return patient.ipc[np.argmin(np.linalg.norm(patient.ipc - hub, axis=1))]


def fixation_pin(patient, body=None):
    """The steel pin (MetalRod) that fixes the patient's bracket: from inside the bracket through the shaft."""
    _, hub = reference_body_feet(patient.reference_to_image, patient.markers_reference, body or ReferenceBodyModel())
    return pin_for_bracket(bone_anchor(patient, body), hub)


def cut_through_sphere(volume, centres, radius, number):
    """Crop a grid so that one of its faces cuts sphere ``number`` (1-based) ``CUT_BEYOND_CENTRE_MM`` beyond its
    centre: the face nearest that sphere among those that leave the other spheres wholly inside.

    Raises:
        ValueError: a bad number, or no face cuts that sphere alone.
    """
    if not 1 <= number <= len(centres):
        raise ValueError(f"cut marker {number}: markers are numbered 1 to {len(centres)}")
    last_index = np.array(volume.voxels.shape) - 1
    ijk = volume.ras_to_ijk_points(centres)
    spacing = volume.spacing
    target, others = ijk[number - 1], np.delete(ijk, number - 1, axis=0)
    faces = [(axis, side) for axis in range(3) for side in (0, 1)]
    gaps = [(target[a] if side == 0 else last_index[a] - target[a]) * spacing[a] for a, side in faces]
    for face in np.argsort(gaps):
        axis, side = faces[face]
        step, margin = CUT_BEYOND_CENTRE_MM / spacing[axis], (radius + 1.0) / spacing[axis]
        index, ijk_to_ras = [slice(None)] * 3, volume.ijk_to_ras.copy()
        if side == 0:
            first = int(np.ceil(target[axis] - step))
            if (others[:, axis] - margin < first).any():
                continue
            index[axis] = slice(first, None)
            ijk_to_ras[:3, 3] += ijk_to_ras[:3, axis] * first
        else:
            last = int(np.floor(target[axis] + step))
            if (others[:, axis] + margin > last).any():
                continue
            index[axis] = slice(0, last + 1)
        return CTVolume(voxels=np.ascontiguousarray(volume.voxels[tuple(index)]), ijk_to_ras=ijk_to_ras)
    raise ValueError(f"no edge of the field of view can cut marker {number} without cutting another sphere")


def write_phantom(directory, volume, truth):
    """Write a phantom to ``directory`` and return the paths written, by name.

    * ``ct.nrrd``: the CT, int16 HU, in LPS (the NRRD header says so);
    * ``truth.json``: the true marker centres and ``ReferenceToImage`` in **RAS** mm (stated in the file as
      ``coordinate_system``), the marker radius, defects and the cut sphere, the rendering settings, and each
      file's frame (``files``);
    * ``bone_surface.vtp``: the true bone surface **cut to the CT's field of view** (the box of its voxel
      centres), tagged LPS as Slicer writes models;
    * ``marker_centres.mrk.json``: the true marker centres as Slicer markups (M1 to M4, LPS in the file).
    """
    from pathlib import Path

    from ..image.volume_io import save_nrrd
    from ..io.file_checks import check_output_folder
    from ..io.point_files import write_points
    from ..io.surface_files import write_surface

    directory = Path(directory)
    check_output_folder(directory, "phantom folder")
    with atomic_folder(directory) as folder:  # all the files or none of them
        paths = {
            "ct": folder / "ct.nrrd",
            "truth": folder / "truth.json",
            "bone_surface": folder / "bone_surface.vtp",
            "marker_centres": folder / "marker_centres.mrk.json",
        }
        save_nrrd(paths["ct"], volume)
        surface_vertices, surface_triangles = clip_to_field_of_view(truth.bone_vertices, truth.bone_triangles, volume)
        write_surface(paths["bone_surface"], surface_vertices, surface_triangles)
        write_points(
            paths["marker_centres"],
            truth.marker_centres,
            labels=[f"M{n + 1}" for n in range(len(truth.marker_centres))],
        )
        files = {name: {"file": path.name, "frame": FILE_FRAMES[name]} for name, path in paths.items()}
        files["bone_surface"]["extent"] = "cut to the CT's field of view (the box of its voxel centres)"
        document = {**truth.to_dict(), "files": files}
        write_json_atomic(paths["truth"], document)
    return {name: directory / path.name for name, path in paths.items()}


def clip_to_field_of_view(vertices, triangles, volume):
    """The part of a surface (RAS vertices (V, 3), triangles (K, 3)) inside a CT's box of voxel centres.

    Triangles crossing the box's faces are cut exactly (VTK), so the surface ends at the field of view.
    """
    from vtkmodules.util.numpy_support import numpy_to_vtk
    from vtkmodules.vtkCommonCore import vtkPoints
    from vtkmodules.vtkCommonDataModel import vtkPlanes
    from vtkmodules.vtkFiltersCore import vtkClipPolyData, vtkTriangleFilter

    shape = np.array(volume.voxels.shape) - 1
    axes = volume.ijk_to_ras[:3, :3]
    origin, far = volume.ijk_to_ras[:3, 3], volume.ijk_to_ras_points(shape[None])[0]
    points, normals = [], []
    for axis in range(3):
        outward = axes[:, axis] / np.linalg.norm(axes[:, axis])
        points += [origin, far]
        normals += [-outward, outward]
    planes = vtkPlanes()
    plane_points = vtkPoints()
    plane_points.SetData(numpy_to_vtk(np.array(points, dtype=np.float64), deep=True))
    planes.SetPoints(plane_points)
    planes.SetNormals(numpy_to_vtk(np.array(normals, dtype=np.float64), deep=True))
    clip = vtkClipPolyData()
    clip.SetInputData(poly_data(vertices, triangles))
    clip.SetClipFunction(planes)
    clip.InsideOutOn()  # keep where every plane's function is negative: inside the box
    triangulate = vtkTriangleFilter()
    triangulate.SetInputConnection(clip.GetOutputPort())
    triangulate.Update()
    return triangle_arrays(triangulate.GetOutput())


def signed_distance_to_mesh(points, vertices, triangles, rng, samples=1_500_000):
    """Signed distance (mm, positive outside) of (N, 3) points near a closed mesh's surface.

    Point-to-plane distance to the nearest of ``samples`` surface samples with their normals (about 0.15 mm
    apart on a tibia): exact to well under 0.01 mm within a few mm of the surface, where it is used.
    """
    surface, normals = sample_surface(vertices, triangles, samples, rng)
    _, nearest = cKDTree(surface).query(points)
    return np.einsum("ij,ij->i", points - surface[nearest], normals[nearest])


def _paint_bone(volume, vertices, triangles, top, anatomy, rng):
    """Bone with partial volume from exact signed distances near the surface, soft tissue around it."""
    spacing = volume.spacing
    ramp = float(np.mean(spacing))
    vertices_ijk = volume.ras_to_ijk_points(vertices)
    margin = int(np.ceil((SOFT_TISSUE_MM + 3.0) / spacing.min()))
    low = np.maximum(np.floor(vertices_ijk.min(axis=0)).astype(int) - margin, 0)
    high = np.minimum(np.ceil(vertices_ijk.max(axis=0)).astype(int) + margin, np.array(volume.voxels.shape) - 1)
    box = tuple(slice(a, b + 1) for a, b in zip(low, high))
    box_shape = high - low + 1

    # Inside/outside of the closed mesh on the grid, scan-line by scan-line (VTK stencil), in index space.
    inside = mesh_inside_grid(vertices_ijk - low, triangles, box_shape)

    depth = ndimage.distance_transform_edt(inside, sampling=spacing)  # mm from the surface, inside
    outside_distance = ndimage.distance_transform_edt(~inside, sampling=spacing)
    signed = np.where(inside, -depth, outside_distance).astype(np.float32)

    # Near the surface replace the voxel-resolution distance by the exact one: point-to-plane distance to the
    # nearest of 1.5 million surface samples with their normals.
    band = np.abs(signed) < 2.0 * spacing.max()
    signed[band] = signed_distance_to_mesh(volume.ijk_to_ras_points(np.argwhere(band) + low), vertices, triangles, rng)

    # RAS height of every voxel of the box (the grid may be turned): cancellous bone in the epiphysis.
    row = volume.ijk_to_ras[2]
    ras_z = (
        row[3]
        + row[0] * np.arange(low[0], high[0] + 1)[:, None, None]
        + row[1] * np.arange(low[1], high[1] + 1)[None, :, None]
        + row[2] * np.arange(low[2], high[2] + 1)[None, None, :]
    )
    interior = np.where(ras_z > top - anatomy["cancellous_below_top_mm"], HU["cancellous"], HU["marrow"])
    cortex = np.clip((anatomy["cortex_mm"] + signed) / ramp + 0.5, 0.0, 1.0)  # 1 in the outer shell
    bone_hu = cortex * HU["cortex"] + (1.0 - cortex) * interior
    tissue = fraction_inside(signed - SOFT_TISSUE_MM, ramp)
    outside_hu = tissue * HU["soft_tissue"] + (1.0 - tissue) * HU["air"]
    bone = fraction_inside(signed, ramp)
    volume.voxels[box] = (bone * bone_hu + (1.0 - bone) * outside_hu).astype(np.float32)
