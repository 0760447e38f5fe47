"""Pivot calibration and the robot calibration of eqs. 3-4 against transforms built by hand."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.pivot import pivot_calibration
from RAMSICPRegistrationLib.core.robot import auxiliary_frame, image_to_robot_base, robot_base_to_tracker
from RAMSICPRegistrationLib.core.transforms import (
    apply_transform,
    invert_transform,
    make_transform,
    rotation_about_axis,
)

from conftest import random_transform

TIP = np.array([1.5, -2.0, 160.0])  # tip offset in the probe frame (mm)
PIVOT = np.array([30.0, -40.0, 250.0])  # divot in the reference frame (mm)


def _pivoting_poses(rng, count=60, noise_mm=0.0):
    poses = []
    for _ in range(count):
        rotation = rotation_about_axis(rng.normal(size=3), np.radians(rng.uniform(-30, 30)))
        translation = PIVOT - rotation @ TIP + rng.normal(scale=noise_mm, size=3)
        poses.append(make_transform(rotation, translation))
    return np.array(poses)


def test_pivot_recovers_tip_and_pivot_exactly(rng):
    result = pivot_calibration(_pivoting_poses(rng))
    np.testing.assert_allclose(result.tip_in_probe, TIP, atol=1e-9)
    np.testing.assert_allclose(result.pivot_in_reference, PIVOT, atol=1e-9)
    assert result.rms_mm < 1e-9 and result.inliers.all()
    np.testing.assert_allclose(result.probe_tip_to_probe[:3, 3], TIP)


def test_pivot_with_noise_and_a_slipped_tip(rng):
    poses = _pivoting_poses(rng, noise_mm=0.1)
    poses[5, :3, 3] += (8.0, 0.0, 0.0)  # the tip slipped out of the divot for one sample
    result = pivot_calibration(poses)
    assert not result.inliers[5] and result.inliers.sum() >= 55
    assert np.linalg.norm(result.tip_in_probe - TIP) < 0.2
    assert result.rms_mm == pytest.approx(0.1 * np.sqrt(3), rel=0.35)  # RMS of 3-D noise of 0.1 per axis


@pytest.mark.parametrize(
    "poses, message",
    [
        (np.tile(np.eye(4), (5, 1, 1)), "5 poses recorded, at least 10 needed"),
        (np.tile(np.eye(4), (20, 1, 1)), "swivelled only 0 degrees"),
        (np.zeros((12, 3, 3)), "expected an (N, 4, 4) array"),
    ],
)
def test_pivot_bad_input(poses, message):
    with pytest.raises(ValueError) as error:
        pivot_calibration(poses)
    assert message in str(error.value)


def test_eq3_recovers_a_known_robot_base_to_tracker(rng):
    truth = random_transform(rng, max_translation_mm=1000.0)
    points_robot = np.array([[400.0, 0.0, 300.0], [450.0, 20.0, 300.0], [410.0, 80.0, 320.0]])
    points_tracker = apply_transform(truth, points_robot)
    np.testing.assert_allclose(robot_base_to_tracker(points_robot, points_tracker), truth, atol=1e-9)
    frame = auxiliary_frame(points_robot)
    np.testing.assert_allclose(frame[:3, 3], points_robot[0])
    assert np.linalg.det(frame[:3, :3]) == pytest.approx(1.0)


def test_eq4_sends_image_points_to_the_robot(rng):
    robot_to_tracker, reference_to_tracker, reference_to_image = (random_transform(rng) for _ in range(3))
    image_point = np.array([[12.0, -30.0, 55.0]])
    # By hand: image -> reference -> tracker -> robot base.
    by_hand = apply_transform(
        invert_transform(robot_to_tracker),
        apply_transform(reference_to_tracker, apply_transform(invert_transform(reference_to_image), image_point)),
    )
    transform = image_to_robot_base(robot_to_tracker, reference_to_tracker, reference_to_image)
    np.testing.assert_allclose(apply_transform(transform, image_point), by_hand, atol=1e-9)


def test_eq3_bad_positions():
    line = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [20.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="collinear"):
        robot_base_to_tracker(line, line)
    triangle = np.array([[0.0, 0.0, 0.0], [50.0, 0.0, 0.0], [0.0, 40.0, 0.0]])
    with pytest.raises(ValueError, match="apart differently in the robot and tracker frames"):
        robot_base_to_tracker(triangle, triangle * 1.2)
    with pytest.raises(ValueError, match="give exactly 3 positions"):
        robot_base_to_tracker(np.vstack((triangle, [[1.0, 1.0, 1.0]])), np.vstack((triangle, [[1.0, 1.0, 1.0]])))
