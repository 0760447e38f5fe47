"""Touches of a tracked probe: the tip held at one point, held still or swivelled, live or in a recording.

A surgeon collects a point by holding the probe tip on it: still, or swivelling the probe about it (as PLUS's
landmark detection expects: the tip fixed while the shaft turns). The detector is fed one frame at a time: the
probe's pose (ProbeToReference (4, 4)) and its calibrated tip (the tip in the probe frame, mm), the frame's time (s)
and number; or only a tip position (3,) for a stream without poses; or an invalid frame (the probe not tracked).
The same detector serves live collection (the navigation controller) and whole recordings (``find_pose_touches``).

**A touch** is a run of frames in which the tip stays at one point: some point ``p`` of the probe within
``tip_error_mm`` of the calibrated tip stays within ``still_mm`` of one point ``q`` of the reference in every frame
(``core.fixed_point``, least squares with ``|p - tip| <= tip_error_mm``), for at least ``still_s`` and
``MIN_FRAMES`` frames. Held still, this is the tip within ``still_mm`` of its mean; swivelled, the swivel is one
touch even with a tip miscalibrated by up to ``tip_error_mm`` (a tip 2.5 mm off traces an arc of 1.9 mm over a
44 degree swivel, which a ball of 1 mm around the mean tip splits into several touches). Where the touch is, and
whether it is a swivel (PLUS's test: a point 100 mm up the shaft moves 30 mm), is ``core.touch``'s.

- **Landing**: frames of a run's first ``LANDING_S`` that stop fitting once the run's point is known better (the
  tip still landing: a decelerating approach, or a frame near the mean of the calibrated tips but not at the
  swivel's fixed point, which differs from it by the tip's calibration error) are left out rather than ending the
  touch.
- **Drift**: a run whose tip (at the run's point of the probe) drifts more than ``MAX_DRIFT_MM`` over it (its
  least-squares line through time) is cut at its ends to the longest stretch that does not: a hand slowing down in
  the air, or a tip sliding, moves steadily; a tip held on a point only scatters. A tip sliding slower than
  ``MAX_DRIFT_MM / still_s`` (5 mm/s) is held still by this definition.
- **Glitches and gaps**: up to ``MAX_GLITCH_FRAMES`` consecutive frames off the point, followed by one on it, are
  left out of the touch (``dropped_frames``) instead of ending it; invalid frames neither end a touch nor count (the
  touch goes on if the tip is back at its point when tracking resumes).
- **Rest**: a touch that is not a swivel with no tracked frame of the probe before it (the stream began with the
  probe lying still) or after it (``finish(end_of_recording=True)``: it was put down). Reported, marked ``rest``.

A touch is emitted when its run ends (``add``/``add_pose`` returns it, ``MAX_GLITCH_FRAMES + 1`` frames after its
last) or when the stream ends (``finish``). Fitting the whole run rather than its first frames makes the point
independent of when the frames arrived. ``pending()`` tells a live user interface, while the tip is still held, that
the current run already qualifies. Defaults: ``still_mm`` 1.5 mm (PLUS's StylusTipMaximumDisplacementThresholdMm;
tracker noise of 0.25 mm RMS stays under 0.6 mm over hundreds of frames), ``still_s`` 0.2 s (the project's own live
demo dwells 0.25 s on each point).
"""

import math
from dataclasses import replace

import numpy as np

from .fixed_point import FixedPointSums
from .touch import SWIVEL_SHAFT_MOTION_MM, Touch, touch_of_poses, with_recording_tip  # noqa: F401 (Touch: API)

