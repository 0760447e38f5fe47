"""A virtual patient built from a real bone mesh, for the demo and the tests.

It follows the paper's set-up ("Data acquisition", "Experimental preparation"), on two kinds of bone:

* ``long-bone`` (tibia, fibula): 8 probe sub-areas SA1-SA8 (4 levels x 2 columns) on the smooth medial face
  of the proximal shaft, below a planned high tibial osteotomy; the 4 targets are the medial, lateral,
  anterior and posterior ends of the cut, the endpoints of a horizontal cut across the whole bone planned on the
  IPC (``core.osteotomy.plan_cut``).
* ``flat-bone`` (the ilium, the paper's own subject): the sub-areas on the smooth lateral (gluteal) face of the
  wing (Fig. 4c), 4 levels x 2 columns below a planned cut across the upper wing; the 4 targets are the
  endpoints of that 40 mm cut on the lateral and the medial surface, the corners of the resected face (Fig. 6b).

Both have the image side (the IPC, ``ipc_points`` surface samples of the bone in image (RAS) coordinates, and the
4 marker-sphere centres of an NDI reference body fixed beside the bone on a bracket) and the patient side (the
reference frame of that body, related to the image by a known ``reference_to_image``); 5 points are touched in
each sub-area.

The IPC here is sampled on the mesh; ``ct_phantom.make_ct_phantom`` renders the same patient as a CT, whose
image side replaces it, and ``simulate_trial`` serves both.

The **exposed surface** is the bone the surgeon lays bare to touch: the true surface within ``EXPOSURE_MARGIN_MM`` of
the sub-areas and facing the same way as they do (within ``EXPOSURE_ANGLE_DEG``). Touches anywhere on it
(``touch``, ``random_touches``) serve the guided experiment (``experiments.guided``): where the touch guidance
sends the probe, and where a surgeon touching freely might.
"""

from dataclasses import dataclass

import numpy as np

from ..core.metrics import target_registration_error
from ..core.osteotomy import plan_cut
from ..core.paired_point import rigid_procrustes
from ..core.transforms import apply_transform, invert_transform, make_transform, rotation_about_axis

PAPER_IPC_POINTS = 194_568
#: The exposed surface reaches this far (mm) beyond the sub-areas ...
EXPOSURE_MARGIN_MM = 15.0
#: ... where the bone faces within this angle (degrees) of the sub-areas' mean outward normal.
EXPOSURE_ANGLE_DEG = 60.0
ANATOMIES = ("long-bone", "flat-bone")
#: Height of the planned cut below the top of the bone (mm): a high tibial osteotomy, a cut across the upper wing.
CUT_BELOW_TOP_MM = {"long-bone": 40.0, "flat-bone": 30.0}
#: Length of the planned cut across the wing (mm); its ends on both surfaces are the targets.
PLATE_CUT_LENGTH_MM = 40.0
#: Where the probe points and the targets are, in words, by anatomy (for reports).
LAYOUT_WORDS = {
    "long-bone": {"probe": "the smooth medial face of the shaft", "targets": "the ends of a high tibial osteotomy cut"},
    "flat-bone": {
        "probe": "the smooth lateral face of the wing",
        "targets": f"the corners of a {PLATE_CUT_LENGTH_MM:g} mm cut across the upper wing",
    },
}


@dataclass(frozen=True)
class TrialData:
    """One simulated acquisition. Patient-side arrays are in reference coordinates, image-side in RAS (mm)."""

    ppc: np.ndarray  # (N, 3) probe points
    sub_area: np.ndarray  # (N,) sub-area number 1..8 of each probe point
    markers_patient: np.ndarray  # (4, 3) marker centres from the tool geometry (tracked)
    markers_image: np.ndarray  # (4, 3) marker centres placed in the image, with placement error
    targets_patient: np.ndarray  # (4, 3) targets touched with the probe (mean of 10 touches)
    targets_image: np.ndarray  # (4, 3) targets in the image


