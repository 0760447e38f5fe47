"""The planned tool path to a robot controller over OpenIGTLink, and the robot's reports back (paper eq. 4: "all
surgical tool poses planned in image space should be eventually transmitted to the robot controller").

The wire protocol uses header version 1, so that any OpenIGTLink peer (3D Slicer, PLUS, ROS-IGTL-Bridge, the C++
library) reads it. The path travels as TRANSFORM messages because a TRANSFORM is a whole pose: the blade's
orientation is part of the plan (a POINT or POLYDATA path would carry positions only and leave the orientation to
the robot), and TRANSFORM is the message every peer decodes, the one the tracker feed already uses.

Navigation to robot, device ``PlanToolToRobotBase`` (``PlannedToolToRobotBase`` is longer than OpenIGTLink's 20
characters for a device name)::

    STATUS     code 1, name PATH_BEGIN, text "<count> <path id>"
    TRANSFORM  count times: the TCP poses PlannedToolToRobotBase (robot base, mm), in order
    STATUS     code 1, name PATH_END, text "<count> <path id>"
    STATUS     code 1, name STOP: stop moving (a closed connection stops the robot too)

Robot to navigation::

    STATUS     device Robot: ACCEPTED "<count> <path id>", REFUSED (code 10, the text says why),
               MOVING "<pose> of <count>" (each pose passed), DONE, STOPPED (the text says why)
    TRANSFORM  device ToolToRobotBase: where the robot's kinematics put the TCP, at the robot's report rate
"""

import logging
import select
import socket
import time
import uuid
from dataclasses import dataclass

import numpy as np

from . import igtl_messages as igtl

logger = logging.getLogger(__name__)

#: Port of the robot controller's OpenIGTLink server (the tracker feed has 18944).
ROBOT_PORT = 18945
PATH_DEVICE = "PlanToolToRobotBase"
POSE_DEVICE = "ToolToRobotBase"
STATUS_DEVICE = "Robot"
PATH_BEGIN, PATH_END, STOP = "PATH_BEGIN", "PATH_END", "STOP"
ROBOT_STATES = ("ACCEPTED", "REFUSED", "MOVING", "DONE", "STOPPED")
#: A path longer than this is refused on both sides (about 16 MB of messages).
MAX_PATH_POSES = 100_000


class PathError(ValueError):
    """A path message sequence that breaks the protocol; the text says how."""


@dataclass(frozen=True)
class Path:
    """A complete path as received: its id and (N, 4, 4) poses in robot-base coordinates (mm)."""

    path_id: str
    poses: np.ndarray


def encode_path(poses, path_id):
    """The messages (bytes) that carry ``poses`` (N, 4, 4) as path ``path_id``."""
    poses = _checked_poses(poses)
    if not path_id or any(character.isspace() for character in path_id):
        raise ValueError(f"path id {path_id!r}: give a word without spaces")
    tag = f"{len(poses)} {path_id}"
    begin = igtl.encode_status(PATH_DEVICE, igtl.Status(1, 0, PATH_BEGIN, tag))
    end = igtl.encode_status(PATH_DEVICE, igtl.Status(1, 0, PATH_END, tag))
    return begin + b"".join(igtl.encode_transform(PATH_DEVICE, pose) for pose in poses) + end


class PathAssembler:
    """Collects one path at a time from a connection's messages (the robot's side of the protocol)."""

    def __init__(self):
        self._expected = None  # (count, path id) between PATH_BEGIN and PATH_END
        self._poses = []

    @property
    def receiving(self):
        return self._expected is not None

    def add(self, message):
        """Take one decoded Message; returns the Path it completes, else None. Messages of other devices and
        STOP are not the assembler's (None). Raises PathError when the sequence breaks the protocol (the
        partial path is dropped)."""
        if message.device != PATH_DEVICE:
            return None
        if message.type == "STATUS":
            name = message.content.error_name
            if name == PATH_BEGIN:
                if self._expected is not None:
                    self._fail(f"PATH_BEGIN of a new path before PATH_END of path {self._expected[1]}")
                self._expected, self._poses = _parse_tag(message.content.text), []
                return None
            if name == PATH_END:
                if self._expected is None:
                    self._fail("PATH_END without PATH_BEGIN")
                tag = _parse_tag(message.content.text)
                if tag != self._expected or len(self._poses) != tag[0]:
                    self._fail(
                        f"path {self._expected[1]}: PATH_BEGIN announced {self._expected[0]} poses, "
                        f"{len(self._poses)} arrived, PATH_END says {tag[0]} ({tag[1]})"
                    )
                path = Path(tag[1], np.array(self._poses))
                self._expected, self._poses = None, []
                return path
            return None
        if self._expected is None:
            self._fail("a path pose outside PATH_BEGIN ... PATH_END")
        if len(self._poses) >= self._expected[0]:
            self._fail(f"path {self._expected[1]}: more than the {self._expected[0]} poses announced")
        self._poses.append(message.content)
        return None

    def _fail(self, reason):
        self._expected, self._poses = None, []
        raise PathError(reason)


def _parse_tag(text):
    parts = text.split()
    if len(parts) != 2 or not parts[0].isdigit() or not 1 <= int(parts[0]) <= MAX_PATH_POSES:
        raise PathError(f"path tag {text!r}: expected '<count> <path id>' with 1 to {MAX_PATH_POSES} poses")
    return int(parts[0]), parts[1]