#: Defaults for a touch: the tip within 1.5 mm (PLUS's StylusTipMaximumDisplacementThresholdMm) for 0.2 s.
DEFAULT_STILL_MM = 1.5
DEFAULT_STILL_S = 0.2
#: How far (mm) the tip's calibration may be off: the swivel's fixed point may lie this far from the calibrated tip.
DEFAULT_TIP_ERROR_MM = 5.0
#: Fewest frames of a touch, and most consecutive frames off the point a touch survives.
MIN_FRAMES = 3
MAX_GLITCH_FRAMES = 2
#: A run's frames of its first LANDING_S (s) that stop fitting as the run's point becomes known better may be left
#: out (the tip still landing: a decelerating approach spends 0.1-0.4 s within 1.5 mm of its point).
LANDING_S = 0.5
#: The most (mm) a touch's tip may drift (its least-squares line through time, from its first frame to its last).
MAX_DRIFT_MM = 1.0
#: Frame times are sums of float intervals; a period this much shorter than still_s still counts.
_TIME_TOLERANCE_S = 1e-9
_NO_TIP = np.zeros(3)


class _Run:
    """The frames of the run being grown: poses (in growing buffers), times, frame numbers, fixed-point sums."""

    def __init__(self, tip):
        self.tip = tip
        self.sums = FixedPointSums()
        self.count = 0
        self._rotations, self._translations = np.empty((64, 3, 3)), np.empty((64, 3))
        self.times, self.frames = [], []
        self.dropped = 0
        self.started_s = None  # the time of the run's first frame, kept when landing frames are left out

    def __len__(self):
        return self.count

    @property
    def rotations(self):
        return self._rotations[: self.count]

    @property
    def translations(self):
        return self._translations[: self.count]

    def _stage(self, rotation, translation):
        """Write a frame after the run's last one without adding it (the buffers grow as needed)."""
        if self.count == len(self._rotations):
            self._rotations = np.concatenate([self._rotations, np.empty_like(self._rotations)])
            self._translations = np.concatenate([self._translations, np.empty_like(self._translations)])
        self._rotations[self.count], self._translations[self.count] = rotation, translation

    def fits(self, rotation, translation, still_mm, tip_error_mm, landing_s):
        """Would every frame, this one included, lie within still_mm of the run's fixed point? Returns the new state
        (sums, frames of the run's start to leave out) when it would, else None. Frames of the run's first
        ``landing_s`` (from its first frame, even one left out since) may be left out for this one to fit (the module's
        docstring: landing)."""
        self._stage(rotation, translation)
        rotations = self._rotations[: self.count + 1]
        translations = self._translations[: self.count + 1]
        landing = int(np.searchsorted(self.times, self.started_s + landing_s, side="right"))
        sums, skip = self.sums.copy(), 0
        sums.add(rotation, translation)
        while True:
            fit = sums.within(self.tip, tip_error_mm)
            distances = np.linalg.norm(rotations[skip:] @ fit.p + translations[skip:] - fit.q, axis=1)
            off = np.flatnonzero(distances[:-1] > still_mm)  # the run's frames off the point
            if not off.size:
                return (sums, skip) if distances[-1] <= still_mm else None
            last = skip + int(off[-1])
            if last >= landing or last + 1 >= self.count:
                return None
            skip = last + 1
            sums = FixedPointSums()
            for kept_rotation, kept_translation in zip(rotations[skip:], translations[skip:]):
                sums.add(kept_rotation, kept_translation)

    def append(self, rotation, translation, time_s, frame, state):
        self.sums, skip = state
        self.started_s = time_s if self.started_s is None else self.started_s
        self._stage(rotation, translation)
        self.count += 1
        self.times.append(time_s)
        self.frames.append(frame)
        if skip:
            self._rotations[: self.count - skip] = self._rotations[skip : self.count].copy()
            self._translations[: self.count - skip] = self._translations[skip : self.count].copy()
            self.count -= skip
            del self.times[:skip], self.frames[:skip]