@dataclass(frozen=True)
class VirtualPatient:
    """Ground truth of a virtual patient; see the module docstring."""

    ipc: np.ndarray
    reference_to_image: np.ndarray
    markers_reference: np.ndarray
    targets_image: np.ndarray
    sub_area_points: tuple  # 8 arrays (K_j, 3): true surface points of each sub-area, image coordinates
    cut_height_mm: float
    anatomy: str = "long-bone"  # one of ANATOMIES
    exposed_points: np.ndarray = None  # (E, 3) true surface points of the exposed bone, image coordinates

    @classmethod
    def from_mesh(
        cls,
        vertices,
        triangles,
        markers_reference,
        lateral_direction,
        anatomy="long-bone",
        seed=0,
        ipc_points=200_000,
        cut_below_top_mm=None,
        bracket_offset_mm=(75.0, 45.0),
        turn_deg=20.0,
    ):
        """Build the virtual patient from a closed bone mesh (RAS mm, +z superior).

        Args:
            vertices, triangles: the mesh, (V, 3) and (K, 3).
            markers_reference: (4, 3) marker centres of the reference body in its own frame (mm).
            lateral_direction: (3,) RAS direction that is lateral for this bone (+x for a right bone).
            anatomy: 'long-bone' (probe points on the medial shaft) or 'flat-bone' (on the lateral face of the wing).
            seed: fixes the IPC sampling and so the whole patient.
            ipc_points: IPC size; the paper's IPC has 194,568 points.
            cut_below_top_mm: height of the osteotomy cut below the top of the bone (default CUT_BELOW_TOP_MM).
            bracket_offset_mm: (lateral, anterior) offset of the reference body from the bone.
            turn_deg: rotation of the reference body's marker plane about the bone's axis, from facing anterior.
        """
        if anatomy not in ANATOMIES:
            raise ValueError(f"anatomy {anatomy!r}: use one of {', '.join(ANATOMIES)}")
        rng = np.random.default_rng(seed)
        ipc, _ = sample_surface(vertices, triangles, ipc_points, rng)
        dense, dense_normals = sample_surface(vertices, triangles, 400_000, rng)
        lateral = np.asarray(lateral_direction, dtype=np.float64)
        anterior = np.array([0.0, 1.0, 0.0])
        if cut_below_top_mm is None:
            cut_below_top_mm = CUT_BELOW_TOP_MM[anatomy]
        cut_height = vertices[:, 2].max() - cut_below_top_mm
        if anatomy == "long-bone":
            targets = _cut_end_points(ipc, cut_height, -lateral, anterior)
            sub_areas = _medial_face_sub_areas(dense, dense_normals, cut_height, -lateral, anterior)
            anchor = _section_centre(ipc, cut_height - 60.0)
            facing = anterior
        else:
            face = _face_normal(dense, dense_normals, cut_height, lateral)
            targets = _plate_cut_end_points(dense, dense_normals, cut_height, face)
            sub_areas = _plate_face_sub_areas(dense, dense_normals, cut_height, face, targets)
            # On a bracket out of the middle of the face, its marker plane facing the same way (and the camera).
            anchor = np.vstack(sub_areas).mean(axis=0)
            along = _along_face(face)
            facing = np.cross(along, (0.0, 0.0, 1.0))  # the face's normal made horizontal: the tool stands upright
            lateral, anterior = face, along if along[1] > 0 else -along
        reference_to_image = _reference_body_pose(
            markers_reference, anchor, lateral, anterior, bracket_offset_mm, turn_deg, facing
        )
        return cls(
            ipc=ipc,
            reference_to_image=reference_to_image,
            markers_reference=markers_reference,
            targets_image=targets,
            sub_area_points=sub_areas,
            cut_height_mm=float(cut_height),
            anatomy=anatomy,
            exposed_points=_exposed_surface(dense, dense_normals, sub_areas),
        )

    @property
    def markers_image(self):
        """True marker centres in image coordinates, (4, 3) mm."""
        return apply_transform(self.reference_to_image, self.markers_reference)

    def marker_fle_for_cr_tre(self, cr_tre_mm, seed=0, trials=2000):
        """Marker placement error (RMS, mm) that gives a mean CR TRE (eq. 11) of ``cr_tre_mm`` at the targets.

        The CR's TRE grows in proportion to the marker error, so one Monte Carlo run at 1 mm (``trials`` CR
        fits, deterministic under ``seed``) gives the factor.
        """
        rng = np.random.default_rng(seed)
        true_markers = self.markers_image
        targets_reference = apply_transform(invert_transform(self.reference_to_image), self.targets_image)
        tre_per_mm = np.empty(trials)
        for trial in range(trials):
            placed = true_markers + _isotropic_noise(rng, true_markers.shape, 1.0)
            coarse = rigid_procrustes(self.markers_reference, placed)
            tre_per_mm[trial] = target_registration_error(coarse, targets_reference, self.targets_image)
        return float(cr_tre_mm / tre_per_mm.mean())

    def simulate_trial(
        self, rng, marker_fle_mm, probe_noise_mm=0.25, points_per_area=5, sub_areas=None, target_touches=10
    ):
        """Simulate one registration's acquisitions.

        Args:
            rng: numpy Generator.
            marker_fle_mm: RMS 3-D error of each marker centre placed in the image (the paper's manual placement).
            probe_noise_mm: RMS 3-D error of a probe-tip touch.
            points_per_area: probe points touched in each sub-area (the paper: 5).
            sub_areas: sub-area numbers (1..8) to touch; all 8 by default.
            target_touches: each patient-side target is the mean of this many touches (the paper: 10).
        """
        sub_areas = tuple(range(1, 9)) if sub_areas is None else tuple(sub_areas)
        image_to_reference = invert_transform(self.reference_to_image)
        touched, labels = [], []
        for area in sub_areas:
            candidates = self.sub_area_points[area - 1]
            chosen = candidates[rng.choice(len(candidates), size=points_per_area, replace=False)]
            touched.append(chosen)
            labels.extend([area] * points_per_area)
        ppc = apply_transform(image_to_reference, np.vstack(touched))
        ppc = ppc + _isotropic_noise(rng, ppc.shape, probe_noise_mm)
        markers_image = self.markers_image + _isotropic_noise(rng, (4, 3), marker_fle_mm)
        targets_patient = apply_transform(image_to_reference, self.targets_image)
        targets_patient = targets_patient + _isotropic_noise(rng, (4, 3), probe_noise_mm / np.sqrt(target_touches))
        return TrialData(
            ppc=ppc,
            sub_area=np.array(labels),
            markers_patient=self.markers_reference.copy(),
            markers_image=markers_image,
            targets_patient=targets_patient,
            targets_image=self.targets_image.copy(),
        )

    def touch(self, rng, points_image, probe_noise_mm=0.25):
        """Probe touches (N, 3) in reference coordinates at the exposed surface's points nearest to the (N, 3) image
        points asked for, each with the probe's isotropic noise (``probe_noise_mm`` RMS 3-D)."""
        from scipy.spatial import cKDTree

        _, nearest = cKDTree(self.exposed_points).query(np.asarray(points_image, dtype=np.float64).reshape(-1, 3))
        touched = apply_transform(invert_transform(self.reference_to_image), self.exposed_points[nearest])
        return touched + _isotropic_noise(rng, touched.shape, probe_noise_mm)

    def random_touches(self, rng, count, probe_noise_mm=0.25):
        """``count`` probe touches (count, 3) in reference coordinates, drawn uniformly over the exposed surface's
        area (its points are area-uniform), each with the probe's noise."""
        chosen = self.exposed_points[rng.choice(len(self.exposed_points), size=count, replace=False)]
        touched = apply_transform(invert_transform(self.reference_to_image), chosen)
        return touched + _isotropic_noise(rng, touched.shape, probe_noise_mm)


