"""Hold-still detection: the touches of a tracked probe tip, live or in a recording.

A surgeon collects a point by holding the probe tip still on the bone. The detector is fed the tip position
(3,) in mm, its time in s and its frame number, one frame at a time, and finds the *hold-still periods*: runs of
consecutive frames in which every tip lies within ``still_mm`` of the run's mean, lasting at least ``still_s``
(last frame's time minus first frame's time). Each period becomes one :class:`Touch`: the mean tip over the
whole period, its frame range, start and end times and its spread (RMS distance of the frames from the mean).

A touch is emitted when its period ends: when a tip leaves the ``still_mm`` ball around the run's mean
(``add`` returns the touch) or when the stream ends (``finish``). Averaging the whole period rather than the
first few frames makes the point independent of when the frames happened to arrive: the same recording, or the
same tracker frames delivered with different network timing, give the same touch. ``pending()`` tells a live
user interface, while the tip is still held, that the current period already qualifies.

Choose ``still_mm`` well above the tracker's frame-to-frame noise (about four times its RMS), or a single noisy
frame ends a period early. By this definition a tip sliding slower than ``2 * still_mm / still_s`` (4 mm/s with
the defaults) is held still: its frames stay within ``still_mm`` of their mean for ``still_s``.
"""

import math
from dataclasses import dataclass

import numpy as np

#: Defaults for a surgeon's touch: the tip held within 1 mm for half a second.
DEFAULT_STILL_MM = 1.0
DEFAULT_STILL_S = 0.5
#: Frame times are sums of float intervals; a period this much shorter than still_s still counts.
_TIME_TOLERANCE_S = 1e-9


@dataclass(frozen=True)
class Touch:
    """One hold-still period: ``position`` (3,) mm is the mean tip over frames ``first_frame..last_frame``."""

    position: np.ndarray
    first_frame: int
    last_frame: int
    start_s: float
    end_s: float
    frames: int
    spread_mm: float

    @property
    def duration_s(self):
        return self.end_s - self.start_s

    def to_dict(self):
        return {
            "position_mm": [float(value) for value in self.position],
            "first_frame": int(self.first_frame),
            "last_frame": int(self.last_frame),
            "start_s": float(self.start_s),
            "end_s": float(self.end_s),
            "frames": int(self.frames),
            "spread_mm": float(self.spread_mm),
        }


class HoldStillDetector:
    """Finds hold-still periods in a stream of tip positions (see the module's docstring).

    Args:
        still_mm: radius (mm) around the period's mean within which every frame of a period lies; > 0.
        still_s: shortest period (s) that counts as a touch; >= 0.
    """

    def __init__(self, still_mm=DEFAULT_STILL_MM, still_s=DEFAULT_STILL_S):
        self.still_mm = _number(still_mm, "hold-still radius", "mm", minimum=0.0, inclusive=False)
        self.still_s = _number(still_s, "hold-still time", "s", minimum=0.0, inclusive=True)
        self.touches = []
        self._last_time = -math.inf
        self._last_frame = None
        self._start_run()

    def _start_run(self):
        self._tips = []
        self._sum = np.zeros(3)
        self._low, self._high = np.full(3, np.inf), np.full(3, -np.inf)
        self._first = None  # (frame, time) of the run's first frame
        self._last = None

    def add(self, tip, time_s, frame=None):
        """Feed one frame: tip (3,) mm, time (s, non-decreasing), frame number (default: a running count).

        Returns the Touch whose period this frame ended, or None.
        """
        tip = np.asarray(tip, dtype=np.float64)
        if tip.shape != (3,) or not np.isfinite(tip).all():
            raise ValueError(f"tip position {tip.tolist()!r}: expected 3 finite numbers (mm)")
        time_s = float(time_s)
        if not math.isfinite(time_s) or time_s < self._last_time:
            raise ValueError(f"frame time {time_s!r} s comes before the previous frame's {self._last_time!r} s")
        if frame is None:
            frame = 0 if self._last_frame is None else self._last_frame + 1
        self._last_time, self._last_frame = time_s, int(frame)
        touch = None
        if self._tips and not self._still_with(tip):
            touch = self._close_run()
        self._tips.append(tip)
        self._sum += tip
        self._low, self._high = np.minimum(self._low, tip), np.maximum(self._high, tip)
        if self._first is None:
            self._first = (int(frame), time_s)
        self._last = (int(frame), time_s)
        return touch

    def _still_with(self, tip):
        """Would every tip of the run, ``tip`` included, lie within still_mm of the new mean?"""
        mean = (self._sum + tip) / (len(self._tips) + 1)
        low, high = np.minimum(self._low, tip), np.maximum(self._high, tip)
        if np.linalg.norm(np.maximum(high - mean, mean - low)) <= self.still_mm:
            return True  # the run's bounding box lies within the ball: no need to look at every frame
        if np.linalg.norm(tip - mean) > self.still_mm:
            return False
        return bool(np.max(np.linalg.norm(np.array(self._tips) - mean, axis=1)) <= self.still_mm)

    def finish(self):
        """End of the stream: returns the Touch of the period still running, or None."""
        return self._close_run()

    def pending(self):
        """The Touch the current period would give if it ended now, or None while it is shorter than still_s."""
        return self._touch_of_run()

    def _touch_of_run(self):
        if not self._tips or self._last[1] - self._first[1] < self.still_s - _TIME_TOLERANCE_S:
            return None
        tips = np.array(self._tips)
        position = tips.mean(axis=0)
        spread = float(np.sqrt(np.mean(np.sum((tips - position) ** 2, axis=1))))
        return Touch(position, self._first[0], self._last[0], self._first[1], self._last[1], len(tips), spread)

    def _close_run(self):
        touch = self._touch_of_run()
        if touch is not None:
            self.touches.append(touch)
        self._start_run()
        return touch


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
    """All touches in a whole stream: tips (N, 3) mm, times (N,) s, frame numbers (N,) (default 0..N-1)."""
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
