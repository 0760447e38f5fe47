"""PLUS-compatible OpenIGTLink server: tracker poses as TRANSFORM messages (``ProbeToTracker``,
``ReferenceToTracker``), tracker state as STATUS, to several clients at once.

Header version 1 by default (OpenIGTLink 1.x peers read it): invalid poses are then not sent, as PLUS does.
With version 2 every pose is sent, invalid ones with ``TransformStatus=INVALID`` and ``TransformValid=false``
metadata. One ``select`` loop paced by the tracker's rate serves every client; sends never block: a client whose
backlog passes ``MAX_BACKLOG_BYTES`` (it stopped reading) is dropped with a log line instead of stalling the rest.
Each new tracker frame is sent once (a poll that finds the same NDI frame numbers sends nothing). A tracker that
stops answering is reported by STATUS, with the reason, and reconnected after a back-off that doubles up to
``BACKOFF_MAX_S``. Any source with ``read()`` and ``next_due()`` can feed it: ``replay.ReplaySource`` streams a
recorded PLUS sequence file instead. The ``ramsicp-tracker-server`` program is ``tracker_server``.
"""

import logging
import select
import socket
import threading
import time
from dataclasses import dataclass

from . import igtl_messages as igtl

logger = logging.getLogger(__name__)

DEFAULT_PORT = 18944
DEFAULT_RATE_HZ = 60.0
MAX_BACKLOG_BYTES = 256 * 1024
DEFAULT_NAMES = {"Probe": "ProbeToTracker", "Reference": "ReferenceToTracker"}
BACKOFF_START_S = 0.25
BACKOFF_MAX_S = 8.0


@dataclass(frozen=True)
class DevicePose:
    """One transform of a frame as it goes on the wire: ``matrix`` (4, 4) or None, ``status`` 'OK' when valid."""

    device: str
    matrix: object
    status: str = "OK"

    @property
    def valid(self):
        return self.status == "OK" and self.matrix is not None


class TrackerSource:
    """Frames from a live tracker, polled ``rate_hz`` times a second; each new tracker frame is passed on once.

    ``tracker_factory`` returns a connected, started tracker with ``poses()`` and ``close()``; it is called again
    after a failure, after a back-off that doubles from ``BACKOFF_START_S`` up to ``BACKOFF_MAX_S`` while the
    tracker keeps failing, each failure logged with its reason and the time of the next try. With
    ``wait_for_client`` the tracker is first read when the first client has connected.
    """

    def __init__(self, tracker_factory, names=None, rate_hz=DEFAULT_RATE_HZ, wait_for_client=False):
        self.tracker_factory = tracker_factory
        self.names = dict(names or DEFAULT_NAMES)
        self.period_s = 1.0 / rate_hz
        self.tracker = None
        self.status = None  # (code, error name, text) for STATUS messages
        self.timestamp_s = None  # frames are stamped with the time they are sent
        self.wait_for_client = wait_for_client  # connect to the tracker only once a client listens
        self.backoff_s = 0.0
        self._due = time.monotonic()
        self._last_frames = None

    def next_due(self):
        return self._due

    def read(self):
        """The poses of one new tracker frame (list of DevicePose), [] when the tracker has no new frame."""
        from .ndi_driver import TrackerConnectionError
        from .ndi_protocol import NDICommandError, NDIProtocolError

        now = time.monotonic()
        self._due += self.period_s
        if self._due < now:  # fell behind (a slow tracker): restart the pacing from now
            self._due = now + self.period_s
        try:
            if self.tracker is None:
                self.tracker = self.tracker_factory()
                self.status = (1, "", "tracker connected")
            poses, _ = self.tracker.poses()
        except (TrackerConnectionError, NDIProtocolError, NDICommandError, OSError) as error:
            self._fail(error, now)
            return []
        self.backoff_s = 0.0
        frames = tuple((tool, None if pose is None else pose.frame) for tool, pose in poses.items())
        if frames == self._last_frames and all(frame is not None for _, frame in frames):
            return []  # polled again within the same tracker frame: nothing new was measured
        self._last_frames = frames
        return [self._device_pose(tool, pose) for tool, pose in poses.items()]

    def _device_pose(self, tool, pose):
        device = self.names.get(tool, f"{tool}ToTracker")
        if pose is None or pose.state != "valid":
            return DevicePose(device, None, "INVALID")
        return DevicePose(device, pose.matrix(), "OUT_OF_VOLUME" if pose.out_of_volume else "OK")

    def _fail(self, error, now):
        if self.tracker is not None:
            try:
                self.tracker.close()
            except OSError:
                pass
        self.tracker = None
        self.backoff_s = min(BACKOFF_MAX_S, max(BACKOFF_START_S, 2 * self.backoff_s))
        self._due = now + self.backoff_s
        text = f"tracker not answering: {error}; next try in {self.backoff_s:g} s"
        logger.warning(text)
        self.status = (16, "DISCONNECTED", text)

    def close(self):
        if self.tracker is not None:
            self.tracker.close()
            self.tracker = None


class BackgroundServing:
    """``start()`` runs ``serve()`` in a daemon thread called ``thread_name``; ``stop()`` sets ``_stop``, waits for
    the thread and then calls ``_release()``. The class creates ``_stop`` (an Event) and ``_thread`` (None)."""

    thread_name = "server"

    def start(self):
        self._thread = threading.Thread(target=self.serve, name=self.thread_name, daemon=True)
        self._thread.start()
        return self

    def stop(self):
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self._release()

    def _release(self):
        """Close what the server holds, once its thread has ended."""