def sample_surface(vertices, triangles, count, rng):
    """``count`` points uniformly distributed over a triangle mesh's area, with outward face normals.

    Returns:
        points (count, 3) and unit normals (count, 3); normals point outward for a mesh with positive volume.
    """
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    cross = np.cross(b - a, c - a)
    areas = 0.5 * np.linalg.norm(cross, axis=1)
    faces = rng.choice(len(triangles), size=count, p=areas / areas.sum())
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1.0
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    points = a[faces] + u[:, None] * (b - a)[faces] + v[:, None] * (c - a)[faces]
    normals = cross[faces] / (2.0 * areas[faces])[:, None]
    return points, normals


def _exposed_surface(points, normals, sub_areas):
    """(E, 3) the surface points (of ``points`` (N, 3), outward ``normals`` (N, 3)) within ``EXPOSURE_MARGIN_MM`` of
    the sub-areas and facing within ``EXPOSURE_ANGLE_DEG`` of their mean outward normal."""
    from scipy.spatial import cKDTree

    touched = np.vstack(sub_areas)
    distances, _ = cKDTree(touched).query(points, distance_upper_bound=EXPOSURE_MARGIN_MM)
    inside = np.isfinite(distances)
    facing = normals[distances == 0.0].mean(axis=0)  # the sub-areas' own points are among ``points``
    facing /= np.linalg.norm(facing)
    return points[inside & (normals @ facing > np.cos(np.radians(EXPOSURE_ANGLE_DEG)))]


def _isotropic_noise(rng, shape, rms_mm):
    """Gaussian noise whose 3-D RMS magnitude is ``rms_mm`` (per-axis sigma = rms / sqrt(3))."""
    return rng.normal(scale=rms_mm / np.sqrt(3.0), size=shape)


