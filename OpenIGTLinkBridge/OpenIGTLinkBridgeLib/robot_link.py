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

import errno
import logging
import os
import select
import socket
import time
import uuid
from dataclasses import dataclass

import numpy as np

from . import igtl_messages as igtl
from .host_lookup import HostLookup

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
    return begin + igtl.encode_transforms(PATH_DEVICE, poses) + end


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
    """The navigation's connection to a robot controller: send a path, read the robot's reports. No call waits.

    The link connects without blocking (``connect_ex`` on a non-blocking socket, a host name looked up off the
    calling thread by ``host_lookup``), queues what it sends and writes it as the socket takes it, and reads only
    what has arrived: ``poll()`` advances all of it and returns at once, so Slicer's GUI thread can call it from a
    timer (the module's logic does, for as long as the link is open, whichever module is shown: a robot controller
    drops a client that stops reading, and the robot stops). ``wait_for`` waits, for scripts and tests.

    States (``state``): CONNECTING, CONNECTED, SENT (a path is out, no answer yet), then what the robot reports
    (``ROBOT_STATES``), and DISCONNECTED (``status_text`` says why: refused, no answer within ``timeout_s``, lost).

    Args:
        host, port: the robot controller's OpenIGTLink server.
        timeout_s: for connecting: no connection after this long is a failure.
        keep_poses: keep every reported ToolToRobotBase in ``poses`` and every STATUS (name, text) in ``statuses``
            (a test's or a recording's wish; a long cut at 125 Hz gives some 10 MB an hour).
        clock: monotonic clock (s).
    """

    def __init__(self, host="127.0.0.1", port=ROBOT_PORT, timeout_s=2.0, keep_poses=False, clock=time.monotonic):
        self.host, self.port, self.timeout_s, self.clock = host, port, timeout_s, clock
        self.socket = None  # once connected
        self._pending = None  # the socket while connecting
        self._lookup = HostLookup(host)
        self._deadline = clock() + timeout_s
        self.outbox = bytearray()  # queued bytes the socket has not taken yet
        self._unsent_path = 0  # bytes at the end of the outbox that belong to the path (cancelled by a stop)
        self.buffer = bytearray()
        self.state = "CONNECTING"  # CONNECTED, SENT, one of ROBOT_STATES, or DISCONNECTED
        self.states_seen = set()  # every state the robot reported for the path now out (several may come at once)
        self.status_text = f"connecting to {host}:{port}"
        self.path_id = None
        self.path_size = 0
        self.passed = 0  # poses of the path the robot has passed
        self.pose = None  # the last ToolToRobotBase (4, 4)
        self.reports = 0  # ToolToRobotBase messages received
        self.poses = [] if keep_poses else None
        self.statuses = [] if keep_poses else None
        self.skipped = 0
        self.poll()

    @property
    def connected(self):
        """True once the connection is made (and until it is closed)."""
        return self.socket is not None

    @property
    def is_open(self):
        """True while connecting or connected: the link has not failed or been closed."""
        return self.state != "DISCONNECTED"

    def send_path(self, poses, path_id=None):
        """Queue (N, 4, 4) PlannedToolToRobotBase poses as one path (written by this call and the next polls, even
        while still connecting); returns its id at once."""
        if not self.is_open:
            raise OSError(f"the connection to the robot controller at {self.host}:{self.port} is closed")
        path_id = path_id or uuid.uuid4().hex[:12]
        data = encode_path(poses, path_id)
        self.outbox += data
        self._unsent_path = len(self.outbox)
        self.path_id, self.path_size, self.passed, self.state = path_id, len(poses), 0, "SENT"
        self.states_seen = set()
        self.status_text = f"path {path_id}: {len(poses)} poses sent"
        self._flush()
        return path_id

    def stop(self):
        """Ask the robot to stop where it is. A path not wholly written yet is cancelled instead: the rest is
        dropped and the connection closed (the robot never receives its end, and a closed connection stops it)."""
        if self._unsent_path:
            self.close()
            self.status_text = "stopped before the whole path was sent; the connection was closed"
            return
        self.outbox += igtl.encode_status(PATH_DEVICE, igtl.Status(1, 0, STOP, "stop"))
        self._flush()

    # -- connection ------------------------------------------------------------------------------------------
    def _connect(self):
        """Advance the connection attempt; True once connected."""
        if self._pending is None:
            if not self._lookup.done:
                return self._check_deadline()
            if self._lookup.error is not None:
                self._lost(f"the robot controller at {self.host}:{self.port} cannot be reached ({self._lookup.error})")
                return False
            pending = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            pending.setblocking(False)
            error = pending.connect_ex((self._lookup.address, self.port))
            if error not in (0, errno.EINPROGRESS, errno.EWOULDBLOCK, errno.EAGAIN):
                pending.close()
                self._unreachable(os.strerror(error))
                return False
            self._pending = pending
        _, writable, _ = select.select([], [self._pending], [], 0)
        if not writable:
            return self._check_deadline()
        pending, self._pending = self._pending, None
        error = pending.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
        if error:
            pending.close()
            self._unreachable(os.strerror(error))
            return False
        pending.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.socket = pending
        if self.state == "CONNECTING":
            self.state, self.status_text = "CONNECTED", f"connected to {self.host}:{self.port}"
        return True

    def _check_deadline(self):
        if self.clock() >= self._deadline:
            self._unreachable(f"no connection within {self.timeout_s:g} s")
        return False

    def _unreachable(self, why):
        self._lost(
            f"the robot controller at {self.host}:{self.port} cannot be reached ({why}); start its OpenIGTLink "
            "server or check the address"
        )

    def _flush(self):
        """Write what the socket takes now of the queued bytes."""
        if self.socket is None or not self.outbox:
            return
        try:
            sent = self.socket.send(self.outbox)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as error:
            self._lost(f"sending to the robot controller at {self.host}:{self.port} failed ({error})")
            return
        del self.outbox[:sent]
        self._unsent_path = max(0, self._unsent_path - sent)

    # -- reading -----------------------------------------------------------------------------------------------
    def poll(self, timeout_s=0.0):
        """Connect, write and read what can be now; with ``timeout_s`` > 0 wait up to that long for the first
        bytes (a script's wish; the navigation polls with 0). Returns the number of messages applied."""
        if not self.is_open or (self.socket is None and not self._connect()):
            return 0
        self._flush()
        if self.socket is None:
            return 0
        readable, _, _ = select.select([self.socket], [], [], timeout_s)
        while readable:
            try:
                chunk = self.socket.recv(1 << 16)
            except (BlockingIOError, InterruptedError):
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
        """Poll until the robot has reported one of ``states`` for the path now out (or the link is lost);
        returns the first of ``states`` it reported, else the state it is in. Blocks: for scripts and tests."""
        deadline = time.monotonic() + timeout_s
        while not self.states_seen & set(states) and self.is_open:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            self.poll()
            waiting = self.socket or self._pending
            if waiting is not None and not self.states_seen & set(states):
                writing = [waiting] if self.outbox or waiting is self._pending else []
                select.select([self.socket] if self.socket else [], writing, [], min(remaining, 0.05))
            elif waiting is None:
                time.sleep(min(remaining, 0.01))  # a host name being looked up
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
        self.status_text = why

    def close(self):
        for sock in (self.socket, self._pending):
            if sock is not None:
                sock.close()
        self.socket = self._pending = None
        self.outbox, self._unsent_path = bytearray(), 0
        self.state = "DISCONNECTED"
