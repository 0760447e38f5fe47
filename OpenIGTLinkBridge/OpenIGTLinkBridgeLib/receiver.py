"""The OpenIGTLink receiver under the OpenIGTLinkBridge widget: transforms into MRML nodes, tool status, eq. 2.

``poll()`` (called from the widget's timer, or by tests) connects or reconnects, reads what has arrived without
blocking, writes each TRANSFORM into the linear transform node of the same name (created once, then reused, so nodes
that SlicerOpenIGTLink already feeds are shared), keeps ``ProbeToReference = inv(ReferenceToTracker) @
ProbeToTracker`` (paper eq. 2) up to date, once per tracker frame (both tools with the frame's time stamp, as PLUS
and our server send them; a tool missing from a frame leaves ProbeToReference as it was), and tracks each tool's
status: valid, missing (flagged invalid by the server), stale (no update for ``stale_after_s``) or disconnected.
Malformed messages are logged and skipped; a broken stream (bad header) resets the connection.

``start_recording(path)`` records every TRANSFORM that arrives, valid or not, to a PLUS sequence file
(``plus_sequence``) that PLUS, Slicer's Sequences module and ``ramsicp-tracker-server --replay`` read: the messages
of one tracker frame (same time stamp) form one file frame, in the order they arrived, with their status; the file
on disk is complete after every frame. ``stop_recording()`` closes it.
"""

import errno
import logging
import select
import socket
import time

import numpy as np

from . import igtl_messages as igtl
from .host_lookup import HostLookup

logger = logging.getLogger(__name__)

STALE_AFTER_S = 1.0
RECONNECT_INTERVAL_S = 0.5