def _checked_poses(poses):
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or not 1 <= len(poses) <= MAX_PATH_POSES:
        raise ValueError(f"tool path: expected 1 to {MAX_PATH_POSES} poses (N, 4, 4), got shape {poses.shape}")
    if not np.isfinite(poses).all():
        raise ValueError("tool path: a pose contains NaN or infinity; plan the path again")
    return poses


class RobotLink:
    """The navigation's connection to a robot controller: send a path, read the robot's reports.

    Args:
        host, port: the robot controller's OpenIGTLink server.
        timeout_s: for connecting and for sending.
        keep_poses: keep every reported ToolToRobotBase in ``poses`` and every STATUS (name, text) in ``statuses``
            (a test's or a recording's wish; a long cut at 125 Hz gives some 10 MB an hour).
    """

    def __init__(self, host="127.0.0.1", port=ROBOT_PORT, timeout_s=2.0, keep_poses=False):
        self.host, self.port = host, port
        try:
            self.socket = socket.create_connection((host, port), timeout=timeout_s)
        except OSError as error:
            raise OSError(
                f"the robot controller at {host}:{port} cannot be reached ({error.strerror or error}); start its "
                "OpenIGTLink server or check the address"
            ) from None
        self.socket.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.buffer = bytearray()
        self.state = "CONNECTED"  # then one of ROBOT_STATES, or DISCONNECTED
        self.states_seen = set()  # every state the robot reported for the path now out (several may come at once)
        self.status_text = ""
        self.path_id = None
        self.path_size = 0
        self.passed = 0  # poses of the path the robot has passed
        self.pose = None  # the last ToolToRobotBase (4, 4)
        self.reports = 0  # ToolToRobotBase messages received
        self.poses = [] if keep_poses else None
        self.statuses = [] if keep_poses else None
        self.skipped = 0

    @property
    def connected(self):
        return self.socket is not None

    def send_path(self, poses, path_id=None):
        """Send (N, 4, 4) PlannedToolToRobotBase poses as one path; returns its id."""
        if self.socket is None:
            raise OSError(f"the connection to the robot controller at {self.host}:{self.port} is closed")
        path_id = path_id or uuid.uuid4().hex[:12]
        data = encode_path(poses, path_id)
        self._send(data)
        self.path_id, self.path_size, self.passed, self.state = path_id, len(poses), 0, "SENT"
        self.states_seen = set()
        self.status_text = f"path {path_id}: {len(poses)} poses sent"
        return path_id

    def stop(self):
        """Ask the robot to stop where it is."""
        self._send(igtl.encode_status(PATH_DEVICE, igtl.Status(1, 0, STOP, "stop")))

    def _send(self, data):
        try:
            self.socket.sendall(data)
        except OSError as error:
            self.close()
            raise OSError(f"sending to the robot controller at {self.host}:{self.port} failed ({error})") from None

    def poll(self, timeout_s=0.0):
        """Read and apply what the robot has sent (waiting up to ``timeout_s`` for the first bytes); returns the
        number of messages applied."""
        if self.socket is None:
            return 0
        readable, _, _ = select.select([self.socket], [], [], timeout_s)
        while readable:
            try:
                chunk = self.socket.recv(1 << 16)
            except (BlockingIOError, InterruptedError, socket.timeout):
                break
            except OSError as error:
                self._lost(f"the connection broke ({error})")
                break
            if not chunk:
                self._lost("the robot controller closed the connection")
                break
            self.buffer += chunk
            readable, _, _ = select.select([self.socket], [], [], 0.0)
        try:
            messages, rest = igtl.decode_available(bytes(self.buffer))
        except igtl.MessageError as error:
            self._lost(f"unreadable message from the robot ({error})")
            return 0
        self.buffer = bytearray(rest)
        for message in messages:
            self._apply(message)
        return len(messages)

    def wait_for(self, states, timeout_s):
        """Poll until the robot has reported one of ``states`` for the path now out (or the connection is lost);
        returns the first of ``states`` it reported, else the state it is in."""
        deadline = time.monotonic() + timeout_s
        while not self.states_seen & set(states) and self.state != "DISCONNECTED":
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            self.poll(min(remaining, 0.1))
        return next((state for state in states if state in self.states_seen), self.state)

    def _apply(self, message):
        if message.type == "TRANSFORM" and message.device == POSE_DEVICE:
            self.pose, self.reports = message.content, self.reports + 1
            if self.poses is not None:
                self.poses.append(message.content)
        elif message.type == "STATUS" and message.device == STATUS_DEVICE:
            name, text = message.content.error_name, message.content.text
            if name not in ROBOT_STATES:
                self.skipped += 1
                return
            self.state, self.status_text = name, text
            self.states_seen.add(name)
            if self.statuses is not None:
                self.statuses.append((name, text))
            if name == "MOVING":
                self.passed = int(text.split()[0]) if text.split() and text.split()[0].isdigit() else self.passed
            elif name == "DONE":
                self.passed = self.path_size
        else:
            self.skipped += 1

    def _lost(self, why):
        logger.warning("robot link: %s", why)
        self.close()
        self.state, self.status_text = "DISCONNECTED", why

    def close(self):
        if self.socket is not None:
            self.socket.close()
            self.socket = None
        if self.state != "DISCONNECTED":
            self.state = "DISCONNECTED"
