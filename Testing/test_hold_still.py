"""The touch detector (core.hold_still, core.touch, core.fixed_point): held still or swivelled, found with known
answers: positions computed here by hand, swivels built about points we chose, with tips miscalibrated on purpose."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.core import hold_still
from RAMSICPRegistrationLib.core.hold_still import (
    MAX_DRIFT_MM,
    HoldStillDetector,
    find_pose_touches,
    find_touches,
)
from RAMSICPRegistrationLib.core.transforms import make_transform, rotation_about_axis

TIP = np.array([10.0, -5.0, 160.0])  # the true tip in the probe frame (mm)
LANDMARK = np.array([30.0, -40.0, 20.0])  # where it rests, reference frame (mm)


def _pose(rotation, point=LANDMARK, tip=TIP):
    """ProbeToReference with the probe's point ``tip`` at ``point``."""
    return make_transform(rotation, np.asarray(point) - rotation @ tip)


def _swivel(count, degrees=40.0, axes=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)), point=LANDMARK, tip=TIP, phase=0.0):
    """A swivel about ``point``: the probe tilted about two axes by up to ``degrees`` / 2 (a figure of eight)."""
    angles = np.linspace(0.0, 2 * np.pi, count) + phase
    half = np.radians(degrees) / 2
    rotations = [
        rotation_about_axis(axes[0], half * np.sin(angle)) @ rotation_about_axis(axes[1], half * np.sin(2 * angle))
        for angle in angles
    ]
    return [_pose(rotation, point, tip) for rotation in rotations]


def _moving_away(start, count, step_mm=5.0):
    """Poses lifting the tip off ``start`` by ``step_mm`` a frame."""
    return [_pose(np.eye(3), start + (0.0, 0.0, step_mm * (number + 1))) for number in range(count)]


def _feed(poses, tip, rate_hz=20.0, detector=None, start_s=0.0):
    detector = HoldStillDetector() if detector is None else detector
    emitted = [detector.add_pose(pose, tip, start_s + number / rate_hz, number) for number, pose in enumerate(poses)]
    return detector, [touch for touch in emitted if touch is not None]


# -- held still: the tip alone ------------------------------------------------------------------------------
def test_a_hand_computed_hold_is_emitted_when_the_tip_has_left_for_three_frames():
    """Three still frames, then three frames 5 mm away: mean (0.2, 0, 0), spread sqrt((0.2^2 + 0 + 0.2^2) / 3)."""
    detector = HoldStillDetector(still_mm=1.0, still_s=0.2)
    assert detector.add((0.0, 0.0, 0.0), 10.0, 7) is None
    assert detector.add((0.2, 0.0, 0.0), 10.1, 8) is None
    assert detector.pending() is None and not detector.holding  # 0.1 s so far: not yet a touch
    assert detector.add((0.4, 0.0, 0.0), 10.2, 9) is None
    assert detector.holding and detector.pending() is not None  # 0.2 s: qualifies, emitted when the hold ends
    assert detector.add((5.0, 0.0, 0.0), 10.3, 10) is None  # off the point: a glitch, or the end?
    assert detector.add((6.0, 0.0, 0.0), 10.4, 11) is None
    touch = detector.add((7.0, 0.0, 0.0), 10.5, 12)  # three off: the end
    np.testing.assert_allclose(touch.position, (0.2, 0.0, 0.0), atol=1e-12)
    assert touch.spread_mm == pytest.approx(np.sqrt(0.08 / 3))
    assert (touch.first_frame, touch.last_frame, touch.frames) == (7, 9, 3)
    assert (touch.start_s, touch.end_s) == (10.0, 10.2) and touch.duration_s == pytest.approx(0.2)
    assert touch.method == "mean tip" and touch.kind == "rest"  # the stream began with it: a rest
    assert detector.finish() is None  # the new run (5, 6, 7 mm: a 1 mm step each) never held still
    assert detector.touches == [touch]
    assert touch.to_dict()["position_mm"] == pytest.approx([0.2, 0.0, 0.0]) and touch.to_dict()["kind"] == "rest"


