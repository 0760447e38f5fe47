"""cr-fused (core.fused): markers and probe points in one weighted fit, against answers known beforehand."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.fused import (
    FLE_FLOOR_MM,
    FusedWeights,
    fused_fit,
    marker_fle,
    surface_sigma,
)
from RAMSICPRegistrationLib.core.icp import icp
from RAMSICPRegistrationLib.core.metrics import predicted_tre, target_registration_error
from RAMSICPRegistrationLib.core.paired_point import fit_rigid_transform, rigid_procrustes
from RAMSICPRegistrationLib.core.registration import register
from RAMSICPRegistrationLib.core.surface_index import SurfaceIndex
from RAMSICPRegistrationLib.core.transforms import (
    apply_transform,
    invert_transform,
    make_transform,
    rotation_about_axis,
)
from RAMSICPRegistrationLib.io.ndi_tools import DEFAULT_REFERENCE_TOOL, tool_marker_geometry

from conftest import ellipsoid_points, random_transform

TOOL = tool_marker_geometry(DEFAULT_REFERENCE_TOOL)


def _weights(fle_mm=1.0, sigma_mm=0.15):
    return FusedWeights(fle_mm, sigma_mm, "given", "prior", 0.25, 0.2)


def _moved(points, transform):
    return np.abs(apply_transform(transform, points) - points).max()


def test_exact_markers_and_surface_points_give_the_true_pose(tibia_patient, tibia_index, rng):
    image_to_reference = invert_transform(tibia_patient.reference_to_image)
    ppc = apply_transform(image_to_reference, tibia_patient.ipc[rng.choice(len(tibia_patient.ipc), 40, replace=False)])
    truth = tibia_patient.reference_to_image
    # Through register: the CR of exact markers is exact, and the fused fit keeps it.
    result = register(tibia_index, ppc, tibia_patient.markers_image, tibia_patient.markers_reference)
    assert result.method == "cr-fused" and result.converged
    assert _moved(tibia_patient.targets_image, result.reference_to_image @ invert_transform(truth)) < 1e-6
    # From a start 2 mm and 1 degree away, the fit returns to the true pose.
    start = make_transform(rotation_about_axis((1.0, 2.0, 0.5), np.radians(1.0)), (1.2, -1.0, 1.2)) @ truth
    fit = fused_fit(tibia_index, ppc, tibia_patient.markers_reference, tibia_patient.markers_image, start, _weights())
    assert fit.converged
    assert _moved(tibia_patient.targets_image, fit.transform @ invert_transform(truth)) < 1e-6


def test_zero_marker_weight_is_cr_icp():
    surface = ellipsoid_points(60000)
    index = SurfaceIndex(surface)
    rng = np.random.default_rng(2)
    pose = random_transform(rng, max_angle_deg=30.0, max_translation_mm=50.0)
    exact = apply_transform(invert_transform(pose), surface[rng.choice(len(surface), 50, replace=False)])
    markers = TOOL + np.array([0.0, 60.0, -40.0])
    coarse = fit_rigid_transform(markers, apply_transform(pose, markers) + (0.8, -0.5, 0.6)).transform
    no_markers = FusedWeights(np.inf, 0.15, "given", "prior", 0.25, 0.2)
    # With the markers switched off, the least-squares SVD variant of the fused fit runs ICP's iterations exactly.
    noisy = exact + rng.normal(scale=0.15, size=exact.shape)
    expected = icp(index, noisy, coarse, tolerance_mm=1e-9).transform
    options = {"solver": "point-to-point", "loss": "least-squares", "variance": "fixed", "tolerance_mm": 1e-9}
    same_solver = fused_fit(index, noisy, markers, markers, coarse, no_markers, **options)
    np.testing.assert_allclose(same_solver.transform, expected, atol=1e-7)
    # And the default (point-to-plane) lands where CR-ICP does: on the true pose, for points on the surface.
    default = fused_fit(index, exact, markers, markers, coarse, no_markers)
    cr_icp = register(index, exact, apply_transform(coarse, markers), markers, method="cr-icp").reference_to_image
    for transform in (default.transform, cr_icp):
        assert _moved(surface, transform @ invert_transform(pose)) < 1e-4


def test_zero_surface_weight_is_the_cr_and_its_fitzpatrick_prediction(tibia_patient, tibia_index):
    trial = tibia_patient.simulate_trial(np.random.default_rng(6), marker_fle_mm=1.0)
    coarse = fit_rigid_transform(trial.markers_patient, trial.markers_image)
    no_surface = FusedWeights(0.8, np.inf, "given", "prior", 0.25, 0.2)
    fit = fused_fit(tibia_index, trial.ppc, trial.markers_patient, trial.markers_image, coarse.transform, no_surface)
    assert _moved(trial.targets_image, fit.transform @ invert_transform(coarse.transform)) < 1e-6
    # The covariance of the marker fit alone is Fitzpatrick, West and Maurer's prediction (metrics.predicted_tre)
    # for the markers where the fit puts them.
    fitted = apply_transform(fit.transform, trial.markers_patient)
    np.testing.assert_allclose(
        fit.predicted_errors_mm(trial.targets_image), predicted_tre(fitted, trial.targets_image, 0.8), rtol=1e-9
    )


def test_on_a_cylinder_the_slide_and_spin_come_from_the_markers():
    # A shaft of radius 15 mm along z: the surface cannot feel a slide along z or a spin about it.
    # The IPC is a regular 0.5 mm grid on it, so each point's neighbours are symmetric and its normal is radial.
    radius = 15.0
    angles, heights = np.meshgrid(np.linspace(0, 2 * np.pi, 193)[:-1], np.arange(-100.0, 100.01, 0.5))
    grid = np.column_stack((radius * np.cos(angles.ravel()), radius * np.sin(angles.ravel()), heights.ravel()))
    index = SurfaceIndex(grid)
    count = 48  # probe points on grid points all around, evenly in angle and symmetric in height
    turns = 2 * np.pi * np.arange(count) / count
    ppc = np.column_stack((radius * np.cos(turns), radius * np.sin(turns), np.tile([-30.0, 30.0], count // 2)))
    markers = np.array([[45.0, 0.0, 30.0], [-45.0, 0.0, 30.0], [0.0, 50.0, -30.0], [0.0, -50.0, -30.0]])
    spin, shift = rotation_about_axis((0.0, 0.0, 1.0), np.radians(2.0)), np.array([0.6, -0.4, 1.5])
    placed = apply_transform(make_transform(spin, shift), markers)  # the markers' pose: a spin and a shift
    weights = _weights(fle_mm=1.0, sigma_mm=0.15)
    coarse = rigid_procrustes(markers, placed)
    fit = fused_fit(index, ppc, markers, placed, coarse, weights, variance="fixed")
    along_axis = fit.transform[2, 3]
    spin_angle = np.arctan2(fit.transform[1, 0], fit.transform[0, 0])
    assert along_axis == pytest.approx(shift[2], abs=1e-3)  # the markers' slide, untouched by the surface
    assert spin_angle == pytest.approx(np.radians(2.0), abs=1e-5)  # and their spin (0.15 um at the shaft surface)
    # Across the axis the surface pulls the shift towards zero: (w_m K I + w_s N / 2 I) t = w_m K d.
    marker_share = 4 * weights.marker_weight / (4 * weights.marker_weight + weights.surface_weight * count / 2)
    np.testing.assert_allclose(fit.transform[:2, 3], marker_share * shift[:2], atol=2e-5)  # 2x the stop tolerance


def test_fle_estimate_from_fre_over_2000_draws():
    rng = np.random.default_rng(7)
    fle = 1.0
    estimates = []
    for _ in range(2000):
        placed = TOOL + rng.normal(scale=fle / np.sqrt(3.0), size=TOOL.shape)
        estimates.append(marker_fle(fit_rigid_transform(TOOL, placed).fre_mm, len(TOOL))[0])
    # E[FRE^2] = (1 - 2/N) FLE^2: the squared estimate is unbiased; 2000 draws of a 6-dof chi-square: +-1.3 %.
    assert np.sqrt(np.mean(np.square(estimates))) == pytest.approx(fle, rel=0.10)
    assert marker_fle(0.001, 4) == (FLE_FLOOR_MM, "floor")


def test_surface_noise_prior_and_its_reestimate(tibia_patient, tibia_index):
    assert surface_sigma(0.25, 0.0) == pytest.approx(0.25 / np.sqrt(3.0))
    assert surface_sigma(0.0, 1.2) == pytest.approx(1.2 / np.sqrt(12.0))
    # Probe points 4x noisier than assumed: the residuals raise sigma, and register says so.
    trial = tibia_patient.simulate_trial(np.random.default_rng(8), marker_fle_mm=1.0, probe_noise_mm=1.0)
    result = register(tibia_index, trial.ppc, trial.markers_image, trial.markers_patient, probe_noise_mm=0.25)
    weights = result.fused_weights
    assert weights.sigma_source == "residuals"
    assert weights.surface_sigma_mm == pytest.approx(1.0 / np.sqrt(3.0), rel=0.3)
    assert any("worse than the probe noise allows" in warning for warning in result.warnings)


def test_surface_noise_reestimate_takes_out_the_poses_six_degrees_of_freedom():
    """Issue 23 (a mutant that survived): F3's re-estimate divides the squared residuals by N - trace(C H_s), the
    points' share of the 6 pose parameters taken out, not by N. With the markers switched off the 12 probe points fix
    all 6, so sum r^2 / (N - 6) is unbiased for the noise put along the normals (0.5 mm) while sum r^2 / N is half
    of it. Mean of the squared estimate over 150 fits: 0.25 mm^2 within 15 % (a 6-dof chi-square spreads 5 % over
    150 fits; the mutant gives 0.12)."""
    semi_axes = np.array([40.0, 25.0, 15.0])
    index = SurfaceIndex(ellipsoid_points(60000, semi_axes=tuple(semi_axes)))
    rng = np.random.default_rng(23)
    no_markers = FusedWeights(np.inf, 0.01, "given", "prior", 0.25, 0.2)  # a prior far below the true noise
    markers = TOOL + np.array([0.0, 60.0, -40.0])
    options = {"loss": "least-squares", "variance": "surface", "restarts": False}
    squared, freedoms = [], []
    for trial in range(150):
        on_surface = ellipsoid_points(12, semi_axes=tuple(semi_axes), seed=1000 + trial)
        normals = on_surface / semi_axes**2
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        noisy = on_surface + rng.normal(scale=0.5, size=(12, 1)) * normals
        fit = fused_fit(index, noisy, markers, markers, np.eye(4), no_markers, **options)
        assert fit.weights.sigma_source == "residuals"
        squared.append(fit.weights.surface_sigma_mm**2)
        freedoms.append(fit.surface_dof)
    assert np.mean(freedoms) == pytest.approx(6.0, abs=0.01)  # the surface alone fixes the whole pose
    assert np.mean(squared) == pytest.approx(0.25, rel=0.15), np.mean(squared)


def test_result_json_carries_weights_and_prediction(tibia_patient, tibia_index):
    trial = tibia_patient.simulate_trial(np.random.default_rng(9), marker_fle_mm=1.0)
    result = register(
        tibia_index,
        trial.ppc,
        trial.markers_image,
        trial.markers_patient,
        trial.targets_image,
        trial.targets_patient,
    )
    document = result.to_dict()
    assert document["method"] == "cr-fused"
    coarse = fit_rigid_transform(trial.markers_patient, trial.markers_image)
    assert document["fused_weights"]["marker_fle_mm"] == pytest.approx(marker_fle(coarse.fre_mm, 4)[0])
    assert document["fused_weights"]["fle_source"] == "fre"
    assert len(document["predicted_tre_mm"]) == 4 and np.array(document["pose_covariance"]).shape == (6, 6)
    np.testing.assert_allclose(result.predicted_error_mm(trial.targets_image), result.predicted_tre_mm)
    assert document["predicted_tre_rms_mm"] == pytest.approx(np.sqrt(np.mean(result.predicted_tre_mm**2)))
    with pytest.raises(ValueError, match="needs cr-fused"):
        register(tibia_index, trial.ppc, trial.markers_image, trial.markers_patient, method="cr").predicted_error_mm(
            trial.targets_image
        )


def test_restart_poses_lie_two_standard_deviations_from_the_cr(tibia_patient, tibia_index):
    from RAMSICPRegistrationLib.core.fused import _starts

    trial = tibia_patient.simulate_trial(np.random.default_rng(10), marker_fle_mm=1.0)
    weights = _weights(fle_mm=1.0)
    data = (tibia_index, None, trial.ppc, trial.markers_patient, trial.markers_image, "least-squares")
    coarse = rigid_procrustes(trial.markers_patient, trial.markers_image)

    def misfit(transform):  # the markers' part of F1
        residuals = apply_transform(transform, trial.markers_patient) - trial.markers_image
        return weights.marker_weight * np.sum(residuals**2)

    starts = _starts(data, weights)
    assert len(starts) == 12
    # Each start is 2 sd along one eigen-motion of the CR's covariance: the markers' misfit rises by 2^2.
    np.testing.assert_allclose([misfit(start) - misfit(coarse) for start in starts], 4.0, rtol=0.02)


@pytest.mark.parametrize("bone", ["right-tibia", "right-ilium"])
def test_predicted_tre_is_calibrated_over_the_demos_trials(bone):
    from RAMSICPRegistrationLib.experiments.demo import FUSED_LABEL, run_demo

    report = run_demo(trials=30, seed=3, bone=bone, image_source="mesh")
    measured = report.tre_mm["manual"][FUSED_LABEL]
    # RMS over 30 trials of a TRE whose square is a sum of a few chi-squares: about 8 % sampling error, so the
    # issue's 0.8-1.25 band is 2.5-3 of its standard deviations. The targets' own 0.08 mm is counted.
    assert 0.8 <= report.calibration("manual") <= 1.25
    expected = np.sqrt(np.mean(measured**2)) / np.sqrt(np.mean(report.predicted_tre_mm["manual"] ** 2) + 0.25**2 / 10)
    assert report.calibration("manual") == pytest.approx(expected)
    assert np.mean(measured) < 0.75 * np.mean(report.tre_mm["manual"]["CR-ICP"])


def test_a_fit_caught_on_the_other_table_of_the_wing_starts_again(ilium):
    # The ilium with a 5 mm marker error: from this CR the first fit settles 15 mm off, its probe points 1.2 mm from
    # the surface (a wrong basin). Started again around the CR it finds the wing, and says so.
    patient = ilium[0]
    index = SurfaceIndex(patient.ipc)
    trial = patient.simulate_trial(np.random.default_rng(8), marker_fle_mm=5.0)
    case = (trial.ppc, trial.markers_image, trial.markers_patient, trial.targets_image, trial.targets_patient)
    result = register(index, *case)
    coarse = fit_rigid_transform(trial.markers_patient, trial.markers_image)
    once = fused_fit(
        index, trial.ppc, trial.markers_patient, trial.markers_image, coarse.transform, result.fused_weights,
        restarts=False,
    )  # fmt: skip
    assert np.sqrt(np.mean(once.surface_residuals_mm**2)) > 3 * surface_sigma(0.25, index.spacing_mm)
    assert result.ppc_rms_mm < 0.5  # the probe noise: 0.25 mm RMS in 3-D
    assert result.tre_mm < 1.0 < target_registration_error(once.transform, trial.targets_patient, trial.targets_image)
    assert any(warning.startswith("cr-fused started again") for warning in result.warnings)


@pytest.mark.parametrize("seed, starts", [(4, 37), (25, 13)])
def test_a_fit_in_a_wrong_basin_of_the_thin_fibula_is_started_again_farther_out(seed, starts, monkeypatch):
    """The fibula, an FLE of 2.5 mm, 8 points: trial 4's first fit ends off the surface and the +-2 sd restarts do not
    leave that basin (7.6 mm TRE), +-6 sd do; trial 25's first fit sits on the surface with the markers pulled away
    (F1 above its chi-square's 99th percentile: 3.6 mm TRE), and the +-2 sd restarts find the bone's own fit."""
    from RAMSICPRegistrationLib.core import fused
    from RAMSICPRegistrationLib.simulation.package_data import shipped_patient

    patient = shipped_patient("right-fibula")[0]
    index = SurfaceIndex(patient.ipc)
    trial = patient.simulate_trial(np.random.default_rng(seed), 2.5, points_per_area=1)
    case = (trial.ppc, trial.markers_image, trial.markers_patient, trial.targets_image, trial.targets_patient)
    result = register(index, *case)
    assert result.tre_mm < 1.0 and any(warning.startswith("cr-fused started again") for warning in result.warnings)
    assert f"of {starts - 1} poses around the CR" in " ".join(result.warnings)
    monkeypatch.setattr(fused, "RESTART_SPREADS", (2.0,))  # the restarts before: +-2 sd, only off the surface
    monkeypatch.setattr(fused, "MISFIT_P", 1e-300)
    assert register(index, *case).tre_mm > 3.0
