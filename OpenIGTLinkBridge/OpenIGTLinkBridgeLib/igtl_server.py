"""PLUS-compatible OpenIGTLink server: tracker poses as TRANSFORM messages (``ProbeToTracker``,
``ReferenceToTracker``), tracker state as STATUS, to several clients at once.

Header version 1 by default (OpenIGTLink 1.x peers read it): invalid poses are then not sent, as PLUS does.
With version 2 every pose is sent, invalid ones with ``TransformStatus=INVALID`` and ``TransformValid=false``
metadata. One ``select`` loop paced by the tracker's rate serves every client; sends never block: a client whose
backlog passes ``MAX_BACKLOG_BYTES`` (it stopped reading) is dropped with a log line instead of stalling the rest.
Each new tracker frame is sent once (a poll that finds the same NDI frame numbers sends nothing). A tracker that
stops answering is reported by STATUS, with the reason, and reconnected after a back-off that doubles up to
``BACKOFF_MAX_S``. ``--replay`` streams a recorded PLUS sequence file instead (``replay.ReplaySource``).
"""

import errno
import logging
import math
import select
import socket
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from RAMSICPRegistrationLib.io.command_line import EXIT_BAD_INPUT, OneLineParser

from . import igtl_messages as igtl
from .ndi_driver import NDI_PORT, parse_ndi_address

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


MAX_RATE_HZ = 1000.0


