"""Replay a PLUS sequence file through the OpenIGTLink server, as PLUS's SavedDataSource replays one.

Frames go out at their recorded times (scaled by ``speed``), in the recorded order, under the recorded names
(optionally renamed, e.g. ``Stylus`` -> ``Probe`` turns PLUS's StylusToTracker into ProbeToTracker). Each
transform carries its recorded status: the server applies the same version 1 / version 2 rules as to a live
tracker (invalid poses are not sent to version 1 peers, and are sent flagged ``TransformValid=false`` to
version 2 peers). Message time stamps keep the recorded intervals, shifted to start at the replay's start, so
a hold-still period lasts as long in the replay as in the recording whatever the speed. The replay starts with
the first client, so that it sees every frame; with ``loop`` it starts again after the last frame, one frame
interval later.
"""

import math
import time

import numpy as np

from .igtl_server import DevicePose

#: OpenIGTLink device names are at most 20 characters.
MAX_DEVICE_NAME = 20


class ReplaySource:
    """A frame source for ``TrackerServer(source=...)`` playing a ``plus_sequence.Recording``."""

    def __init__(self, recording, speed=1.0, loop=False, rename=None):
        try:
            speed = float(speed)
        except (TypeError, ValueError):
            speed = math.nan
        if not math.isfinite(speed) or speed <= 0:
            raise ValueError(f"replay speed {speed!r}: give a number above 0 (1 = recorded speed)")
        self.recording, self.speed, self.loop = recording, speed, bool(loop)
        self.names = rename_devices(recording.transform_names, rename or {})
        times = recording.timestamps_s
        backwards = np.flatnonzero(np.diff(times) < 0)
        if backwards.size:
            index = int(backwards[0]) + 1
            raise ValueError(
                f"{recording.path}: frame {index}, Timestamp: {times[index]!r} s is earlier than frame "
                f"{index - 1}'s; a replay needs times in order"
            )
        self.offsets_s = times - times[0]
        interval = float(np.median(np.diff(times))) if len(times) > 1 else 0.0
        self.loop_s = self.offsets_s[-1] + interval  # PLUS also holds the last frame for one interval
        if self.loop and self.loop_s <= 0:
            raise ValueError(f"{recording.path}: all frames share one time stamp; nothing to loop over")
        self.status = None
        self.timestamp_s = None
        self.wait_for_client = True
        self.frames_read = 0
        self._index = 0
        self._round = 0
        self._start = None  # monotonic time of the first frame
        self._wall_start = None

    def next_due(self):
        """Monotonic time the next frame is due at; None once a replay without loop has sent its last frame."""
        if self._start is None:
            self._start, self._wall_start = time.monotonic(), time.time()
            self.status = (1, "", f"replaying {_name(self.recording)}")
        if self._index >= len(self.offsets_s):
            return None
        return self._start + (self._round * self.loop_s + self.offsets_s[self._index]) / self.speed

    def read(self):
        frame = self.recording.frames[self._index]
        self.timestamp_s = self._wall_start + self._round * self.loop_s + self.offsets_s[self._index]
        poses = [
            DevicePose(self.names[name], matrix, "OK" if frame.is_valid(name) else _status(frame, name))
            for name, matrix in frame.transforms.items()
        ]
        self.frames_read += 1
        self._index += 1
        if self._index == len(self.offsets_s):
            if self.loop:
                self._index, self._round = 0, self._round + 1
            else:
                self.status = (1, "", f"replay finished: {self.frames_read} frames of {_name(self.recording)}")
        return poses

    def close(self):
        pass


def _status(frame, name):
    text = frame.statuses.get(name, "INVALID").strip().upper()
    return "INVALID" if text == "OK" else text


def _name(recording):
    return recording.path.name if recording.path is not None else "the recording"


def parse_renames(texts):
    """``["Stylus=Probe", ...]`` -> {"Stylus": "Probe"}; raises ValueError naming a malformed one."""
    renames = {}
    for text in texts or ():
        old, equals, new = text.partition("=")
        old, new = old.strip(), new.strip()
        if not equals or not old or not new or not (old + new).replace("_", "").isalnum():
            raise ValueError(f"--rename {text!r}: write OLD=NEW, e.g. Stylus=Probe or StylusToTracker=ProbeToTracker")
        if old in renames:
            raise ValueError(f"--rename {text!r}: {old} is renamed twice")
        renames[old] = new
    return renames


def rename_devices(names, renames):
    """Device name for each recorded transform name: a rename OLD=NEW applies to the whole name OLD, or to its
    first frame (``OLDToX`` -> ``NEWToX``). Refuses renames that match nothing, collide or are too long."""
    devices = {}
    used = set()
    for old in renames:
        if not any(name == old or name.startswith(old + "To") for name in names):
            raise ValueError(
                f"--rename {old}={renames[old]}: the recording has no {old} transform (it has {', '.join(names)})"
            )
    for name in names:
        device = name
        for old, new in renames.items():
            if name == old:
                device = new
            elif name.startswith(old + "To") and device == name:
                device = new + name[len(old) :]
        if device in used:
            raise ValueError(f"renaming gives two transforms the name {device}; rename one of them differently")
        if len(device) > MAX_DEVICE_NAME or not device.isascii():
            raise ValueError(f"device name {device!r} is longer than OpenIGTLink's {MAX_DEVICE_NAME} characters")
        used.add(device)
        devices[name] = device
    return devices