def _section_centre(points, height, half_thickness=1.0):
    section = points[np.abs(points[:, 2] - height) < half_thickness]
    return section.mean(axis=0)


def _cut_end_points(ipc, height, medial, anterior):
    """The medial, lateral, anterior and posterior ends of the bone's cross-section at ``height``: the endpoints
    of a horizontal cut across the whole bone (``core.osteotomy``), across medial and the blade advancing anterior.
    """
    return plan_cut(ipc, (0.0, 0.0, height), np.cross(medial, anterior), depth=anterior).endpoints


def _medial_face_sub_areas(points, normals, cut_height, medial, anterior, radius_mm=6.0):
    """8 patches of true surface points on the medial face: 4 levels below the cut x 2 columns."""
    face_normal = (medial + anterior) / np.linalg.norm(medial + anterior)
    up = np.array([0.0, 0.0, 1.0])
    areas = []
    for level in cut_height - np.array([20.0, 40.0, 60.0, 80.0]):
        band = np.abs(points[:, 2] - level) < 1.0
        for angle in (np.radians(20.0), np.radians(-20.0)):
            direction = rotation_about_axis(up, angle) @ face_normal
            score = np.where(band, normals @ direction, -np.inf)
            centre = points[np.argmax(score)]
            patch = np.linalg.norm(points - centre, axis=1) < radius_mm
            areas.append(points[patch & (normals @ direction > 0.5)])
    return tuple(areas)


def _face_normal(points, normals, cut_height, lateral, depth_mm=(10.0, 70.0)):
    """Mean outward normal (3,) of a plate's lateral face between ``depth_mm`` below the cut."""
    band = (points[:, 2] < cut_height - depth_mm[0]) & (points[:, 2] > cut_height - depth_mm[1])
    facing = band & (normals @ lateral > 0.5)
    mean = normals[facing].mean(axis=0)
    return mean / np.linalg.norm(mean)


def _along_face(face):
    """Unit horizontal direction (3,) lying in a face whose normal is ``face``."""
    along = np.cross((0.0, 0.0, 1.0), face)
    return along / np.linalg.norm(along)


def _plate_cut_end_points(points, normals, height, face, length_mm=PLATE_CUT_LENGTH_MM):
    """The 4 corners of a cut across a plate at ``height``: its two ends on the face and on the opposite surface.

    The cut runs ``length_mm`` horizontally along the face, centred on the face's middle at that height; each
    corner is the surface point of the section nearest to the cut's end line.
    """
    along = _along_face(face)
    section = np.abs(points[:, 2] - height) < 0.3
    corners = []
    for side in (1.0, -1.0):  # the face, then the opposite (medial) surface
        wall = points[section & (side * (normals @ face) > 0.3)]
        centre = np.median(points[section & (normals @ face > 0.3)] @ along)
        for end in (centre - length_mm / 2.0, centre + length_mm / 2.0):
            corners.append(wall[np.argmin(np.abs(wall @ along - end))])
    return np.array(corners)


def _plate_face_sub_areas(points, normals, cut_height, face, targets, radius_mm=6.0):
    """8 patches of true surface points on a plate's face: 4 levels below the cut x 2 columns."""
    along = _along_face(face)
    middle = float(np.mean(targets[:2] @ along))
    areas = []
    for level in cut_height - np.array([15.0, 30.0, 45.0, 60.0]):
        band = (np.abs(points[:, 2] - level) < 1.0) & (normals @ face > 0.7)
        for column in (middle - 15.0, middle + 15.0):
            centre = points[band][np.argmin(np.abs(points[band] @ along - column))]
            patch = np.linalg.norm(points - centre, axis=1) < radius_mm
            areas.append(points[patch & (normals @ face > 0.5)])
    return tuple(areas)


def _reference_body_pose(markers, bone_centre, lateral, anterior, offset_mm, turn_deg, facing):
    """ReferenceToImage of a reference body on a bracket lateral-anterior of the bone.

    The tool's marker plane normal (+x of NDI passive tools) points along ``facing`` (horizontal), towards the
    camera, turned ``turn_deg`` about the bone's axis; its long axis (+z) runs along the bone.
    """
    x_axis = rotation_about_axis((0.0, 0.0, 1.0), np.radians(turn_deg)) @ facing
    z_axis = np.array([0.0, 0.0, 1.0])
    rotation = np.column_stack((x_axis, np.cross(z_axis, x_axis), z_axis))
    centre = bone_centre + offset_mm[0] * lateral + offset_mm[1] * anterior
    return make_transform(rotation, centre - rotation @ markers.mean(axis=0))
