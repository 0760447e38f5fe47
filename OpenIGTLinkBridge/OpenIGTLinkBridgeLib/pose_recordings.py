"""A tool's recorded poses from any of the three files they come in, for ``ramsicp pivot``: a PLUS sequence file
(``.igs.mha``, ``.seq.mha``, ``.mha``), a folder of 4x4 text matrices or a CSV table
(``RAMSICPRegistrationLib.io.pose_files``).

From a PLUS file the poses are the tool's in the reference's frame (``inv(ReferenceToTracker) @ ToolToTracker``,
paper eq. 2) in the frames where both are valid, timed by the frames' time stamps; without a reference transform in
the file, the tool's in the tracker's frame (the divot then must not move relative to the tracker). The tool, when
not named, is the one that moves (``recorded_touches.choose_tool``).
"""

from pathlib import Path

import numpy as np

from RAMSICPRegistrationLib.io.pose_files import PoseRecording, read_pose_folder, read_pose_table

from .plus_sequence import SUFFIXES, read_sequence
from .recorded_touches import DEFAULT_REFERENCE, choose_tool, recorded_poses


def read_poses(path, tool=None, reference=DEFAULT_REFERENCE):
    """PoseRecording of ``path`` (a PLUS sequence file, a folder of matrices or a CSV table); ValueError in one line
    naming the file and what to give."""
    path = Path(path)
    if path.is_dir():
        return read_pose_folder(path)
    if not path.exists():
        raise ValueError(f"{path}: no such file or folder")
    if path.name.lower().endswith(SUFFIXES):
        return recorded_tool_poses(read_sequence(path), tool, reference)
    return read_pose_table(path)


def recorded_tool_poses(recording, tool=None, reference=DEFAULT_REFERENCE):
    """PoseRecording of ``tool`` in a PLUS Recording (the module's docstring)."""
    warnings = list(recording.warnings)
    has_reference = reference in recording.transform_names
    tool = choose_tool(recording, reference if has_reference else None) if tool is None else tool
    if has_reference:
        poses, valid = recorded_poses(recording, tool, reference)
    else:
        if tool not in recording.transform_names:
            names = ", ".join(recording.transform_names)
            raise ValueError(f"{recording.path}: has no {tool} transform (it has {names}); choose one with --tool")
        poses, valid = recording.matrices(tool)
        warnings.append(f"{recording.path}: no {reference} transform: the poses of {tool} are in the tracker's frame")
    if not valid.all():
        warnings.append(f"{recording.path}: {int((~valid).sum())} frames without a valid {tool} pose left out")
    frames = np.flatnonzero(valid)
    return PoseRecording(
        poses[valid],
        recording.timestamps_s[valid],
        f"{recording.path} ({tool})",
        tuple(f"frame {index}" for index in frames),
        tuple(warnings),
    )
