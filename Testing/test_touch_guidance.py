"""The next touch and 'enough' (``core.touch_guidance``): known answers by brute force, then touched for real."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.fused import predicted_errors
from RAMSICPRegistrationLib.core.registration import register
from RAMSICPRegistrationLib.core.touch_guidance import target_gram, touch_gains, touch_guidance
from RAMSICPRegistrationLib.core.transforms import apply_transform, invert_transform


@pytest.fixture(scope="module")
def eight_points(tibia_patient, tibia_index):
    """A registration by cr-fused from 8 probe points (one per sub-area), targets the plan's endpoints."""
    trial = tibia_patient.simulate_trial(np.random.default_rng(26), 1.0, points_per_area=1)
    result = register(tibia_index, trial.ppc, trial.markers_image, trial.markers_patient, tibia_patient.targets_image)
    return trial, result


def test_the_gain_of_a_touch_is_the_fall_of_the_summed_predicted_squared_error(
    eight_points, tibia_patient, tibia_index
):
    """G2 in closed form against the covariance inverted again with the touch's row added, candidate by candidate
    (F4's covariance alone, as G2 scores it)."""
    _, result = eight_points
    targets, centre = tibia_patient.targets_image, result.uncertainty.centre_mm
    candidates = tibia_patient.exposed_points[::2000]
    normals = tibia_index.normals(tibia_index.nearest(candidates)[1])
    gains = touch_gains(result.uncertainty, target_gram(targets, centre), tibia_index, candidates)
    now = np.sum(predicted_errors(result.uncertainty.covariance, centre, targets) ** 2)
    for candidate, normal, gain in zip(candidates, normals, gains):
        touched = result.uncertainty.with_touches(candidate, normal)
        after = np.sum(predicted_errors(touched.covariance, centre, targets) ** 2)
        assert gain == pytest.approx(now - after, rel=1e-6)


def test_the_next_touch_is_the_best_reachable_point_and_keeps_its_promise(eight_points, tibia_patient, tibia_index):
    trial, result = eight_points
    reachable = tibia_patient.exposed_points[::10]  # 3,900 true surface points of the exposed bone
    guidance = touch_guidance(result, tibia_index, reachable=reachable, count=3)
    touch = guidance.next_touch
    assert any(np.array_equal(touch.position_image, point) for point in reachable)
    # No reachable point promises less (brute force over all of them).
    every = [
        result.uncertainty.with_touches(point, tibia_index.normals(tibia_index.nearest(point[None])[1]))
        .errors_at(tibia_patient.targets_image)
        .rms_mm
        for point in reachable
    ]
    assert touch.predicted_tre_rms_mm == pytest.approx(min(np.sqrt(np.mean(np.square(every), axis=1))), rel=1e-9)
    assert touch.predicted_tre_rms_mm < guidance.predicted_tre_rms_mm
    # Planned touches are scored after the ones before them: each promises less than the last.
    promised = [planned.predicted_tre_rms_mm for planned in guidance.touches]
    assert promised == sorted(promised, reverse=True) and len(promised) == 3
    # Touch it on the true bone (exact), register again: the prediction is what was promised, to the change of the
    # fit's pose and matches that the new point brings (4 % here).
    touched = apply_transform(invert_transform(tibia_patient.reference_to_image), touch.position_image[None])
    again = register(
        tibia_index, np.vstack((trial.ppc, touched)), trial.markers_image, trial.markers_patient,
        tibia_patient.targets_image,
    )  # fmt: skip
    assert again.predicted_tre_rms_mm == pytest.approx(touch.predicted_tre_rms_mm, rel=0.05)


def test_the_whole_ipc_is_reachable_by_default_and_found_as_well_as_by_scoring_every_point(eight_points, tibia_index):
    """Thinned to 20,000 candidates, then refined within 5 mm: as good as scoring all 200,000 IPC points."""
    _, result = eight_points
    guidance = touch_guidance(result, tibia_index)
    gains = touch_gains(
        result.uncertainty, target_gram(result.targets_image, result.uncertainty.centre_mm), tibia_index,
        tibia_index.points,
    )  # fmt: skip
    best = tibia_index.points[int(np.argmax(gains))]
    normal = tibia_index.normals(tibia_index.nearest(best[None])[1])
    exhaustive = result.uncertainty.with_touches(best, normal).errors_at(result.targets_image).rms_mm
    assert guidance.next_touch.predicted_tre_rms_mm <= np.sqrt(np.mean(exhaustive**2)) * 1.01


def test_enough_is_the_95_percent_bound_of_every_target_against_the_limit(eight_points, tibia_index):
    _, result = eight_points
    bounds = result.predicted_tre_95_mm
    above = touch_guidance(result, tibia_index, target_tre_mm=float(bounds.max()) + 0.01)
    below = touch_guidance(result, tibia_index, target_tre_mm=float(bounds.max()) - 0.01)
    assert above.enough is True and below.enough is False
    np.testing.assert_allclose(above.predicted_tre_95_mm, bounds)
    document = above.to_dict()
    assert document["enough"] is True and document["target_tre_mm"] == pytest.approx(bounds.max() + 0.01)
    assert len(document["next_touch"]["position_image"]) == 3 and "predicted_tre_rms_mm" in document["next_touch"]
    assert "enough" not in touch_guidance(result, tibia_index).to_dict()


@pytest.mark.parametrize(
    "change, message",
    [
        ({"reachable": np.array([[0.0, 0.0, 0.0]])}, "mm from the IPC"),
        ({"target_tre_mm": -1.0}, "give a positive number of mm"),
        ({"target_tre_mm": float("nan")}, "give a positive number of mm"),
        ({"count": 0}, "plan at least 1 touch"),
        ({"targets_image": np.zeros((0, 3))}, "targets in the image"),
    ],
)
def test_bad_requests_say_what_to_do(eight_points, tibia_index, change, message):
    _, result = eight_points
    with pytest.raises(ValueError, match=message):
        touch_guidance(result, tibia_index, **change)


def test_a_method_without_a_covariance_is_refused(tibia_patient, tibia_index):
    trial = tibia_patient.simulate_trial(np.random.default_rng(3), 1.0)
    result = register(tibia_index, trial.ppc, trial.markers_image, trial.markers_patient, method="cr-icp")
    with pytest.raises(ValueError, match="need cr-fused"):
        touch_guidance(result, tibia_index, targets_image=tibia_patient.targets_image)
