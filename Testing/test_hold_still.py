"""The hold-still detector (core.hold_still): touches found with known answers."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.hold_still import HoldStillDetector, find_touches


def test_a_hand_computed_period():
    """Three still frames then a jump: mean (0.2, 0, 0), spread sqrt((0.2^2 + 0 + 0.2^2) / 3) mm."""
    detector = HoldStillDetector(still_mm=1.0, still_s=0.2)
    assert detector.add((0.0, 0.0, 0.0), 10.0, 7) is None
    assert detector.add((0.2, 0.0, 0.0), 10.1, 8) is None
    assert detector.pending() is None  # 0.1 s so far: not yet a touch
    assert detector.add((0.4, 0.0, 0.0), 10.2, 9) is None
    assert detector.pending() is not None  # 0.2 s: qualifies, but is only emitted when the period ends
    touch = detector.add((5.0, 0.0, 0.0), 10.3, 10)
    np.testing.assert_allclose(touch.position, (0.2, 0.0, 0.0), atol=1e-12)
    assert touch.spread_mm == pytest.approx(np.sqrt(0.08 / 3))
    assert (touch.first_frame, touch.last_frame, touch.frames) == (7, 9, 3)
    assert (touch.start_s, touch.end_s) == (10.0, 10.2) and touch.duration_s == pytest.approx(0.2)
    assert detector.finish() is None  # the new run holds one frame only
    assert detector.touches == [touch]
    assert touch.to_dict()["position_mm"] == pytest.approx([0.2, 0.0, 0.0])


def test_a_period_ends_when_any_of_its_frames_would_leave_the_ball_around_the_mean():
    """x = 0, 0.9, 1.9: mean 0.933, every frame within 1 mm. x = 0, 0.9, 2.1: mean 1.0, 2.1 is 1.1 mm away."""
    kept = find_touches([(0, 0, 0), (0.9, 0, 0), (1.9, 0, 0)], [0.0, 1.0, 2.0], still_mm=1.0, still_s=0.5)
    assert [(t.first_frame, t.last_frame) for t in kept] == [(0, 2)]
    np.testing.assert_allclose(kept[0].position, (2.8 / 3, 0, 0))
    ended = find_touches([(0, 0, 0), (0.9, 0, 0), (2.1, 0, 0)], [0.0, 1.0, 2.0], still_mm=1.0, still_s=0.5)
    assert [(t.first_frame, t.last_frame) for t in ended] == [(0, 1)]
    # An early frame can fall out too: x = 0, nine times 1.0, 1.9 (mean 0.991), then 1.9 again moves the mean
    # to 1.067, 1.067 mm from x = 0, although the new frame is only 0.833 mm from it.
    x = [0.0] + [1.0] * 9 + [1.9, 1.9]
    touches = find_touches([(value, 0, 0) for value in x], np.arange(12.0), still_mm=1.0, still_s=0.5)
    assert [(t.first_frame, t.last_frame) for t in touches] == [(0, 10)]
    np.testing.assert_allclose(touches[0].position, (10.9 / 11, 0, 0))


def test_a_period_shorter_than_still_s_is_not_a_touch_and_finish_ends_the_last():
    tips = [(0, 0, 0)] * 3 + [(10, 0, 0)] * 4
    times = [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6]  # first run 0.2 s, second 0.3 s
    touches = find_touches(tips, times, still_mm=1.0, still_s=0.3)
    assert len(touches) == 1 and (touches[0].first_frame, touches[0].last_frame) == (3, 6)
    np.testing.assert_allclose(touches[0].position, (10, 0, 0))
    assert touches[0].spread_mm == 0.0


def _synthetic_session(rng, positions, rate_hz=60.0):
    """Tip samples (N, 3), times (N,) and the true hold intervals: each touch held 0.7-1.4 s with hand tremor
    (8-12 Hz, 0.15 mm) and tracker noise (0.1 mm RMS), reached by a lifted, decelerating move; one brief pause
    (0.25 s) mid-move and one slow slide (10 mm/s for 1.5 s) that must not count."""
    tips, times, holds = [], [], []
    clock = 0.0
    current = positions[0] + np.array([0.0, 0.0, 30.0])

    def sample(point):
        nonlocal clock
        tips.append(point + rng.normal(scale=0.1 / np.sqrt(3), size=3))
        times.append(clock)
        clock += (1.0 + rng.uniform(-0.1, 0.1)) / rate_hz  # timing jitter

    for number, target in enumerate(positions):
        move_s = rng.uniform(0.4, 0.8)
        start, steps = current.copy(), int(move_s * rate_hz)
        for step in range(1, steps + 1):
            fraction = step / steps
            eased = 1 - (1 - fraction) ** 3  # decelerates onto the bone
            point = start + (target - start) * eased + np.array([0, 0, 15.0]) * np.sin(np.pi * fraction)
            sample(point)
            if number == 3 and step == steps // 2:  # a brief pause in the air, shorter than still_s
                for _ in range(int(0.25 * rate_hz)):
                    sample(point)
        hold_s = rng.uniform(0.7, 1.4)
        frequency, phase = rng.uniform(8, 12), rng.uniform(0, 2 * np.pi)
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        begin = len(times)
        hold_start = clock
        while clock - hold_start < hold_s:
            sample(target + 0.15 * np.sin(2 * np.pi * frequency * (clock - hold_start) + phase) * direction)
        holds.append((begin, len(times) - 1))
        if number == 5:  # a slow slide across the bone: 10 mm/s is motion, not a touch
            slide_start = clock
            while clock - slide_start < 1.5:
                sample(target + np.array([10.0 * (clock - slide_start) + 3.0, 0.0, 0.0]))
        current = target + np.array([0.0, 0.0, 0.0])
    return np.array(tips), np.array(times), holds


def test_eight_touches_with_tremor_are_found_within_a_tenth_of_a_millimetre_and_nothing_else():
    rng = np.random.default_rng(16)
    positions = rng.uniform(-60, 60, size=(8, 3))
    tips, times, holds = _synthetic_session(rng, positions)
    touches = find_touches(tips, times, still_mm=1.0, still_s=0.5)
    assert len(touches) == 8
    errors = np.linalg.norm(np.array([t.position for t in touches]) - positions, axis=1)
    assert errors.max() < 0.1, errors
    for touch, (first, last) in zip(touches, holds):
        assert first - 3 <= touch.first_frame and touch.last_frame <= last + 1  # inside the true hold
        assert touch.frames >= 0.9 * (last - first + 1)  # and covering nearly all of it
        assert 0.05 < touch.spread_mm < 0.3  # tremor (0.15 mm amplitude) and noise (0.1 mm RMS)


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda d: d.add((0.0, np.nan, 0.0), 0.0), "3 finite numbers"),
        (lambda d: d.add((0.0, 0.0), 0.0), "3 finite numbers"),
        (lambda d: (d.add((0, 0, 0), 1.0), d.add((0, 0, 0), 0.5)), "comes before the previous frame"),
        (lambda d: d.add((0, 0, 0), float("inf")), "comes before"),
    ],
)
def test_bad_frames_are_refused_with_a_reason(call, message):
    with pytest.raises(ValueError, match=message):
        call(HoldStillDetector())


@pytest.mark.parametrize("still_mm, still_s", [(0.0, 0.5), (-1.0, 0.5), (float("nan"), 0.5), (1.0, -0.1), ("x", 1)])
def test_bad_settings_are_refused(still_mm, still_s):
    with pytest.raises(ValueError, match="give a finite number"):
        HoldStillDetector(still_mm, still_s)


def test_a_slow_drift_counts_as_held_up_to_twice_the_radius_over_the_time():
    """Drifting at v mm/s, the frames stay within still_mm of their mean for 2 * still_mm / v seconds."""
    times = np.arange(0.0, 3.0, 0.01)
    tips = np.outer(times, (1.0, 0.0, 0.0))  # 1 mm/s
    touches = find_touches(tips, times, still_mm=0.5, still_s=0.5)
    assert [(t.first_frame, t.last_frame) for t in touches] == [(0, 100), (101, 200), (201, 299)]  # 1 s each
    for touch in touches:  # every frame of each period lies within 0.5 mm of its mean
        inside = tips[touch.first_frame : touch.last_frame + 1]
        assert np.abs(inside[:, 0] - touch.position[0]).max() <= 0.5
