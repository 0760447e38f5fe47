"""The predicted error's distribution (``core.error_prediction``): known distributions, then coverage on trials."""

from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from RAMSICPRegistrationLib.core.error_prediction import PoseUncertainty, PredictedErrors
from RAMSICPRegistrationLib.core.fused import predicted_errors
from RAMSICPRegistrationLib.core.registration import register
from RAMSICPRegistrationLib.core.transforms import apply_transform, invert_transform

ZERO = np.zeros((1, 3, 3))


@pytest.mark.parametrize(
    "covariance, quantile, mean",
    [
        # Isotropic: |e| / s is chi with 3 degrees of freedom.
        (np.eye(3), np.sqrt(stats.chi2.ppf(0.95, 3)), 2.0 * np.sqrt(2.0 / np.pi)),
        # All along one direction: |e| is half-normal.
        (np.diag([1.0, 0.0, 0.0]), stats.norm.ppf(0.975), np.sqrt(2.0 / np.pi)),
        # In a plane: Rayleigh.
        (np.diag([1.0, 1.0, 0.0]), np.sqrt(-2.0 * np.log(0.05)), np.sqrt(np.pi / 2.0)),
    ],
)
def test_known_distributions_of_the_error_length(covariance, quantile, mean):
    errors = PredictedErrors(ZERO, covariance[None])
    assert errors.quantile_mm(0.95)[0] == pytest.approx(quantile, abs=2e-3)
    assert errors.mean_mm[0] == pytest.approx(mean, abs=2e-3)
    assert errors.rms_mm[0] == pytest.approx(np.sqrt(np.trace(covariance)))
    assert errors.probability_within(quantile)[0] == pytest.approx(0.95, abs=1e-3)


def test_an_anisotropic_error_against_a_million_draws():
    covariance = np.array([[4.0, 1.0, 0.3], [1.0, 1.0, -0.2], [0.3, -0.2, 0.25]])
    draws = np.linalg.norm(np.random.default_rng(1).multivariate_normal(np.zeros(3), covariance, 1_000_000), axis=1)
    errors = PredictedErrors(ZERO, covariance[None])
    assert errors.mean_mm[0] == pytest.approx(draws.mean(), rel=2e-3)
    for probability in (0.5, 0.9, 0.95, 0.99):
        assert errors.quantile_mm(probability)[0] == pytest.approx(np.quantile(draws, probability), rel=3e-3)


def test_an_fle_estimated_from_4_markers_gives_students_and_fishers_bounds():
    """The markers' part alone with nu = 6 degrees of freedom (E2): one coordinate's bound is Student's t(6), the
    length of an isotropic error Fisher's F(3, 6) (the prediction intervals of a variance estimated with 6 degrees
    of freedom)."""
    one = PredictedErrors(np.diag([1.0, 0.0, 0.0])[None], ZERO, marker_dof=6)
    assert one.quantile_mm(0.95)[0] == pytest.approx(stats.t.ppf(0.975, 6), rel=2e-3)
    assert one.rms_mm[0] == pytest.approx(1.0)  # the RMS keeps the estimate: it is unbiased in FLE^2
    isotropic = PredictedErrors((np.eye(3) / 3.0)[None], ZERO, marker_dof=6)
    assert isotropic.quantile_mm(0.95)[0] == pytest.approx(np.sqrt(stats.f.ppf(0.95, 3, 6)), rel=2e-3)
    # Under the floor the FLE is at least the floor: never below the known-FLE bound.
    floored = PredictedErrors(np.diag([1.0, 0.0, 0.0])[None], ZERO, 6, fle_estimate_ratio=0.01, fle_ratio_floor=1.0)
    assert floored.quantile_mm(0.95)[0] == pytest.approx(stats.norm.ppf(0.975), abs=2e-3)


def test_the_uncertainty_of_a_fit_splits_its_covariance_and_agrees_with_f4(tibia_patient, tibia_index, rng):
    trial = tibia_patient.simulate_trial(rng, 1.0, points_per_area=2)
    result = register(tibia_index, trial.ppc, trial.markers_image, trial.markers_patient, trial.targets_image)
    uncertainty = result.uncertainty
    information = uncertainty.marker_information + uncertainty.surface_information
    np.testing.assert_allclose(uncertainty.covariance @ information, np.eye(6), atol=1e-8)
    errors = uncertainty.errors_at(trial.targets_image)
    np.testing.assert_allclose(errors.rms_mm, result.predicted_tre_mm, rtol=1e-10)
    # F4 (the covariance alone) plus E3, the mean excess of a fit whose marker weight came from an estimated FLE.
    f4 = predicted_errors(result.pose_covariance, result.covariance_centre_mm, trial.targets_image)
    excess = np.trace(errors.bias, axis1=1, axis2=2)
    np.testing.assert_allclose(errors.rms_mm**2, f4**2 + excess, rtol=1e-9)
    assert np.all(excess > 0.0) and np.all(excess < f4**2)
    assert uncertainty.marker_dof == 6 and result.fused_weights.fle_source == "fre"
    assert result.tre_mm is None and result.target_errors_mm is None  # image targets alone: no measured TRE
    assert np.all(result.predicted_tre_95_mm > result.predicted_tre_mm)
    case = (trial.ppc, trial.markers_image, trial.markers_patient, trial.targets_image)
    given = register(tibia_index, *case, fle_mm=1.0)
    assert given.uncertainty.marker_dof is None and given.uncertainty.weighting_bias is None  # a given FLE is known
    np.testing.assert_allclose(
        given.predicted_tre_mm, predicted_errors(given.pose_covariance, given.covariance_centre_mm, trial.targets_image)
    )