class HoldStillDetector:
    """Finds touches in a stream of probe poses or tip positions (see the module's docstring).

    Args:
        still_mm: radius (mm) around the touch's point within which the tip stays in every frame; > 0.
        still_s: shortest touch (s); >= 0.
        tip_error_mm: how far (mm) the held point may lie from the calibrated tip; >= 0.
    """

    def __init__(self, still_mm=DEFAULT_STILL_MM, still_s=DEFAULT_STILL_S, tip_error_mm=DEFAULT_TIP_ERROR_MM):
        self.still_mm = _number(still_mm, "hold-still radius", "mm", minimum=0.0, inclusive=False)
        self.still_s = _number(still_s, "hold-still time", "s", minimum=0.0, inclusive=True)
        self.tip_error_mm = _number(tip_error_mm, "tip calibration error", "mm", minimum=0.0, inclusive=True)
        self.touches = []
        self._last_time = -math.inf
        self._last_frame = None
        self._seen_valid = False  # a tracked frame came before the current run
        self._valid_before_run = False
        self._run = None
        self._off = []  # frames off the run's point, not yet known to be glitches or the run's end

    # -- feeding -------------------------------------------------------------------------------------------
    def add_pose(self, probe_to_reference, tip_in_probe, time_s, frame=None):
        """Feed one tracked frame: ProbeToReference (4, 4), the calibrated tip (3,) in the probe frame (mm), the
        frame's time (s, non-decreasing) and number (default: a running count). Returns the Touch this frame
        ended, or None."""
        pose = np.asarray(probe_to_reference, dtype=np.float64)
        if pose.shape != (4, 4) or not np.isfinite(pose).all():
            raise ValueError(f"probe pose of shape {pose.shape}: expected a finite (4, 4) ProbeToReference")
        tip = np.asarray(tip_in_probe, dtype=np.float64)
        if tip.shape != (3,) or not np.isfinite(tip).all():
            raise ValueError(f"tip {np.asarray(tip_in_probe).tolist()!r}: expected 3 finite numbers (mm, probe frame)")
        time_s, frame = self._clock(time_s, frame)
        return self._feed(pose[:3, :3].copy(), pose[:3, 3].copy(), tip, time_s, frame)

    def add(self, tip, time_s, frame=None):
        """Feed one tip position (3,) mm without its pose (a touch is then the tip held still). Returns the Touch
        this frame ended, or None."""
        tip = np.asarray(tip, dtype=np.float64)
        if tip.shape != (3,) or not np.isfinite(tip).all():
            raise ValueError(f"tip position {tip.tolist()!r}: expected 3 finite numbers (mm)")
        time_s, frame = self._clock(time_s, frame)
        return self._feed(np.eye(3), tip, _NO_TIP, time_s, frame)

    def add_invalid(self, time_s, frame=None):
        """A frame in which the probe was not tracked: it neither ends nor extends the touch running."""
        self._clock(time_s, frame)

    def finish(self, end_of_recording=True):
        """End of the stream: returns the Touch of the run still going, or None. ``end_of_recording``: the stream
        ended by itself (a probe still then was put down: a rest, unless its last frames had left the point);
        False when a user stops collecting live."""
        touch = self._close(end_of_recording and not self._off)
        self._off = []
        return touch

    def pending(self):
        """The Touch the current run would give if it ended now, or None while it does not qualify yet."""
        return self._touch_of_run(end_of_recording=False)

    @property
    def holding(self):
        """True while the current run already qualifies as a touch (cheaper than ``pending``)."""
        return self._held_part(self._run) is not None

    # -- the run -------------------------------------------------------------------------------------------
    def _clock(self, time_s, frame):
        try:
            time_s = float(time_s)
        except (TypeError, ValueError):
            time_s = math.nan
        if not math.isfinite(time_s) or time_s < self._last_time:
            raise ValueError(f"frame time {time_s!r} s comes before the previous frame's {self._last_time!r} s")
        if frame is None:
            frame = 0 if self._last_frame is None else self._last_frame + 1
        self._last_time, self._last_frame = time_s, int(frame)
        return time_s, int(frame)

    def _feed(self, rotation, translation, tip, time_s, frame):
        run = self._run
        if run is None or not np.array_equal(tip, run.tip):  # the first frame, or a new calibration: a new run
            touch = self._close(False)
            self._off = []
            self._start(rotation, translation, tip, time_s, frame)
            return touch
        state = run.fits(rotation, translation, self.still_mm, self.tip_error_mm, LANDING_S)
        if state is not None:
            run.dropped += len(self._off)  # the frames off the point were glitches
            self._off = []
            run.append(rotation, translation, time_s, frame, state)
            return None
        self._off.append((rotation, translation, time_s, frame))
        if len(self._off) <= MAX_GLITCH_FRAMES:
            return None
        touch, off = self._close(False), self._off
        self._off = []
        for index, (rotation, translation, time_s, frame) in enumerate(off):  # the next run, greedily
            state = None if index == 0 else self._run.fits(rotation, translation, self.still_mm, self.tip_error_mm, 0)
            if state is None:  # a run of fewer than MIN_FRAMES frames ends: never a touch
                self._start(rotation, translation, tip, time_s, frame)
            else:
                self._run.append(rotation, translation, time_s, frame, state)
        return touch

    def _start(self, rotation, translation, tip, time_s, frame):
        self._valid_before_run = self._seen_valid
        self._seen_valid = True
        self._run = _Run(tip)
        sums = FixedPointSums()
        sums.add(rotation, translation)
        self._run.append(rotation, translation, time_s, frame, (sums, 0))

    def _close(self, end_of_recording):
        touch = self._touch_of_run(end_of_recording)
        if touch is not None:
            self.touches.append(touch)
        self._run = None
        return touch

    def _qualifies(self, times, first, last):
        return last - first + 1 >= MIN_FRAMES and times[last] - times[first] >= self.still_s - _TIME_TOLERANCE_S

    def _held_part(self, run):
        """(first, last) frames of the run (indices) that make a touch: all of them when the tip drifted at most
        MAX_DRIFT_MM, else the longest stretch found by leaving out frames at either end (a slow landing or
        lift-off); None when no such stretch qualifies."""
        if run is None or not self._qualifies(run.times, 0, len(run) - 1):
            return None
        times = np.asarray(run.times)
        fit = run.sums.within(run.tip, self.tip_error_mm)
        drift = _Drift(run.rotations @ fit.p + run.translations, times)
        first, last = 0, len(run) - 1
        while drift(first, last) > MAX_DRIFT_MM:
            if drift(first + 1, last) <= drift(first, last - 1):
                first += 1
            else:
                last -= 1
            if not self._qualifies(times, first, last):
                return None
        return first, last

    def _touch_of_run(self, end_of_recording):
        run = self._run
        held = self._held_part(run)
        if held is None:
            return None
        first, last = held
        end_of_recording = end_of_recording and last == len(run) - 1
        rotations, translations = run.rotations[first : last + 1].copy(), run.translations[first : last + 1].copy()
        sums = run.sums
        if (first, last) != (0, len(run) - 1):
            sums = FixedPointSums()
            for rotation, translation in zip(rotations, translations):
                sums.add(rotation, translation)
        touch = touch_of_poses(rotations, translations, run.tip, sums, self.tip_error_mm)
        valid_before = self._valid_before_run or first > 0
        rest = touch.shaft_motion_mm < SWIVEL_SHAFT_MOTION_MM and (not valid_before or end_of_recording)
        return replace(
            touch,
            first_frame=run.frames[first],
            last_frame=run.frames[last],
            start_s=run.times[first],
            end_s=run.times[last],
            rest=rest,
            dropped_frames=run.dropped,
        )


