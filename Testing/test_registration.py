"""The whole registration (CR, CR-ICP, CR-RAMSICP) on the tibia virtual patient, with its warnings."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.registration import register
from RAMSICPRegistrationLib.core.transforms import apply_transform, invert_transform, make_transform


def _exact_case(patient, rng, marker_shift=(0.0, 0.0, 0.0), count=60):
    """Probe points that are IPC points all around the bone, exact markers shifted by a known vector."""
    image_to_reference = invert_transform(patient.reference_to_image)
    ppc = apply_transform(image_to_reference, patient.ipc[rng.choice(len(patient.ipc), count, replace=False)])
    targets_patient = apply_transform(image_to_reference, patient.targets_image)
    return dict(
        ppc=ppc,
        markers_image=patient.markers_image + marker_shift,
        markers_patient=patient.markers_reference,
        targets_image=patient.targets_image,
        targets_patient=targets_patient,
    )


def test_cr_with_a_known_marker_shift_has_that_tre(tibia_patient, tibia_index, rng):
    case = _exact_case(tibia_patient, rng, marker_shift=(0.6, 0.0, -0.8))
    result = register(tibia_index, method="cr", **case)
    assert result.tre_mm == pytest.approx(1.0, abs=1e-9)  # a pure 1 mm translation of every marker
    assert result.fre_mm == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(result.target_errors_mm, 1.0, atol=1e-9)
    assert result.iterations is None and result.scale is None


@pytest.mark.parametrize("method, options", [("cr-icp", {}), ("cr-ramsicp", {"scale": 5.0})])
def test_fine_registration_removes_a_known_cr_error(tibia_patient, tibia_index, rng, method, options):
    case = _exact_case(tibia_patient, rng, marker_shift=(0.3, -0.2, 0.2))
    result = register(tibia_index, method=method, **options, **case)
    assert result.tre_mm < 0.01
    assert result.ppc_rms_mm < 0.01
    np.testing.assert_allclose(result.reference_to_image, tibia_patient.reference_to_image, atol=1e-3)
    assert result.converged


def test_sweep_reports_every_l_and_the_chosen_one(tibia_patient, tibia_index):
    trial = tibia_patient.simulate_trial(np.random.default_rng(4), marker_fle_mm=1.0)
    result = register(
        tibia_index,
        trial.ppc,
        trial.markers_image,
        trial.markers_patient,
        trial.targets_image,
        trial.targets_patient,
        method="cr-ramsicp",
        sweep=True,
    )
    assert [entry.scale for entry in result.sweep] == pytest.approx(np.arange(1.0, 5.01, 0.2))
    assert result.scale_policy == "targets"
    assert result.tre_mm == pytest.approx(min(entry.tre_mm for entry in result.sweep))
    assert any("for evaluation" in warning for warning in result.warnings)
    document = result.to_dict()
    for key in (
        "method",
        "reference_to_image",
        "fre_mm",
        "ppc_rms_mm",
        "tre_mm",
        "scale",
        "iterations",
        "residuals_mm",
        "sweep",
        "warnings",
    ):
        assert key in document
    no_targets = register(
        tibia_index, trial.ppc, trial.markers_image, trial.markers_patient, method="cr-ramsicp", sweep=True
    )
    assert no_targets.scale_policy == "rms-plateau" and no_targets.tre_mm is None


def test_medial_face_points_warn_about_the_weak_direction(tibia_patient, tibia_index):
    trial = tibia_patient.simulate_trial(np.random.default_rng(5), marker_fle_mm=1.0)
    result = register(tibia_index, trial.ppc, trial.markers_image, trial.markers_patient, method="cr-icp")
    assert any("poorly constrain the pose" in warning for warning in result.warnings)


def test_markers_in_the_wrong_order_are_reported(tibia_patient, tibia_index, rng):
    case = _exact_case(tibia_patient, rng)
    case["markers_image"] = case["markers_image"][[1, 0, 2, 3]]
    result = register(tibia_index, method="cr", **case)
    assert any("same order as the tool's" in warning for warning in result.warnings)


def test_a_probe_point_off_the_bone_is_named(tibia_patient, tibia_index, rng):
    case = _exact_case(tibia_patient, rng)
    case["ppc"][7] += 25.0 * np.array([0.0, 1.0, 0.0]) @ tibia_patient.reference_to_image[:3, :3]
    result = register(tibia_index, method="cr-icp", **case)
    assert result.residuals_mm[7] > 5.0
    assert any("lie far from the bone surface" in warning and " 7 (" in warning for warning in result.warnings)


@pytest.mark.parametrize(
    "change, message",
    [
        ({"method": "icp"}, "method 'icp': use one of cr, cr-icp, cr-ramsicp, cr-fused"),
        ({"method": "cr-icp", "sweep": True}, "apply to cr-ramsicp only"),
        ({"method": "cr-fused", "policy": "rms-plateau"}, "apply to cr-ramsicp only"),
        ({"method": "cr-fused", "fle_mm": -1.0}, "marker error (FLE) -1.0 mm: give a positive number"),
        ({"method": "cr-fused", "probe_noise_mm": float("nan")}, "probe noise nan mm: give a positive number"),
        ({"ppc": np.zeros((2, 3))}, "PPC (probe points): 2 point(s) given, at least 3 needed"),
        ({"ppc": np.outer(np.arange(5.0), (1.0, 2.0, 3.0))}, "PPC (probe points): the points are (nearly) collinear"),
        ({"markers_image": np.zeros((2, 3))}, "markers in the image: 2 point(s) given, at least 3 needed"),
        (
            {"markers_image": np.eye(3)},
            "markers in the patient (reference) has 4 points but markers in the image has 3",
        ),
        ({"targets_image": np.zeros((4, 3))}, "give them in both frames"),
        ({"targets_image": np.zeros((3, 3)), "targets_patient": np.zeros((4, 3))}, "3 in the image"),
        ({"method": "cr-ramsicp", "policy": "targets"}, "ask for the sweep"),
        ({"method": "cr-ramsicp", "sweep": True, "policy": "targets"}, "needs target points"),
        ({"method": "cr-ramsicp", "scale": 0.5}, "must be a finite number >= 1"),
    ],
)
def test_bad_requests_raise_clear_errors(tibia_patient, tibia_index, rng, change, message):
    case = _exact_case(tibia_patient, rng, count=10)
    del case["targets_image"], case["targets_patient"]
    case.update(change)
    with pytest.raises(ValueError) as error:
        register(tibia_index, **case)
    assert message in str(error.value)


def test_ipc_may_be_given_as_an_array():
    plane_with_bump = np.random.default_rng(0).uniform(-30, 30, size=(20000, 3))
    plane_with_bump[:, 2] = 0.01 * (plane_with_bump[:, 0] ** 2 + 2 * plane_with_bump[:, 1] ** 2)
    markers = np.array([[0.0, 0.0, 0.0], [50.0, 0.0, 0.0], [0.0, 40.0, 0.0], [0.0, 0.0, 30.0]])
    pose = make_transform(translation=(1.0, 2.0, 3.0))
    ppc = apply_transform(invert_transform(pose), plane_with_bump[:50])
    result = register(plane_with_bump, ppc, apply_transform(pose, markers), markers, method="cr-icp")
    np.testing.assert_allclose(result.reference_to_image, pose, atol=1e-6)
