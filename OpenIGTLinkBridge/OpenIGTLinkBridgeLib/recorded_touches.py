"""Touches (hold-still periods) of a probe tip in a recorded session, with the detector live collection uses.

For every frame in which both the tool (e.g. StylusToTracker) and the reference (ReferenceToTracker) are
valid, the tip in reference coordinates is ``inv(ReferenceToTracker) @ ToolToTracker @ tip`` (paper eq. 2),
timed by the frame's recorded time stamp; ``core.hold_still.HoldStillDetector`` finds the touches. A frame in
which either is invalid ends the period running (the tip's whereabouts are then unknown).
"""

from dataclasses import dataclass

import numpy as np

from RAMSICPRegistrationLib.core.hold_still import DEFAULT_STILL_MM, DEFAULT_STILL_S, HoldStillDetector


@dataclass(frozen=True)
class RecordedTouches:
    """The touches of one tool in a recording; ``tips`` (N, 3) mm and ``frames`` (N,) of its valid frames."""

    touches: list
    tips: np.ndarray
    frames: np.ndarray
    frame_count: int

    def to_dict(self):
        return {
            "touches": [touch.to_dict() for touch in self.touches],
            "valid_frames": int(len(self.frames)),
            "frames": int(self.frame_count),
        }


def frame_timing(recording):
    """Frame timing of a recording: count, duration (s), mean rate (Hz) and interval statistics (ms)."""
    intervals_ms = 1000.0 * np.diff(recording.timestamps_s)
    duration = float(recording.timestamps_s[-1] - recording.timestamps_s[0])
    summary = {"frames": len(recording.frames), "duration_s": duration}
    if len(intervals_ms):
        summary.update(
            rate_hz=(len(recording.frames) - 1) / duration if duration > 0 else float("inf"),
            interval_median_ms=float(np.median(intervals_ms)),
            interval_sd_ms=float(np.std(intervals_ms)),
            interval_min_ms=float(intervals_ms.min()),
            interval_max_ms=float(intervals_ms.max()),
        )
    return summary


def recorded_tips(recording, tool, reference, tip_mm):
    """(tips (N, 3) in reference coordinates, frame indices (N,), valid (all frames,) bool) of ``tool``'s tip."""
    names = recording.transform_names
    for option, name in (("--tool", tool), ("--reference", reference)):
        if name not in names:
            raise ValueError(
                f"{recording.path}: has no {name} transform (it has {', '.join(names)}); choose one with {option}"
            )
    tip = np.asarray(tip_mm, dtype=np.float64)
    if tip.shape != (3,) or not np.isfinite(tip).all():
        raise ValueError(f"tip {tip_mm!r}: give 3 finite numbers, the tip in the {tool} frame (mm)")
    tools, tool_valid = recording.matrices(tool)
    references, reference_valid = recording.matrices(reference)
    valid = tool_valid & reference_valid
    tool_to_reference = np.linalg.solve(references[valid], tools[valid])  # inv(ReferenceToTracker) @ ToolToTracker
    tips = np.einsum("nij,j->ni", tool_to_reference[:, :3, :3], tip) + tool_to_reference[:, :3, 3]
    return tips, np.flatnonzero(valid), valid


def find_recorded_touches(
    recording,
    tool="StylusToTracker",
    reference="ReferenceToTracker",
    tip_mm=(0.0, 0.0, 0.0),
    still_mm=DEFAULT_STILL_MM,
    still_s=DEFAULT_STILL_S,
):
    """The touches of ``tool``'s tip (``tip_mm`` in the tool's frame) in ``recording``, in reference coordinates."""
    tips, frames, valid = recorded_tips(recording, tool, reference, tip_mm)
    detector = HoldStillDetector(still_mm, still_s)
    times = recording.timestamps_s
    position = 0
    for index in range(len(recording.frames)):
        if not valid[index]:
            detector.finish()
            continue
        detector.add(tips[position], times[index], index)
        position += 1
    detector.finish()
    return RecordedTouches(list(detector.touches), tips, frames, len(recording.frames))