def test_the_weighting_excess_is_the_mean_of_the_sandwich_over_the_fles_estimates():
    """E3 against its definition, averaged by brute force over 20,000 equally likely values of chi2(6) (the
    midpoints of its quantiles); zero for markers alone, whose weight does not matter."""
    from RAMSICPRegistrationLib.core.error_prediction import _weighting_bias

    rng = np.random.default_rng(3)
    root = rng.normal(size=(6, 6))
    markers = root @ root.T + 6.0 * np.eye(6)
    surface = np.diag([0.0, 4.0, 0.5, 9.0, 0.0, 2.0])
    scales = 6.0 / stats.chi2.ppf((np.arange(20_000) + 0.5) / 20_000, 6)
    total = np.zeros((6, 6))
    for scale in scales:
        covariance = np.linalg.inv(scale * markers + surface)
        total += covariance @ (scale**2 * markers + surface) @ covariance - covariance
    np.testing.assert_allclose(_weighting_bias(markers, surface, 6), total / len(scales), rtol=0.02, atol=1e-5)
    alone = _weighting_bias(markers, np.zeros((6, 6)), 6)  # E[1 - chi2(6) / 6] = 0 times the markers' covariance
    assert np.abs(alone).max() < 1e-3 * np.abs(np.linalg.inv(markers)).max()


def test_a_touch_lowers_the_covariance_as_refitting_with_it_does(tibia_patient, tibia_index, rng):
    """``with_touches`` adds one row per touch to the information (G1): the same covariance as a registration that
    has the touch among its probe points, to the change of the matches and the centre."""
    trial = tibia_patient.simulate_trial(rng, 1.0, points_per_area=1)
    case = (trial.markers_image, trial.markers_patient, trial.targets_image)
    before = register(tibia_index, trial.ppc, *case)
    touch = tibia_patient.sub_area_points[2][0]  # a true surface point, image coordinates
    normal = tibia_index.normals(tibia_index.nearest(touch[None])[1])
    promised = before.uncertainty.with_touches(touch, normal).errors_at(trial.targets_image).rms_mm
    touched = apply_transform(invert_transform(tibia_patient.reference_to_image), touch[None])
    after = register(tibia_index, np.vstack((trial.ppc, touched)), *case)
    np.testing.assert_allclose(after.predicted_tre_mm, promised, rtol=0.02)
    assert np.all(promised < before.predicted_tre_mm)


def test_the_95_percent_bound_covers_95_percent_of_simulated_trials(tibia_patient, tibia_index):
    """Coverage on trials drawn as the experiments draw them (FLE 1 mm, 8 points): 60 trials x 4 targets; the share
    within the bound has a standard error of 0.014 at 0.95, and 0.90 is 3.5 of them below."""
    rng = np.random.default_rng(95)
    truth = apply_transform(invert_transform(tibia_patient.reference_to_image), tibia_patient.targets_image)
    within, measured, mean = [], [], []
    for _ in range(60):
        trial = tibia_patient.simulate_trial(rng, 1.0, points_per_area=1)
        result = register(tibia_index, trial.ppc, trial.markers_image, trial.markers_patient, trial.targets_image)
        errors = np.linalg.norm(apply_transform(result.reference_to_image, truth) - trial.targets_image, axis=1)
        within.append(errors <= result.predicted_tre_95_mm)
        measured.append(errors)
        mean.append(result.predicted_tre_mean_mm)
    assert np.mean(within) >= 0.90
    assert 0.8 <= np.mean(measured) / np.mean(mean) <= 1.25


def test_pose_uncertainty_from_a_fit_with_a_known_fle_has_no_dof(tibia_patient, tibia_index, rng):
    trial = tibia_patient.simulate_trial(rng, 1.0)
    result = register(tibia_index, trial.ppc, trial.markers_image, trial.markers_patient, fle_mm=0.5)
    assert isinstance(result.uncertainty, PoseUncertainty) and result.uncertainty.marker_dof is None
    assert result.predicted_tre_95_mm is None  # no targets, no prediction at them


def test_other_modes_add_their_second_moment_about_the_chosen_pose():
    """M2 by hand: a mode a quarter of the posterior holds, 4 mm along x, adds 0.25 x 16 mm^2 along x at every
    point; a mode turned by 90 degrees about z through the origin moves (10, 0, 0) to (0, 10, 0): an offset
    (-10, 10, 0), and leaves the origin where it is."""
    from RAMSICPRegistrationLib.core.transforms import make_transform

    base = PoseUncertainty(
        covariance=np.zeros((6, 6)),
        centre_mm=np.zeros(3),
        marker_information=np.zeros((6, 6)),
        surface_information=np.eye(6),
    )
    points = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]])
    slid = replace(base, mode_weights=np.array([0.25]), mode_motions=make_transform(np.eye(3), [4.0, 0, 0])[None])
    expected = np.zeros((2, 3, 3))
    expected[:, 0, 0] = 4.0
    np.testing.assert_allclose(slid.errors_at(points).covariances, expected, atol=1e-12)
    assert slid.errors_at(points).rms_mm == pytest.approx([2.0, 2.0])
    turn = make_transform(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), np.zeros(3))
    turned = replace(base, mode_weights=np.array([0.5]), mode_motions=turn[None]).errors_at(points)
    np.testing.assert_allclose(turned.covariances[0], 0.0, atol=1e-12)
    np.testing.assert_allclose(turned.covariances[1], 0.5 * np.outer([-10.0, 10.0, 0.0], [-10.0, 10.0, 0.0]))