def test_a_single_glitch_is_left_out_and_does_not_split_the_hold():
    """A hold of 1 s at 20 Hz with one frame 5 mm off in the middle: one touch, the glitch left out, the mean that
    of the other 20 frames exactly."""
    tips = np.zeros((21, 3)) + (1.0, 2.0, 3.0)
    tips[::2, 0] += 0.1  # a known scatter
    glitched = tips.copy()
    glitched[10] += (5.0, 0.0, 0.0)
    detector = HoldStillDetector()
    detector.add((50.0, 0.0, 0.0), -0.05)  # the tip elsewhere first: the hold is not a rest
    for number, tip in enumerate(glitched):
        assert detector.add(tip, number / 20.0) is None
    touch = detector.finish(end_of_recording=False)
    assert touch.dropped_frames == 1 and touch.frames == 20 and touch.kind == "hold"
    np.testing.assert_allclose(touch.position, np.delete(tips, 10, axis=0).mean(axis=0), atol=1e-12)


def test_a_hold_ends_when_a_frame_would_leave_the_ball_around_the_mean():
    """x = 1, 0, 1.9, 1 (mean 0.975): every frame within 1 mm, one hold. x = 1, 0, 1 then 2.1: with it the mean is
    1.025 and x = 0 lies 1.025 mm from it, so 2.1 is off the point, and with the two frames after it ends the hold."""
    kept = find_touches([(x, 0, 0) for x in (1.0, 0.0, 1.9, 1.0)], np.arange(4.0), still_mm=1.0, still_s=0.5)
    assert [(t.first_frame, t.last_frame) for t in kept] == [(0, 3)]
    np.testing.assert_allclose(kept[0].position, (3.9 / 4, 0, 0))
    x = [1.0, 0.0, 1.0, 2.1, 2.1, 2.1]
    ended = find_touches([(value, 0, 0) for value in x], np.arange(6.0), still_mm=1.0, still_s=0.5)
    assert [(t.first_frame, t.last_frame) for t in ended] == [(0, 2), (3, 5)]
    np.testing.assert_allclose(ended[0].position, (2.0 / 3, 0, 0))


def test_a_run_shorter_than_still_s_or_three_frames_is_no_touch():
    tips = [(0, 0, 0)] * 3 + [(10, 0, 0)] * 5
    times = [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7]  # first run 0.2 s, second 0.4 s
    touches = find_touches(tips, times, still_mm=1.0, still_s=0.3)
    assert [(t.first_frame, t.last_frame) for t in touches] == [(3, 7)]
    assert find_touches([(0, 0, 0)] * 2, [0.0, 5.0], still_s=0.2) == []  # 5 s, but 2 frames: no mean worth it


@pytest.mark.parametrize("speed_mm_s, touches", [(10.0, 0), (3.0, 2)])
def test_a_tip_sliding_steadily_is_held_only_while_it_drifts_less_than_a_millimetre(speed_mm_s, touches):
    """A tip sliding at 10 mm/s drifts 1 mm in 0.1 s, less than the shortest touch: never held. At 3 mm/s it drifts
    1 mm in 0.33 s: the runs the radius allows (1 s, 3 mm) are cut to stretches that drift at most 1 mm."""
    times = np.arange(0.0, 2.0, 0.02)
    tips = np.outer(times * speed_mm_s, (1.0, 0.0, 0.0))
    found = find_touches(tips, times)
    assert len(found) == touches
    for touch in found:
        assert touch.duration_s * speed_mm_s <= MAX_DRIFT_MM + 1e-9 and touch.duration_s >= 0.2


def test_eight_touches_with_tremor_are_found_within_a_tenth_of_a_millimetre_and_nothing_else():
    from test_collect import synthetic_session  # noqa: PLC0415

    rng = np.random.default_rng(16)
    positions = rng.uniform(-60, 60, size=(8, 3))
    tips, times, holds = synthetic_session(rng, positions)
    touches = find_touches(tips, times, still_mm=1.0, still_s=0.5)  # the pause (0.25 s) and the slide do not count
    assert len(touches) == 8
    errors = np.linalg.norm(np.array([t.position for t in touches]) - positions, axis=1)
    assert errors.max() < 0.1, errors
    for touch, (first, last) in zip(touches, holds):
        assert first - 3 <= touch.first_frame and touch.last_frame <= last + 1  # inside the true hold
        assert touch.frames >= 0.9 * (last - first + 1)  # and covering nearly all of it
        assert 0.05 < touch.spread_mm < 0.3  # tremor (0.15 mm amplitude) and noise (0.1 mm RMS)