class _Drift:
    """How far (mm) the least-squares line through tips[first..last] (N, 3) over their times (N,) s moves from the
    first frame to the last: from prefix sums, so that any stretch costs the same."""

    def __init__(self, tips, times):
        self.times = times - times[0]
        self._t = np.concatenate([[0.0], np.cumsum(self.times)])
        self._tt = np.concatenate([[0.0], np.cumsum(self.times**2)])
        self._x = np.vstack([np.zeros(3), np.cumsum(tips - tips[0], axis=0)])
        self._tx = np.vstack([np.zeros(3), np.cumsum(self.times[:, None] * (tips - tips[0]), axis=0)])

    def __call__(self, first, last):
        count = last - first + 1
        t, tt = self._t[last + 1] - self._t[first], self._tt[last + 1] - self._tt[first]
        x, tx = self._x[last + 1] - self._x[first], self._tx[last + 1] - self._tx[first]
        spread = tt - t * t / count
        if count < 2 or spread <= 1e-12 * max(tt, 1.0):
            return 0.0
        velocity = (tx - t * x / count) / spread
        return float(np.linalg.norm(velocity) * (self.times[last] - self.times[first]))


def _number(value, what, unit, minimum, inclusive):
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if not math.isfinite(number) or number < minimum or (number == minimum and not inclusive):
        bound = f">= {minimum:g}" if inclusive else f"> {minimum:g}"
        raise ValueError(f"{what} {value!r} {unit}: give a finite number {bound}")
    return number