class TrackerReceiver:
    """OpenIGTLink client writing into a vtkMRMLScene.

    Args:
        scene: the MRML scene (``slicer.mrmlScene`` in Slicer).
        reference_name, probe_name: device names of the reference body and the probe (PLUS: ...ToTracker).
        probe_to_reference_name: the node eq. 2 keeps up to date.
        clock: monotonic clock (s), injectable for tests.
    """

    def __init__(
        self,
        scene,
        host="127.0.0.1",
        port=18944,
        reference_name="ReferenceToTracker",
        probe_name="ProbeToTracker",
        probe_to_reference_name="ProbeToReference",
        stale_after_s=STALE_AFTER_S,
        clock=time.monotonic,
    ):
        self.scene, self.host, self.port = scene, host, port
        self.reference_name, self.probe_name = reference_name, probe_name
        self.probe_to_reference_name = probe_to_reference_name
        self.stale_after_s, self.clock = stale_after_s, clock
        self.socket = None
        self.buffer = bytearray()
        self.last_update = {}
        self.valid = {}
        self.matrices = {}
        self.timestamps = {}  # device -> time stamp (s) of its last valid pose: the tracker frame it belongs to
        self.received = {}
        self.skipped = 0
        self.last_status = None
        self._next_attempt = 0.0
        self._pending = None  # a connection attempt in progress
        self._lookup = None  # the HostLookup of the server's address
        self.resolution_error = None  # why the host name could not be resolved at the last attempt
        self.on_update = None  # optional callable(device, matrix, timestamp_s) after each valid transform
        self.recorder = None  # the SequenceRecorder while recording
        self.recording_error = None  # why a recording stopped by itself (a write failed), else None
        self._frame_stamp = None
        self._frame_poses = {}  # device -> (matrix, status) of the frame being received
        self._recorded_devices = {}

    # -- connection ----------------------------------------------------------------------------------------
    @property
    def connected(self):
        return self.socket is not None

    def _address(self):
        """The server's IPv4 address, or None while a host name is being looked up (``host_lookup``: never on the
        calling thread, Slicer's GUI thread, since a lookup can take seconds)."""
        if self._lookup is None:
            self._lookup = HostLookup(self.host)
        if not self._lookup.done:
            return None
        if self._lookup.error is not None:  # try again at the next interval: the network may come back
            if self.resolution_error != self._lookup.error:
                logger.warning("%s", self._lookup.error)
            self.resolution_error, self._lookup = self._lookup.error, None
            self._next_attempt = self.clock() + RECONNECT_INTERVAL_S
            return None
        self.resolution_error = None
        return self._lookup.address

    def _connect(self):
        """Advance a non-blocking connection attempt; never blocks the caller (Slicer's GUI thread)."""
        if self._pending is None:
            if self.clock() < self._next_attempt:
                return False
            address = self._address()
            if address is None:
                return False
            self._next_attempt = self.clock() + RECONNECT_INTERVAL_S
            pending = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            pending.setblocking(False)
            error = pending.connect_ex((address, self.port))
            if error not in (0, errno.EINPROGRESS, errno.EWOULDBLOCK, errno.EAGAIN):
                pending.close()
                return False
            self._pending = pending
        _, writable, _ = select.select([], [self._pending], [], 0)
        if not writable:
            if self.clock() >= self._next_attempt:  # no answer within the interval: start again
                self._pending.close()
                self._pending = None
            return False
        pending, self._pending = self._pending, None
        if pending.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR) != 0:
            pending.close()
            return False
        pending.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.socket, self.buffer = pending, bytearray()
        logger.info("connected to the OpenIGTLink server at %s:%d", self.host, self.port)
        return True

    def _reset(self, why):
        logger.warning("OpenIGTLink connection reset: %s", why)
        if self.socket is not None:
            self.socket.close()
        self.socket, self.buffer = None, bytearray()

    def close(self):
        for sock in (self.socket, self._pending):
            if sock is not None:
                sock.close()
        self.socket = self._pending = None
        self.stop_recording()

    # -- recording -----------------------------------------------------------------------------------------
    def start_recording(self, path):
        """Record the transforms received from now on to the PLUS sequence file ``path`` (.igs.mha, .seq.mha).

        Raises ``plus_sequence.SequenceFileError`` (a ValueError) when the file cannot be written. Returns the
        SequenceRecorder; its ``frames`` counts the frames written so far.
        """
        from .plus_sequence import SequenceRecorder

        self.stop_recording()
        self.recorder = SequenceRecorder(path)
        self.recording_error = None
        self._frame_stamp, self._frame_poses, self._recorded_devices = None, {}, {}
        logger.info("recording the tracker feed to %s", path)
        return self.recorder

    def stop_recording(self):
        """Write the last frame and close the file; returns its path (None when not recording)."""
        if self.recorder is None:
            return None
        self._write_frame()
        recorder, self.recorder = self.recorder, None
        path = recorder.close()
        logger.info("recorded %d frames to %s", recorder.frames, path)
        return path

    def _record(self, message, valid):
        if message.timestamp_s != self._frame_stamp or message.device in self._frame_poses:
            self._write_frame()  # a new time stamp (or a device again) starts the next tracker frame
            self._frame_stamp = message.timestamp_s
        status = "OK" if valid else message.metadata.get("TransformStatus", "INVALID")
        if not valid and status.strip().upper() in ("OK", ""):
            status = "INVALID"  # flagged invalid by TransformValid: never recorded as OK
        self._frame_poses[message.device] = (message.content, status)
        self._recorded_devices.setdefault(message.device, None)

    def _write_frame(self):
        from .plus_sequence import SequenceFileError, TrackedFrame

        if self.recorder is None or not self._frame_poses:
            return
        poses = dict(self._frame_poses)
        for device in self._recorded_devices:  # a device seen before but not sent now (version 1): invalid
            poses.setdefault(device, (np.eye(4), "INVALID"))
        frame = TrackedFrame(
            self._frame_stamp,
            {device: matrix for device, (matrix, _) in poses.items()},
            {device: status for device, (_, status) in poses.items()},
        )
        self._frame_poses = {}
        try:
            self.recorder.add(frame)
        except SequenceFileError as error:  # e.g. the disk is full: keep tracking, keep what was written
            self.recording_error = str(error)
            logger.error("recording stopped: %s", error)
            recorder, self.recorder = self.recorder, None
            recorder.close()

    # -- polling -------------------------------------------------------------------------------------------
    def poll(self):
        """Read everything that has arrived and apply it; returns the number of messages applied."""
        if self.socket is None and not self._connect():
            return 0
        while True:
            try:
                chunk = self.socket.recv(1 << 16)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as error:
                self._reset(f"read failed ({error})")
                return 0
            if not chunk:
                self._reset("the server closed the connection")
                return 0
            self.buffer += chunk
        return self._apply_buffered()

    def _apply_buffered(self):
        applied = 0
        while len(self.buffer) >= igtl.HEADER_SIZE:
            try:
                header = igtl.decode_header(bytes(self.buffer[: igtl.HEADER_SIZE]))
            except igtl.MessageError as error:
                self.skipped += 1
                self._reset(f"unreadable header ({error})")  # the stream cannot be re-synchronised
                return applied
            end = igtl.HEADER_SIZE + header.body_size
            if len(self.buffer) < end:
                break  # the rest of the body is still on its way
            body = bytes(self.buffer[igtl.HEADER_SIZE : end])
            del self.buffer[:end]
            try:
                message = igtl.decode_body(header, body)
            except igtl.MessageError as error:
                self.skipped += 1
                logger.warning("skipped a message: %s", error)
                continue
            self._apply(message)
            applied += 1
        return applied

    def _apply(self, message):
        if message.type == "STATUS":
            self.last_status = message.content
            return
        device = message.device
        self.received[device] = self.received.get(device, 0) + 1
        self.last_update[device] = self.clock()
        valid = message.metadata.get("TransformValid", "true").lower() != "false"
        self.valid[device] = valid
        if self.recorder is not None:
            self._record(message, valid)
        if not valid:
            return
        self.matrices[device] = message.content
        self.timestamps[device] = message.timestamp_s
        _write(self._node(device), message.content)
        if (
            device in (self.reference_name, self.probe_name)
            and self._fresh(self.reference_name)
            and self._fresh(self.probe_name)
            and self.timestamps[self.reference_name] == self.timestamps[self.probe_name]
        ):  # once per tracker frame, when its second tool arrives: never a probe of one frame on another's reference
            probe_to_reference = np.linalg.inv(self.matrices[self.reference_name]) @ self.matrices[self.probe_name]
            _write(self._node(self.probe_to_reference_name), probe_to_reference)
        if self.on_update is not None:
            self.on_update(device, message.content, message.timestamp_s)

    def _node(self, name):
        node = self.scene.GetFirstNodeByName(name)
        if node is None or not node.IsA("vtkMRMLTransformNode"):
            node = self.scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", name)
        return node

    def _fresh(self, device):
        return self.valid.get(device, False) and self.clock() - self.last_update.get(device, -1e9) <= self.stale_after_s

    def status(self, device):
        """'disconnected', 'never seen', 'stale', 'missing' or 'valid'."""
        if self.socket is None:
            return "disconnected"
        if device not in self.last_update:
            return "never seen"
        if self.clock() - self.last_update[device] > self.stale_after_s:
            return "stale"
        return "valid" if self.valid.get(device) else "missing"


def _write(node, matrix):
    from vtkmodules.vtkCommonMath import vtkMatrix4x4

    vtk_matrix = vtkMatrix4x4()
    for row in range(4):
        for column in range(4):
            vtk_matrix.SetElement(row, column, float(matrix[row][column]))
    node.SetMatrixTransformToParent(vtk_matrix)