# -- swivelled: poses ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("error_mm", [0.0, 1.0, 2.5, 4.0])
def test_a_swivel_with_a_miscalibrated_tip_is_one_touch_at_its_fixed_point(error_mm):
    """A 44 degree swivel about LANDMARK, the tip told to the detector ``error_mm`` off: one touch, at the landmark
    (the swivel's least-squares fixed point), the true tip found, PLUS's swivel test passed."""
    calibrated = TIP + error_mm * np.array([0.6, 0.0, 0.8])
    poses = [_pose(np.eye(3))] + _swivel(80, degrees=44.0) + _moving_away(LANDMARK, 3)
    detector, emitted = _feed(poses, calibrated)
    (touch,) = emitted
    assert touch.method == "pivot" and touch.tip_from == "pivot" and touch.kind == "swivel"
    np.testing.assert_allclose(touch.position, LANDMARK, atol=1e-9)
    np.testing.assert_allclose(touch.tip_in_probe, TIP, atol=1e-9)
    assert (touch.first_frame, touch.last_frame) == (0, 80) and touch.spread_mm < 1e-9
    assert touch.swivelled and touch.swivel_deg > 44.0  # two tilts of up to 22 degrees each
    assert detector.finish() is None


def test_without_room_for_the_calibration_error_the_swivel_splits_as_the_issue_reported():
    """The mutant: the held point forced to be the calibrated tip (tip_error_mm 0), 2.5 mm off. The tip then traces
    an arc of 1.9 mm and a radius of 1 mm around the mean cuts the one swivel into several touches."""
    calibrated = TIP + (2.5, 0.0, 0.0)
    poses = _swivel(160, degrees=44.0) + _moving_away(LANDMARK, 3)
    _, emitted = _feed(poses, calibrated, detector=HoldStillDetector(still_mm=1.0, tip_error_mm=0.0))
    assert len(emitted) > 1


def test_a_hold_is_the_mean_tip_exactly_and_a_fan_takes_the_calibration_along_its_axis():
    """Held still (no turn): the mean of the tips at the calibrated tip. Fanned about one axis only: the fixed point
    along the other two directions, the calibrated tip along the fan's axis (the poses say nothing there)."""
    calibrated = TIP + (1.0, 1.5, -2.0)
    still = [_pose(rotation_about_axis((0, 0, 1), 0.0)) for _ in range(20)]
    shaken = [pose.copy() for pose in still]
    for number, pose in enumerate(shaken):
        pose[:3, 3] += 0.01 * np.array([number % 3, number % 5, number % 2])  # a known scatter
    touch = hold_still.touch_of_poses(*_arrays(shaken), calibrated, _sums(shaken), 5.0)
    tips = np.array([pose[:3, :3] @ calibrated + pose[:3, 3] for pose in shaken])
    assert touch.method == "mean tip" and touch.tip_from == "calibration"
    np.testing.assert_allclose(touch.position, tips.mean(axis=0), atol=1e-9)
    fan = [_pose(rotation_about_axis((1.0, 0.0, 0.0), angle)) for angle in np.radians(np.linspace(-20, 20, 41))]
    touch = hold_still.touch_of_poses(*_arrays(fan), calibrated, _sums(fan), 5.0)
    assert touch.method == "partial pivot"
    expected_tip = np.array([calibrated[0], TIP[1], TIP[2]])  # x: the fan's axis, from the calibration
    np.testing.assert_allclose(touch.tip_in_probe, expected_tip, atol=1e-9)
    expected = np.mean([pose[:3, :3] @ expected_tip + pose[:3, 3] for pose in fan], axis=0)
    np.testing.assert_allclose(touch.position, expected, atol=1e-9)
    assert abs(touch.position[0] - LANDMARK[0]) == pytest.approx(1.0, abs=1e-9)  # the calibration's error, along x