class TrackerServer(BackgroundServing):
    """Serve a tracker, or a recording, over OpenIGTLink.

    Args:
        tracker_factory: callable returning a connected, started tracker with ``poses()`` and ``close()``;
            called again to reconnect after the tracker fails (see TrackerSource).
        names: tool name -> OpenIGTLink device name (PLUS convention by default).
        header_version: 1 or 2.
        source: instead of a tracker, a frame source like TrackerSource: ``next_due()`` (monotonic time of the
            next frame, None when there are no more), ``read()`` (a list of DevicePose), ``status``,
            ``timestamp_s`` (the frame's time stamp, None: now), ``wait_for_client`` (start with the first
            client) and ``close()``; e.g. a ``replay.ReplaySource``. ``serve()`` returns when it is done.
        listener: a listening socket already bound (the command line binds it first, to report a busy port).
    """

    def __init__(
        self,
        tracker_factory=None,
        host="127.0.0.1",
        port=DEFAULT_PORT,
        rate_hz=DEFAULT_RATE_HZ,
        names=None,
        header_version=1,
        status_device="Tracker",
        source=None,
        listener=None,
    ):
        if header_version not in (1, 2):
            raise ValueError(f"header version {header_version}: use 1 or 2")
        if (tracker_factory is None) == (source is None):
            raise ValueError("give a tracker factory or a frame source, not both")
        self.source = source if source is not None else TrackerSource(tracker_factory, names, rate_hz)
        self.header_version = header_version
        self.status_device = status_device
        self.listener = listener if listener is not None else socket.create_server((host, port))
        self.listener.setblocking(False)
        self.address = self.listener.getsockname()
        self.clients = {}  # socket -> bytearray backlog
        self.frames_sent = 0
        self.finished = threading.Event()  # set when a finite source (a replay without --loop) is done
        self._last_status = None
        self._stop = threading.Event()
        self._thread = None

    thread_name = "TrackerServer"

    @property
    def tracker(self):
        return getattr(self.source, "tracker", None)

    def _release(self):
        for client in list(self.clients):
            client.close()
        self.listener.close()
        self.source.close()

    def serve(self):
        """Serve until stop(), or until a finite source is done and every client has its frames."""
        while not self._stop.is_set():
            waiting = self.source.wait_for_client and not self.clients and not self.frames_sent
            due = None if waiting else self.source.next_due()
            if not waiting and due is None and not any(self.clients.values()):
                self.finished.set()
                return
            timeout = 0.2 if due is None else min(0.2, max(0.0, due - time.monotonic()))
            writers = [client for client, backlog in self.clients.items() if backlog]
            readable, writable, _ = select.select([self.listener, *self.clients], writers, [], timeout)
            for sock in readable:
                if sock is self.listener:
                    self._accept()
                else:
                    self._read_and_discard(sock)
            for sock in writable:
                self._flush(sock)
            if due is not None and time.monotonic() >= due:
                self._frame()

    def _accept(self):
        try:
            client, address = self.listener.accept()
        except OSError:
            return
        client.setblocking(False)
        client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.clients[client] = bytearray()
        logger.info("OpenIGTLink client %s:%d connected", *address[:2])
        if self._last_status is not None:
            self._queue(client, self._status_message(*self._last_status))

    def _read_and_discard(self, client):
        try:
            data = client.recv(65536)  # clients may send requests; this server only streams
        except OSError:
            data = b""
        if not data:
            self._drop(client, "disconnected")

    def _flush(self, client):
        backlog = self.clients.get(client)
        if not backlog:
            return
        try:
            sent = client.send(backlog)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            self._drop(client, "went away")
            return
        del backlog[:sent]

    def _queue(self, client, data):
        backlog = self.clients[client]
        backlog += data
        self._flush(client)
        if client in self.clients and len(self.clients[client]) > MAX_BACKLOG_BYTES:
            self._drop(client, f"stopped reading ({len(self.clients[client])} bytes queued)")

    def _drop(self, client, why):
        self.clients.pop(client, None)
        try:
            client.close()
        except OSError:
            pass
        logger.warning("OpenIGTLink client dropped: %s", why)

    def _broadcast(self, data):
        for client in list(self.clients):
            self._queue(client, data)

    def _frame(self):
        poses = self.source.read()
        if poses:
            self._send(poses)
        if self.source.status is not None:  # after the frame: "replay finished" follows the last one
            self._set_status(*self.source.status)

    def _send(self, poses):
        now = time.time() if self.source.timestamp_s is None else self.source.timestamp_s
        for pose in poses:
            if pose.valid:
                metadata = {"TransformStatus": "OK", "TransformValid": "true"} if self.header_version == 2 else None
                self._broadcast(igtl.encode_transform(pose.device, pose.matrix, now, self.header_version, metadata))
            elif self.header_version == 2:  # version 1 peers get no invalid pose at all, as PLUS sends them
                matrix = _IDENTITY if pose.matrix is None else pose.matrix
                metadata = {"TransformStatus": pose.status, "TransformValid": "false"}
                self._broadcast(igtl.encode_transform(pose.device, matrix, now, 2, metadata))
        self.frames_sent += 1

    def _set_status(self, code, name, text):
        if self._last_status != (code, name, text):
            self._last_status = (code, name, text)
            logger.info("tracker status: %s", text)
            self._broadcast(self._status_message(code, name, text))

    def _status_message(self, code, name, text):
        return igtl.encode_status(
            self.status_device, igtl.Status(code, 0, name, text), time.time(), self.header_version
        )


_IDENTITY = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
