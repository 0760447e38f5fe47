"""The other minima of F1 a few probe points leave (``core.pose_modes``) and what they add to the predicted error."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.core import registration
from RAMSICPRegistrationLib.core.registration import register
from RAMSICPRegistrationLib.core.surface_index import SurfaceIndex
from RAMSICPRegistrationLib.core.transforms import apply_transform


@pytest.fixture(scope="module")
def fibula():
    from RAMSICPRegistrationLib.simulation.package_data import shipped_patient

    patient = shipped_patient("right-fibula")[0]
    return patient, SurfaceIndex(patient.ipc)


@pytest.mark.parametrize("seed", [2, 17])
def test_a_wrong_basin_of_the_fibula_is_predicted_by_the_mode_the_truth_lies_in(fibula, seed, monkeypatch):
    """The fibula, an FLE of 2.5 mm, the 5 points of one sub-area: trials 2 and 17 end 10.6 and 7.8 mm off at the
    targets, beyond the single Gaussian's 95 % bound (6.1 and 4.6 mm), because the points fit the shaft as well where
    the truth is. The search finds that minimum (within 4 mm of the truth at every target, a quarter or more of the
    posterior), the bound then reaches the error, and the pose is the one registered without the search.

    Which other minima the refits land in depends on the last bits of the linear algebra: OpenBLAS's AVX-512 and
    AVX2 kernels give trial 2 two and five minima, and a bound of 9.7-10.6 and 10.2-11.2 mm against errors of
    9.9-10.6 mm. So the bound must reach 95 % of the error, not all of it (the single Gaussian's reaches 57-61 %)."""
    patient, index = fibula
    rng = np.random.default_rng(seed)
    trial = patient.simulate_trial(rng, 2.5, sub_areas=(int(rng.integers(1, 9)),))
    case = (trial.ppc, trial.markers_image, trial.markers_patient, trial.targets_image, trial.targets_patient)
    result = register(index, *case)
    monkeypatch.setattr(registration, "searched", lambda fit, count: False)
    alone = register(index, *case)
    np.testing.assert_array_equal(result.reference_to_image, alone.reference_to_image)
    assert alone.uncertainty.mode_weights is None
    assert np.all(alone.predicted_tre_95_mm < result.target_errors_mm)
    assert np.all(result.target_errors_mm < result.predicted_tre_95_mm / 0.95)
    error = apply_transform(result.reference_to_image, trial.targets_patient) - trial.targets_image
    uncertainty, targets = result.uncertainty, trial.targets_image
    near = [
        share for share, motion in zip(uncertainty.mode_weights, uncertainty.mode_motions)
        if np.all(np.linalg.norm(apply_transform(motion, targets) - targets - error, axis=1) < 4.0)
    ]  # fmt: skip
    assert result.tre_mm > 7.0 and max(near) > 0.25


def test_forty_points_are_not_searched_and_a_single_basin_adds_nothing(tibia_patient, tibia_index):
    """40 points (the demo's) leave the prediction as it was; 5 points on the tibia with an FLE of 0.5 mm search and
    find no other minimum within the markers' reach, so the prediction is unchanged too."""
    rng = np.random.default_rng(5)
    trial = tibia_patient.simulate_trial(rng, 1.0)
    result = register(tibia_index, trial.ppc, trial.markers_image, trial.markers_patient, trial.targets_image)
    assert len(trial.ppc) == 40 and result.uncertainty.mode_weights is None
    trial = tibia_patient.simulate_trial(rng, 0.5, sub_areas=(3,))
    result = register(tibia_index, trial.ppc, trial.markers_image, trial.markers_patient, trial.targets_image)
    assert len(trial.ppc) == 5 and len(result.uncertainty.mode_weights) == 0
