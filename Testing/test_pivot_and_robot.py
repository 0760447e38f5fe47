"""Pivot calibration, the robot calibration of eqs. 3-4 and the four-point TCP calibration against transforms
built by hand."""

from pathlib import Path

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.pivot import OUTLIER_FACTOR, pivot_calibration
from RAMSICPRegistrationLib.core.robot import (
    auxiliary_frame,
    image_to_robot_base,
    robot_base_to_tracker,
    tcp_four_point,
)
from RAMSICPRegistrationLib.core.transforms import (
    apply_transform,
    invert_transform,
    make_transform,
    rotation_about_axis,
)
from RAMSICPRegistrationLib.io.pose_files import read_pose_folder

from conftest import random_transform

SKSURGERY = Path(__file__).parent / "Data" / "sksurgerycore_pivot"
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


def test_robust_names_the_slip_as_a_time_range_and_lsq_keeps_it(rng):
    """Poses 20-24 with the tip slipped 6 mm out of the divot: the robust fit drops exactly them, as one range with
    their times and residuals, and finds the tip; plain least squares keeps every pose and is pulled off."""
    poses = _pivoting_poses(rng, noise_mm=0.1)
    poses[20:25, :3, 3] += (0.0, 6.0, 0.0)
    times = 100.0 + np.arange(60) / 20.0
    robust = pivot_calibration(poses, "robust", times)
    (slip,) = robust.dropped
    assert (slip.first, slip.last, slip.count) == (20, 24, 5)
    assert (slip.start_s, slip.end_s) == (times[20], times[24])
    assert slip.max_residual_mm == pytest.approx(6.0, abs=0.5) and robust.inliers.sum() == 55
    assert np.linalg.norm(robust.tip_in_probe - TIP) < 0.2
    assert robust.threshold_mm == pytest.approx(OUTLIER_FACTOR * np.median(robust.residuals_mm))
    plain = pivot_calibration(poses, "lsq")
    assert plain.inliers.all() and plain.dropped == () and plain.threshold_mm is None
    assert np.linalg.norm(plain.tip_in_probe - TIP) > 2 * np.linalg.norm(robust.tip_in_probe - TIP)
    document = robust.to_dict()
    assert {"tip_mm", "pivot_mm", "rms_mm", "dropped"} <= set(document)
    assert document["dropped"][0]["first_pose"] == 20 and document["dropped"][0]["end_s"] == times[24]


def test_the_residual_is_reported_per_pose_per_axis_and_as_plus_does():
    """Hand-computed: two residual vectors (3, 4, 0) and (0, 0, 0) of a fit; per pose 3-D RMS sqrt(25 / 2),
    scikit-surgery's sqrt(25 / 6), PLUS's mean 2.5."""
    from RAMSICPRegistrationLib.core.pivot import PivotResult

    result = PivotResult(np.zeros(3), np.zeros(3), np.sqrt(25 / 2), np.ones(2, bool), 30.0, "lsq", np.array([5.0, 0]))
    assert result.residual_per_axis_mm == pytest.approx(np.sqrt(25 / 6))
    assert result.mean_residual_mm == pytest.approx(2.5)


def test_lsq_on_scikit_surgerys_real_recording_gives_its_owners_expected_values():
    """scikit-surgerycore's own test (test_pivot.py::test_return_value, commit 8f71235) on its 1151 poses: the tip
    (-14.476, 395.143, -7.558), the pivot (-805.285, -85.448, -2112.066) and the residual 1.838 (its definition,
    sqrt(sum of squared components / 3N)), to 1e-3 mm; the per-pose 3-D RMS is sqrt(3) times that."""
    recording = read_pose_folder(SKSURGERY)
    result = pivot_calibration(recording.poses, "lsq")
    np.testing.assert_allclose(result.tip_in_probe, (-14.476, 395.143, -7.558), atol=1e-3)
    np.testing.assert_allclose(result.pivot_in_reference, (-805.285, -85.448, -2112.066), atol=1e-3)
    assert result.residual_per_axis_mm == pytest.approx(1.838, abs=1e-3)
    assert result.rms_mm == pytest.approx(1.838 * np.sqrt(3), abs=2e-3) and result.inliers.all()


def test_robust_on_scikit_surgerys_recording_drops_the_slips_and_names_them():
    """The same recording: the runs where the tip slipped (residuals of 7-13 mm at 19.5, 22.9-24.5, 33.6-34.4 and
    44.9-45.6 s from the first pose) are dropped as ranges; the kept poses fit better than all of them (as the owner
    expects of its RANSAC fit) and the tip moves by less than 2 mm."""
    recording = read_pose_folder(SKSURGERY)
    times = recording.times_s - recording.times_s[0]
    plain = pivot_calibration(recording.poses, "lsq")
    robust = pivot_calibration(recording.poses, "robust", times)
    assert robust.rms_mm < plain.rms_mm and robust.residual_per_axis_mm < 1.838
    assert 1000 < robust.inliers.sum() < 1151
    slips = [(entry.start_s, entry.end_s) for entry in robust.dropped if entry.max_residual_mm > 7.0]
    assert len(slips) == 4
    for (start, end), (expected_start, expected_end) in zip(
        slips, [(19.4, 19.8), (22.8, 24.5), (33.5, 34.4), (44.8, 45.6)]
    ):
        assert expected_start <= start <= end <= expected_end + 0.05
    assert all(entry.max_residual_mm > robust.threshold_mm for entry in robust.dropped)
    assert np.linalg.norm(robust.tip_in_probe - plain.tip_in_probe) < 2.0