def test_a_landing_on_the_mean_tip_then_a_swivel_is_one_touch(monkeypatch):
    """Held still first (0.5 s), the tip told 4 mm off, after a frame landing tilted 30 degrees, 1.2 mm from the
    mean of the calibrated tips: the swivel then moves the run's point by the calibration error onto the landmark,
    where that tilted frame lies 3.3 mm off (its own tilt turns the 4 mm error by 2.1 mm). It is left out rather
    than cutting the landmark in two."""
    calibrated = TIP + (0.0, 4.0, 0.0)
    still = [_pose(np.eye(3)) for _ in range(10)]
    mean_tip = still[0][:3, :3] @ calibrated + still[0][:3, 3]
    tilt = rotation_about_axis((1.0, 0.0, 0.0), np.radians(30.0))
    shift = (tilt - np.eye(3)) @ (TIP - calibrated)  # how the landing frame moves from the calibrated to the true tip
    landing = _pose(tilt, mean_tip + 1.2 * shift / np.linalg.norm(shift), calibrated)
    assert np.linalg.norm(landing[:3, :3] @ TIP + landing[:3, 3] - LANDMARK) == pytest.approx(3.27, abs=0.01)
    poses = [_pose(np.eye(3), LANDMARK + (0, 0, 50.0))] + [landing] + still + _swivel(60, degrees=40.0)
    poses += _moving_away(LANDMARK, 3)
    _, emitted = _feed(poses, calibrated)
    (touch,) = emitted
    assert touch.first_frame == 2 and touch.method == "pivot"  # the landing frame (1) left out
    np.testing.assert_allclose(touch.position, LANDMARK, atol=1e-9)
    fits = hold_still._Run.fits  # the mutant: no landing frame may be left out
    monkeypatch.setattr(hold_still._Run, "fits", lambda run, *arguments: fits(run, *arguments[:-1], -1.0))
    _, split = _feed(poses, calibrated)
    assert len(split) == 2


def test_invalid_frames_neither_end_nor_split_a_touch_but_a_tip_back_elsewhere_is_a_new_one():
    poses = _swivel(40)
    detector = HoldStillDetector()
    detector.add_pose(_pose(np.eye(3), LANDMARK + (0, 0, 80.0)), TIP, -0.1, -1)
    for number, pose in enumerate(poses):
        if 15 <= number < 25:
            detector.add_invalid(number / 20.0, number)  # half a second without tracking
        else:
            assert detector.add_pose(pose, TIP, number / 20.0, number) is None
    elsewhere = [_pose(np.eye(3), LANDMARK + (20.0, 0, 0)) for _ in range(10)]
    emitted = [detector.add_pose(pose, TIP, 2.0 + number / 20.0) for number, pose in enumerate(elsewhere)]
    (first,) = [touch for touch in emitted if touch is not None]
    assert (first.first_frame, first.last_frame, first.frames) == (0, 39, 30)
    np.testing.assert_allclose(first.position, LANDMARK, atol=1e-9)
    second = detector.finish()
    np.testing.assert_allclose(second.position, LANDMARK + (20.0, 0, 0), atol=1e-9)
    assert second.kind == "rest"  # the recording ended with the probe lying there


def test_rests_are_the_probe_still_at_the_start_or_the_end_and_never_a_swivel():
    lying = [_pose(np.eye(3), (300.0, 0.0, 0.0)) for _ in range(20)]
    air = _moving_away(LANDMARK, 3)
    poses = lying + air + [_pose(np.eye(3))] * 10 + air + _swivel(40) + air + lying
    touches, _ = find_pose_touches(poses, TIP, np.arange(len(poses)) / 20.0, recording_tip=False)
    assert [touch.kind for touch in touches] == ["rest", "hold", "swivel", "rest"]
    _, emitted = _feed(_swivel(40) + air, TIP)  # a swivel from the first frame on is a touch, not a rest
    assert [touch.kind for touch in emitted] == ["swivel"]
    detector, _ = _feed(lying, TIP)
    assert detector.finish(end_of_recording=False).kind == "rest"  # it began with the stream
    detector, _ = _feed(air + lying, TIP)
    assert detector.finish(end_of_recording=False).kind == "hold"  # live: stopping collection is no rest
    detector, _ = _feed(air + lying + air[:2], TIP)
    assert detector.finish().kind == "hold"  # the tip had left before the recording ended