def _parser():
    parser = OneLineParser(
        prog="ramsicp-tracker-server",
        description="Stream an NDI tracker (or its simulator, or a recorded PLUS sequence file) over OpenIGTLink "
        "as PLUS does: ProbeToTracker and ReferenceToTracker as TRANSFORM messages, the tracker's state as STATUS, "
        "to every client (3D Slicer with SlicerOpenIGTLink, or the OpenIGTLinkBridge module).",
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--ndi", metavar="HOST[:PORT]", help=f"NDI Vega on the network (port {NDI_PORT} by default)")
    source.add_argument("--serial", metavar="DEV", help="NDI Polaris on a serial line, e.g. /dev/ttyUSB0")
    source.add_argument("--simulate", action="store_true", help="start the Vega simulator on loopback and use it")
    source.add_argument(
        "--replay",
        metavar="FILE",
        type=Path,
        help="replay a PLUS sequence file (.igs.mha, .seq.mha) at its recorded timing, starting with the first "
        "client; the server exits when the replay is done",
    )
    parser.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    parser.add_argument(
        "--port", type=int, default=DEFAULT_PORT, help=f"OpenIGTLink port to serve on (default {DEFAULT_PORT})"
    )
    parser.add_argument(
        "--rate",
        type=float,
        default=DEFAULT_RATE_HZ,
        help=f"tracker polls per second (default {DEFAULT_RATE_HZ:g}); each new tracker frame is sent once, "
        "so poll at least as fast as the tracker measures",
    )
    parser.add_argument(
        "--header-version",
        type=int,
        choices=(1, 2),
        default=1,
        help="OpenIGTLink header version (default 1: invalid poses are not sent; 2: sent with TransformStatus)",
    )
    parser.add_argument(
        "--probe-name", default=DEFAULT_NAMES["Probe"], help="device name of the probe's pose (default ProbeToTracker)"
    )
    parser.add_argument(
        "--reference-name",
        default=DEFAULT_NAMES["Reference"],
        help="device name of the reference body's pose (default ReferenceToTracker)",
    )
    parser.add_argument("--reference-rom", type=Path, help="reference body .rom file (default NDI 8700339)")
    parser.add_argument("--probe-rom", type=Path, help="probe .rom file (default NDI 8700340)")
    parser.add_argument(
        "--tool-rom",
        type=Path,
        help="also track the cutting tool's markers (.rom file), sent as --tool-name; for the live guidance of a cut",
    )
    parser.add_argument(
        "--tool-name", default="ToolToTracker", help="device name of the cutting tool's pose (default ToolToTracker)"
    )
    parser.add_argument("--loop", action="store_true", help="with --replay: start again after the last frame")
    parser.add_argument(
        "--speed", type=float, default=1.0, help="with --replay: playback speed (default 1, the recorded speed)"
    )
    parser.add_argument(
        "--rename",
        action="append",
        metavar="OLD=NEW",
        help="with --replay: rename a recorded transform, e.g. Stylus=Probe sends StylusToTracker as "
        "ProbeToTracker (repeatable)",
    )
    return parser


def _check_arguments(arguments):
    """Every argument and file checked before anything starts; raises ValueError with one line."""
    if not 0 <= arguments.port <= 65535:
        raise ValueError(f"--port {arguments.port}: give a port from 1 to 65535 (OpenIGTLink's is {DEFAULT_PORT})")
    # (--port 0 is accepted: the system picks a free port, which the log line gives)
    if not (math.isfinite(arguments.rate) and 0 < arguments.rate <= MAX_RATE_HZ):
        raise ValueError(f"--rate {arguments.rate:g}: give a rate above 0 and at most {MAX_RATE_HZ:g} per second")
    if arguments.replay is None and (arguments.loop or arguments.rename or arguments.speed != 1.0):
        raise ValueError("--loop, --speed and --rename only apply to --replay FILE")
    if arguments.ndi is not None:
        try:
            arguments.ndi_address = parse_ndi_address(arguments.ndi)
        except ValueError as error:
            raise ValueError(f"--ndi {error}") from None
    for option, path in (
        ("--reference-rom", arguments.reference_rom),
        ("--probe-rom", arguments.probe_rom),
        ("--tool-rom", arguments.tool_rom),
    ):
        if path is not None:
            _check_rom(option, path)


def _check_rom(option, path):
    if not path.exists():
        raise ValueError(f"{option} {path}: no such file")
    if path.is_dir():
        raise ValueError(f"{option} {path}: is a folder; give the tool's .rom file")
    try:
        data = path.read_bytes()
    except OSError as error:
        raise ValueError(f"{option} {path}: cannot be read ({error.strerror or error})") from None
    if not data.startswith(b"NDI") or not 64 <= len(data) <= 1024:
        raise ValueError(
            f"{option} {path}: not an NDI tool definition (a .rom file starts with 'NDI' and has 64 to 1024 "
            f"bytes; this one has {len(data)}); export the tool's .rom from NDI's software"
        )


def _listen(host, port):
    try:
        return socket.create_server((host, port))
    except OSError as error:
        if error.errno == errno.EADDRINUSE:
            raise ValueError(
                f"port {port} on {host} is in use (another ramsicp-tracker-server or PlusServer?); stop it or "
                "give another --port"
            ) from None
        raise ValueError(f"cannot serve on {host}:{port} ({error.strerror or error})") from None


def main(argv=None):
    """``ramsicp-tracker-server (--ndi HOST[:PORT] | --serial DEV | --simulate | --replay FILE)``."""
    arguments = _parser().parse_args(argv)
    try:
        _check_arguments(arguments)
        source = None
        if arguments.replay is not None:
            from .plus_sequence import read_sequence
            from .replay import ReplaySource, parse_renames

            recording = read_sequence(arguments.replay)
            source = ReplaySource(recording, arguments.speed, arguments.loop, parse_renames(arguments.rename))
        listener = _listen(arguments.host, arguments.port)
    except ValueError as error:
        print(f"ramsicp-tracker-server: error: {' '.join(str(error).split())}", file=sys.stderr)
        return EXIT_BAD_INPUT
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
    simulator = None
    if source is None:
        from RAMSICPRegistrationLib.io.ndi_tools import tool_rom_path

        from .ndi_driver import open_tracker

        roms = {
            "Reference": arguments.reference_rom or tool_rom_path("8700339"),
            "Probe": arguments.probe_rom or tool_rom_path("8700340"),
        }
        if arguments.tool_rom is not None:
            roms["Tool"] = arguments.tool_rom
        host, port = arguments.ndi_address if arguments.ndi else (None, NDI_PORT)
        if arguments.simulate:
            from .live_scenario import demo_simulator

            simulator, _ = demo_simulator()
            simulator.start()
            host, port = simulator.address[0], simulator.address[1]

        def connect():
            return open_tracker(host, port, arguments.serial, roms)

        names = {"Probe": arguments.probe_name, "Reference": arguments.reference_name, "Tool": arguments.tool_name}
        source = TrackerSource(connect, names, arguments.rate)
    server = TrackerServer(source=source, listener=listener, header_version=arguments.header_version)
    logger.info("serving OpenIGTLink on %s:%d", *server.address[:2])
    try:
        server.serve()
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
        if simulator is not None:
            simulator.stop()
    if server.finished.is_set():
        logger.info("%s", server.source.status[2] if server.source.status else "done")
    return 0


if __name__ == "__main__":
    sys.exit(main())
