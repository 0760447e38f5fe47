"""Touches of a probe tip in a recorded session, with the detector live collection uses (``core.hold_still``).

For every frame in which both the tool (e.g. StylusToTracker) and the reference (ReferenceToTracker) are valid, the
tool's pose in reference coordinates is ``inv(ReferenceToTracker) @ ToolToTracker`` (paper eq. 2), timed by the
frame's recorded time stamp; ``core.hold_still.HoldStillDetector`` finds the touches (held still or swivelled; the
rests at the start and the end marked). A frame in which either is invalid is a gap: it neither ends nor extends a
touch. The tool, when not named, is the one tool besides the reference that moves in the recording.
"""

from dataclasses import dataclass

import numpy as np

from RAMSICPRegistrationLib.core.hold_still import (
    DEFAULT_STILL_MM,
    DEFAULT_STILL_S,
    DEFAULT_TIP_ERROR_MM,
    HoldStillDetector,
    find_pose_touches,
)

DEFAULT_REFERENCE = "ReferenceToTracker"
#: A tool whose origin spans less than this (mm, bounding-box diagonal in the reference frame) lay still throughout.
MOVING_MM = 10.0


@dataclass(frozen=True)
class RecordedTouches:
    """The touches of one tool in a recording (rests included, marked); ``tips`` (N, 3) mm and ``frames`` (N,) of
    its valid frames (the calibrated tip in reference coordinates); ``recording_tip`` (3,) mm: the tip the
    recording's pivots agree on (None with fewer than two), which placed its partial pivots and holds."""

    touches: list
    tips: np.ndarray
    frames: np.ndarray
    frame_count: int
    tool: str = ""
    reference: str = ""
    recording_tip: object = None

    @property
    def landmarks(self):
        """The touches that are not rests."""
        return [touch for touch in self.touches if not touch.rest]

    def to_dict(self):
        return {
            "tool": self.tool,
            "reference": self.reference,
            "touches": [touch.to_dict() for touch in self.touches],
            "recording_tip_mm": None if self.recording_tip is None else [float(v) for v in self.recording_tip],
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


def tool_motion_mm(recording, name, reference=DEFAULT_REFERENCE):
    """How far (mm) the origin of ``name`` moved: the diagonal of its bounding box over its valid frames, in
    ``reference``'s coordinates when the recording has it (else the tracker's); 0 with fewer than 2 valid frames."""
    matrices, valid = recording.matrices(name)
    if reference in recording.transform_names and reference != name:
        references, reference_valid = recording.matrices(reference)
        valid = valid & reference_valid
        matrices = np.linalg.solve(references[valid], matrices[valid])
    else:
        matrices = matrices[valid]
    if len(matrices) < 2:
        return 0.0
    origins = matrices[:, :3, 3]
    return float(np.linalg.norm(origins.max(axis=0) - origins.min(axis=0)))


def choose_tool(recording, reference=DEFAULT_REFERENCE, option="--tool"):
    """The recording's tool: the only transform besides ``reference``, or the only one of them that moves (more than
    MOVING_MM); else ValueError listing the names and how far each moved."""
    others = [name for name in recording.transform_names if name != reference]
    if not others:
        raise ValueError(
            f"{recording.path}: holds no tool besides {reference} (it has {', '.join(recording.transform_names)})"
        )
    if len(others) == 1:
        return others[0]
    motion = {name: tool_motion_mm(recording, name, reference) for name in others}
    moving = [name for name in others if motion[name] > MOVING_MM]
    if len(moving) == 1:
        return moving[0]
    listed = ", ".join(f"{name} (moved {motion[name]:.0f} mm)" for name in others)
    reason = "several of them move" if moving else "none of them moves"
    raise ValueError(f"{recording.path}: which tool? {reason}: {listed}; choose one with {option}")


def recorded_poses(recording, tool, reference=DEFAULT_REFERENCE):
    """(ToolToReference (N, 4, 4), valid (N,) bool) for every frame; invalid frames hold the identity."""
    names = recording.transform_names
    for option, name in (("--tool", tool), ("--reference", reference)):
        if name not in names:
            raise ValueError(
                f"{recording.path}: has no {name} transform (it has {', '.join(names)}); choose one with {option}"
            )
    tools, tool_valid = recording.matrices(tool)
    references, reference_valid = recording.matrices(reference)
    valid = tool_valid & reference_valid
    poses = np.tile(np.eye(4), (len(valid), 1, 1))
    poses[valid] = np.linalg.solve(references[valid], tools[valid])  # inv(ReferenceToTracker) @ ToolToTracker
    return poses, valid


def recorded_tips(recording, tool, reference, tip_mm):
    """(tips (N, 3) in reference coordinates, frame indices (N,), valid (all frames,) bool) of ``tool``'s tip."""
    tip = _tip(tip_mm, tool)
    poses, valid = recorded_poses(recording, tool, reference)
    tips = poses[valid, :3, :3] @ tip + poses[valid, :3, 3]
    return tips, np.flatnonzero(valid), valid


def find_recorded_touches(
    recording,
    tool=None,
    reference=DEFAULT_REFERENCE,
    tip_mm=(0.0, 0.0, 0.0),
    still_mm=DEFAULT_STILL_MM,
    still_s=DEFAULT_STILL_S,
    tip_error_mm=DEFAULT_TIP_ERROR_MM,
    recording_tip=True,
):
    """The touches of ``tool``'s tip (``tip_mm`` in the tool's frame) in ``recording``, in reference coordinates.
    ``tool`` None: ``choose_tool``; ``recording_tip``: place them with the tip the recording's swivels agree on
    (``core.touch.with_recording_tip``)."""
    HoldStillDetector(still_mm, still_s, tip_error_mm)  # refuses bad settings before any work
    tool = choose_tool(recording, reference) if tool is None else tool
    tip = _tip(tip_mm, tool)
    poses, valid = recorded_poses(recording, tool, reference)
    touches, recording_tip = find_pose_touches(
        poses,
        tip,
        recording.timestamps_s,
        valid,
        still_mm=still_mm,
        still_s=still_s,
        tip_error_mm=tip_error_mm,
        recording_tip=recording_tip,
    )
    tips = poses[valid, :3, :3] @ tip + poses[valid, :3, 3]
    return RecordedTouches(touches, tips, np.flatnonzero(valid), len(recording.frames), tool, reference, recording_tip)


def _tip(tip_mm, tool):
    tip = np.asarray(tip_mm, dtype=np.float64)
    if tip.shape != (3,) or not np.isfinite(tip).all():
        raise ValueError(f"tip {tip_mm!r}: give 3 finite numbers, the tip in the {tool} frame (mm)")
    return tip