@pytest.mark.parametrize(
    "poses, method, message",
    [
        (np.tile(np.eye(4), (5, 1, 1)), "robust", "5 poses recorded, at least 10 needed"),
        (np.tile(np.eye(4), (20, 1, 1)), "robust", "swivelled only 0 degrees"),
        (np.zeros((12, 3, 3)), "robust", "expected an (N, 4, 4) array"),
        (np.tile(np.eye(4), (12, 1, 1)), "ransac", "pivot method 'ransac': choose one of robust, lsq"),
        (
            np.array([make_transform(rotation_about_axis((1, 0, 0), np.radians(a))) for a in range(0, 40, 2)]),
            "lsq",
            "the poses do not fix the tip (smallest singular value",
        ),
    ],
)
def test_pivot_bad_input(poses, method, message):
    with pytest.raises(ValueError) as error:
        pivot_calibration(poses, method)
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


TCP = np.array([1.2, -0.8, 185.0])  # a saw's TCP on the flange (mm)
FIXED_POINT = np.array([450.0, -120.0, 210.0])  # where the TCP is held, robot base (mm)
FLANGE_DOWN = np.diag([1.0, -1.0, -1.0])


def _flange_poses(tilts, rng=None, noise_mm=0.0):
    """FlangeToRobotBase poses that hold the TCP on FIXED_POINT, the flange turned by each (axis, degrees)."""
    poses = []
    for axis, degrees in tilts:
        rotation = FLANGE_DOWN @ rotation_about_axis(axis, np.radians(degrees))
        translation = FIXED_POINT - rotation @ TCP
        if noise_mm:
            translation = translation + rng.normal(scale=noise_mm, size=3)
        poses.append(make_transform(rotation, translation))
    return np.array(poses)


FOUR_TILTS = [((1, 0, 0), 45.0), ((1, 0, 0), -45.0), ((0, 1, 0), 45.0), ((0, 1, 0), -45.0)]


def test_four_point_tcp_recovers_the_offset_exactly_from_exact_poses():
    result = tcp_four_point(_flange_poses(FOUR_TILTS))
    np.testing.assert_allclose(result.tcp_in_flange, TCP, atol=1e-9)
    np.testing.assert_allclose(result.point_in_base, FIXED_POINT, atol=1e-9)
    assert result.rms_mm < 1e-9 and result.spread_deg > 20.0
    np.testing.assert_allclose(result.tool_to_flange[:3, 3], TCP)


def test_four_point_tcp_within_0_05_mm_from_noisy_flange_poses():
    """Four poses tilted 45 degrees about two axes, each flange position off by 0.015 mm per axis (a robot
    repeatability of about +-0.03 mm): over 200 calibrations the TCP is within 0.05 mm in 95 % of them."""
    errors, rms = [], []
    for seed in range(200):
        result = tcp_four_point(_flange_poses(FOUR_TILTS, np.random.default_rng(seed), noise_mm=0.015))
        errors.append(np.linalg.norm(result.tcp_in_flange - TCP))
        rms.append(result.rms_mm)
    assert np.percentile(errors, 95) < 0.05 and np.mean(errors) < 0.03
    assert 0.005 < np.mean(rms) < 0.03  # the residuals show the noise (4 poses, 6 unknowns: less than 0.026)


@pytest.mark.parametrize(
    "tilts, message",
    [
        ([((0, 0, 1), a) for a in (0.0, 30.0, 60.0, 90.0)], "turn about one axis only"),  # flange positions coplanar
        ([((1, 0, 0), 30.0), ((1, 0, 0), 31.0), ((0, 1, 0), 30.0), ((0, 1, 0), -30.0)], "poses 1 and 2 repeat"),
        (FOUR_TILTS[:3], "3 flange poses given, at least 4 needed"),
    ],
)
def test_four_point_tcp_refuses_degenerate_poses(tilts, message):
    with pytest.raises(ValueError, match=message):
        tcp_four_point(_flange_poses(tilts))


def test_four_point_tcp_names_a_pose_whose_tcp_slipped():
    poses = _flange_poses(FOUR_TILTS + [((1, 1, 0), 30.0)])
    poses[2, :3, 3] += (3.0, 0.0, 0.0)
    with pytest.raises(ValueError, match=r"flange pose 3 puts the TCP .* the TCP slipped off the point"):
        tcp_four_point(poses)
    poses[2, :3, :3] *= 1.1
    with pytest.raises(ValueError, match="flange pose 3: the 3x3 block is not a rotation"):
        tcp_four_point(poses)
