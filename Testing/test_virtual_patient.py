"""The demo's virtual patient: its geometry and its error model give what they promise."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.metrics import target_registration_error
from RAMSICPRegistrationLib.core.paired_point import fit_rigid_transform
from RAMSICPRegistrationLib.simulation.virtual_patient import sample_surface


def test_surface_samples_lie_on_triangles_with_outward_normals():
    # A unit cube's 12 triangles, wound outward: every sample has one coordinate at 0 or 1.
    vertices = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    faces = np.array(
        [
            [0, 1, 3],
            [0, 3, 2],
            [4, 6, 7],
            [4, 7, 5],
            [0, 4, 5],
            [0, 5, 1],
            [2, 3, 7],
            [2, 7, 6],
            [0, 2, 6],
            [0, 6, 4],
            [1, 5, 7],
            [1, 7, 3],
        ]
    )
    points, normals = sample_surface(vertices, faces, 5000, np.random.default_rng(0))
    on_face = np.isclose(points, 0.0) | np.isclose(points, 1.0)
    assert on_face.any(axis=1).all()
    centre = np.full(3, 0.5)
    assert np.all(np.sum((points - centre) * normals, axis=1) > 0)  # outward
    assert abs(np.mean(np.isclose(points[:, 0], 1.0)) - 1 / 6) < 0.02  # uniform by area


def test_geometry_of_the_tibia_patient(tibia_patient, tibia_index):
    patient = tibia_patient
    assert len(patient.ipc) == 200_000
    assert len(patient.sub_area_points) == 8 and min(len(area) for area in patient.sub_area_points) > 100
    distances, _ = tibia_index.nearest(patient.targets_image)
    assert distances.max() < 0.6  # targets are on the bone surface, at the cut height
    np.testing.assert_allclose(patient.targets_image[:, 2], patient.cut_height_mm, atol=0.3)
    spacing = np.linalg.norm(patient.markers_image[:, None] - patient.markers_image[None], axis=2)
    reference_spacing = np.linalg.norm(patient.markers_reference[:, None] - patient.markers_reference[None], axis=2)
    np.testing.assert_allclose(spacing, reference_spacing, atol=1e-9)  # a rigid pose
    bone_distance, _ = tibia_index.nearest(patient.markers_image)
    assert bone_distance.min() > 30.0  # the reference body is beside the bone, on a bracket


def test_trial_error_model(tibia_patient, tibia_index):
    rng = np.random.default_rng(3)
    trials = [tibia_patient.simulate_trial(rng, marker_fle_mm=1.0, probe_noise_mm=0.25) for _ in range(50)]
    trial = trials[0]
    assert trial.ppc.shape == (40, 3) and np.bincount(trial.sub_area).tolist() == [0] + [5] * 8
    # The same seed draws the same touched points; only the probe noise differs: 0.25 mm RMS in 3-D.
    clean = tibia_patient.simulate_trial(np.random.default_rng(9), 1.0, probe_noise_mm=0.0)
    noisy = tibia_patient.simulate_trial(np.random.default_rng(9), 1.0, probe_noise_mm=0.25)
    on_surface = np.vstack(tibia_patient.sub_area_points)
    from RAMSICPRegistrationLib.core.transforms import apply_transform

    clean_in_image = apply_transform(tibia_patient.reference_to_image, clean.ppc)
    assert np.min(np.linalg.norm(on_surface[None] - clean_in_image[:, None], axis=2), axis=1).max() < 1e-9
    probe_noise = np.linalg.norm(noisy.ppc - clean.ppc, axis=1)
    assert np.sqrt(np.mean(probe_noise**2)) == pytest.approx(0.25, rel=0.2)
    marker_errors = np.concatenate(
        [np.linalg.norm(t.markers_image - tibia_patient.markers_image, axis=1) for t in trials]
    )
    assert np.sqrt(np.mean(marker_errors**2)) == pytest.approx(1.0, rel=0.1)


def test_marker_error_calibration_gives_the_requested_cr_tre(tibia_patient):
    fle = tibia_patient.marker_fle_for_cr_tre(1.33)
    rng = np.random.default_rng(11)
    tres = []
    for _ in range(1500):
        trial = tibia_patient.simulate_trial(rng, marker_fle_mm=fle)
        coarse = fit_rigid_transform(trial.markers_patient, trial.markers_image).transform
        tres.append(target_registration_error(coarse, trial.targets_patient, trial.targets_image))
    assert np.mean(tres) == pytest.approx(1.33, rel=0.04)


def test_geometry_of_the_ilium_patient(ilium):
    from RAMSICPRegistrationLib.core.surface_index import SurfaceIndex

    patient, vertices, _ = ilium
    assert patient.anatomy == "flat-bone"
    index = SurfaceIndex(patient.ipc)
    distances, _ = index.nearest(patient.targets_image)
    assert distances.max() < 0.6  # the 4 targets are on the bone surface, at the cut's height
    np.testing.assert_allclose(patient.targets_image[:, 2], patient.cut_height_mm, atol=0.3)
    assert patient.cut_height_mm == pytest.approx(vertices[:, 2].max() - 30.0)
    lateral_ends, medial_ends = patient.targets_image[:2], patient.targets_image[2:]
    # Two ends on the lateral table, 40 mm apart along the cut; across the wing, the medial table's two ends.
    chord = np.linalg.norm(lateral_ends[1] - lateral_ends[0])
    assert 40.0 <= chord < 50.0  # 40 mm along the cut's line, a little more across the curved face
    thickness = np.linalg.norm(lateral_ends - medial_ends, axis=1)
    assert np.all((thickness > 3.0) & (thickness < 25.0))
    assert np.all(lateral_ends[:, 0] > medial_ends[:, 0])  # lateral is +x for a right bone
    # 8 sub-areas on the lateral face, 4 levels below the cut (15 to 60 mm) in 2 columns.
    centres = np.array([area.mean(axis=0) for area in patient.sub_area_points])
    assert min(len(area) for area in patient.sub_area_points) > 100
    np.testing.assert_allclose(patient.cut_height_mm - centres[::2, 2], [15.0, 30.0, 45.0, 60.0], atol=2.0)
    spacing = np.linalg.norm(patient.markers_image[:, None] - patient.markers_image[None], axis=2)
    reference_spacing = np.linalg.norm(patient.markers_reference[:, None] - patient.markers_reference[None], axis=2)
    np.testing.assert_allclose(spacing, reference_spacing, atol=1e-9)  # a rigid pose
    bone_distance, _ = index.nearest(patient.markers_image)
    assert bone_distance.min() > 30.0  # the reference body is beside the bone, on a bracket