def test_streaming_and_the_whole_recording_give_the_same_touches():
    """One definition: the frames fed one by one (as the controller does live) or the recording at once, and the
    same frames delivered in other bursts, give identical touches."""
    rng = np.random.default_rng(5)
    poses = _moving_away(LANDMARK, 3) + _swivel(50) + _moving_away(LANDMARK, 4)
    poses += [_pose(np.eye(3), LANDMARK + (40.0, 0, 0))] * 12 + _moving_away(LANDMARK + (40.0, 0, 0), 4)
    noisy = [pose.copy() for pose in poses]
    for pose in noisy:
        pose[:3, 3] += rng.normal(scale=0.05, size=3)
    times = np.cumsum(rng.uniform(0.03, 0.07, size=len(noisy)))
    whole, _ = find_pose_touches(noisy, TIP, times, recording_tip=False)
    detector = HoldStillDetector()
    streamed = [detector.add_pose(pose, TIP, time) for pose, time in zip(noisy, times)]
    streamed = [touch for touch in streamed + [detector.finish()] if touch is not None]
    assert len(whole) == 2 and len(streamed) == 2
    for one, other in zip(whole, streamed):
        assert one.to_dict() == other.to_dict()


def test_a_recordings_swivels_place_its_holds_with_the_tip_they_agree_on():
    """Three swivels (known points) and a hold, the tip told 2 mm off: the swivels' joint tip is the true one, and
    the hold, placed with it, lands on its true point instead of 2 mm away."""
    calibrated = TIP + (2.0, 0.0, 0.0)
    points = [LANDMARK, LANDMARK + (60.0, 0, 0), LANDMARK + (0, 60.0, 0)]
    air = _moving_away(LANDMARK + (0, 0, 100.0), 3, step_mm=20.0)
    poses = []
    for number, point in enumerate(points):
        poses += air + _swivel(40, point=point, phase=number)
    hold_point = LANDMARK + (60.0, 60.0, 0.0)
    poses += air + [_pose(rotation_about_axis((1, 0, 0), 0.3), hold_point)] * 10 + air
    touches, tip = find_pose_touches(poses, calibrated, np.arange(len(poses)) / 20.0)
    np.testing.assert_allclose(tip, TIP, atol=1e-9)
    assert [touch.tip_from for touch in touches] == ["recording"] * 4
    np.testing.assert_allclose([touch.position for touch in touches], points + [hold_point], atol=1e-9)
    unrefined, none = find_pose_touches(poses, calibrated, np.arange(len(poses)) / 20.0, recording_tip=False)
    assert none is None and np.linalg.norm(unrefined[3].position - hold_point) == pytest.approx(2.0, abs=1e-9)


# -- bad input ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "call, message",
    [
        (lambda d: d.add((0.0, np.nan, 0.0), 0.0), "3 finite numbers"),
        (lambda d: d.add((0.0, 0.0), 0.0), "3 finite numbers"),
        (lambda d: (d.add((0, 0, 0), 1.0), d.add((0, 0, 0), 0.5)), "comes before the previous frame"),
        (lambda d: d.add((0, 0, 0), float("inf")), "comes before"),
        (lambda d: d.add_pose(np.eye(3), TIP, 0.0), r"expected a finite \(4, 4\) ProbeToReference"),
        (lambda d: d.add_pose(np.full((4, 4), np.nan), TIP, 0.0), "expected a finite"),
        (lambda d: d.add_pose(np.eye(4), (1.0, 2.0), 0.0), "expected 3 finite numbers"),
        (lambda d: (d.add_invalid(2.0), d.add_pose(np.eye(4), TIP, 1.0)), "comes before"),
    ],
)
def test_bad_frames_are_refused_with_a_reason(call, message):
    with pytest.raises(ValueError, match=message):
        call(HoldStillDetector())


@pytest.mark.parametrize(
    "still_mm, still_s, tip_error_mm",
    [(0.0, 0.5, 5), (-1.0, 0.5, 5), (float("nan"), 0.5, 5), (1.0, -0.1, 5), ("x", 1, 5), (1, 1, -1)],
)
def test_bad_settings_are_refused(still_mm, still_s, tip_error_mm):
    with pytest.raises(ValueError, match="give a finite number"):
        HoldStillDetector(still_mm, still_s, tip_error_mm)


def _arrays(poses):
    poses = np.array(poses)
    return poses[:, :3, :3], poses[:, :3, 3]


def _sums(poses):
    from RAMSICPRegistrationLib.core.fixed_point import FixedPointSums

    sums = FixedPointSums()
    for pose in poses:
        sums.add(pose[:3, :3], pose[:3, 3])
    return sums