def find_touches(tips, times_s, frames=None, still_mm=DEFAULT_STILL_MM, still_s=DEFAULT_STILL_S):
    """All touches in a whole stream of tip positions: tips (N, 3) mm, times (N,) s, frame numbers (N,)
    (default 0..N-1). Without poses a touch is the tip held still."""
    tips = np.asarray(tips, dtype=np.float64)
    times_s = np.asarray(times_s, dtype=np.float64)
    if tips.ndim != 2 or tips.shape[1] != 3 or len(times_s) != len(tips):
        raise ValueError(f"tips {tips.shape} and times {times_s.shape}: expected (N, 3) and (N,)")
    frames = np.arange(len(tips)) if frames is None else np.asarray(frames)
    detector = HoldStillDetector(still_mm, still_s)
    for tip, time_s, frame in zip(tips, times_s, frames):
        detector.add(tip, time_s, int(frame))
    detector.finish()
    return list(detector.touches)


def find_pose_touches(
    poses,
    tip_in_probe,
    times_s,
    valid=None,
    frames=None,
    still_mm=DEFAULT_STILL_MM,
    still_s=DEFAULT_STILL_S,
    tip_error_mm=DEFAULT_TIP_ERROR_MM,
    recording_tip=True,
):
    """All touches in a whole recording: ProbeToReference poses (N, 4, 4), the calibrated tip (3,) mm, times (N,)
    s, ``valid`` (N,) bool (default all), frame numbers (N,) (default 0..N-1); invalid frames' poses are ignored.

    Returns (touches, tip): with ``recording_tip`` the touches are placed with the tip the recording's full pivots
    agree on (``core.touch.with_recording_tip``; tip None, and each touch placed by itself, with fewer than two)."""
    poses = np.asarray(poses, dtype=np.float64)
    times_s = np.asarray(times_s, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or len(times_s) != len(poses):
        raise ValueError(f"poses {poses.shape} and times {times_s.shape}: expected (N, 4, 4) and (N,)")
    valid = np.ones(len(poses), dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    frames = np.arange(len(poses)) if frames is None else np.asarray(frames)
    detector = HoldStillDetector(still_mm, still_s, tip_error_mm)
    for pose, time_s, is_valid, frame in zip(poses, times_s, valid, frames):
        if is_valid:
            detector.add_pose(pose, tip_in_probe, time_s, int(frame))
        else:
            detector.add_invalid(time_s, int(frame))
    detector.finish()
    if not recording_tip:
        return list(detector.touches), None
    touches, tip, _ = with_recording_tip(detector.touches, tip_in_probe)
    return touches, tip
