"""PLUS-compatible OpenIGTLink server: tracker poses as TRANSFORM messages (``ProbeToTracker``,
``ReferenceToTracker``), tracker state as STATUS, to several clients at once.

Header version 1 by default (OpenIGTLink 1.x peers read it): invalid poses are then not sent, as PLUS does.
With version 2 every pose is sent, invalid ones with ``TransformStatus=INVALID`` and ``TransformValid=false``
metadata. One ``select`` loop paced by the tracker's rate serves every client; sends never block: a client whose
backlog passes ``MAX_BACKLOG_BYTES`` (it stopped reading) is dropped with a log line instead of stalling the rest.
A tracker that stops answering is reported by STATUS and reconnected.
"""

import argparse
import logging
import select
import socket
import sys
import threading
import time

from . import igtl_messages as igtl

logger = logging.getLogger(__name__)

DEFAULT_PORT = 18944
DEFAULT_RATE_HZ = 60.0
MAX_BACKLOG_BYTES = 256 * 1024
DEFAULT_NAMES = {"Probe": "ProbeToTracker", "Reference": "ReferenceToTracker"}


class TrackerServer:
    """Serve a tracker over OpenIGTLink.

    Args:
        tracker_factory: callable returning a connected, started tracker with ``poses()`` and ``close()``;
            called again to reconnect after the tracker fails.
        names: tool name -> OpenIGTLink device name (PLUS convention by default).
        header_version: 1 or 2.
    """

    def __init__(
        self,
        tracker_factory,
        host="127.0.0.1",
        port=DEFAULT_PORT,
        rate_hz=DEFAULT_RATE_HZ,
        names=None,
        header_version=1,
        status_device="Tracker",
    ):
        if header_version not in (1, 2):
            raise ValueError(f"header version {header_version}: use 1 or 2")
        self.tracker_factory = tracker_factory
        self.names = dict(names or DEFAULT_NAMES)
        self.header_version = header_version
        self.status_device = status_device
        self.period_s = 1.0 / rate_hz
        self.listener = socket.create_server((host, port))
        self.listener.setblocking(False)
        self.address = self.listener.getsockname()
        self.clients = {}  # socket -> bytearray backlog
        self.tracker = None
        self.frames_sent = 0
        self._last_status = None
        self._stop = threading.Event()
        self._thread = None

    def start(self):
        self._thread = threading.Thread(target=self.serve, name="TrackerServer", daemon=True)
        self._thread.start()
        return self

    def stop(self):
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        for client in list(self.clients):
            client.close()
        self.listener.close()
        if self.tracker is not None:
            self.tracker.close()

    def serve(self):
        next_frame = time.monotonic()
        while not self._stop.is_set():
            timeout = max(0.0, next_frame - time.monotonic())
            writers = [client for client, backlog in self.clients.items() if backlog]
            readable, writable, _ = select.select([self.listener, *self.clients], writers, [], timeout)
            for sock in readable:
                if sock is self.listener:
                    self._accept()
                else:
                    self._read_and_discard(sock)
            for sock in writable:
                self._flush(sock)
            if time.monotonic() >= next_frame:
                next_frame += self.period_s
                if next_frame < time.monotonic():  # fell behind (a slow tracker): restart the pacing
                    next_frame = time.monotonic() + self.period_s
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
        from .ndi_driver import TrackerConnectionError
        from .ndi_protocol import NDIProtocolError

        try:
            if self.tracker is None:
                self.tracker = self.tracker_factory()
                self._set_status(1, "", "tracker connected")
            poses, _ = self.tracker.poses()
        except (TrackerConnectionError, NDIProtocolError, OSError) as error:
            if self.tracker is not None:
                try:
                    self.tracker.close()
                except OSError:
                    pass
            self.tracker = None
            self._set_status(16, "DISCONNECTED", f"tracker not answering: {error}")
            time.sleep(min(0.5, self.period_s * 10))  # back off before reconnecting; no busy loop
            return
        now = time.time()
        for tool, pose in poses.items():
            device = self.names.get(tool, f"{tool}ToTracker")
            valid = pose is not None and pose.state == "valid" and not pose.out_of_volume
            if valid:
                metadata = {"TransformStatus": "OK", "TransformValid": "true"} if self.header_version == 2 else None
                self._broadcast(igtl.encode_transform(device, pose.matrix(), now, self.header_version, metadata))
            elif self.header_version == 2:
                why = "OUT_OF_VOLUME" if pose is not None and pose.out_of_volume else "INVALID"
                matrix = pose.matrix() if pose is not None and pose.state == "valid" else _IDENTITY
                self._broadcast(
                    igtl.encode_transform(device, matrix, now, 2, {"TransformStatus": why, "TransformValid": "false"})
                )
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


def main(argv=None):
    """``ramsicp-tracker-server (--ndi HOST[:PORT] | --serial DEV | --simulate)``."""
    parser = argparse.ArgumentParser(prog="ramsicp-tracker-server", description=__doc__.splitlines()[0])
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--ndi", metavar="HOST[:PORT]", help="NDI Vega on the network (port 8765 by default)")
    source.add_argument("--serial", metavar="DEV", help="NDI Polaris on a serial line")
    source.add_argument("--simulate", action="store_true", help="start the Vega simulator on loopback and use it")
    parser.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT)
    parser.add_argument("--rate", type=float, default=DEFAULT_RATE_HZ, help="frames per second (default 60)")
    parser.add_argument("--header-version", type=int, choices=(1, 2), default=1)
    parser.add_argument("--probe-name", default=DEFAULT_NAMES["Probe"], help="device name of the probe's pose")
    parser.add_argument("--reference-name", default=DEFAULT_NAMES["Reference"], help="device name of the reference's")
    parser.add_argument("--reference-rom", help="reference body .rom (default NDI 8700339)")
    parser.add_argument("--probe-rom", help="probe .rom (default NDI 8700340)")
    arguments = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
    from RAMSICPRegistrationLib.io.ndi_tools import tool_rom_path

    from .ndi_driver import open_tracker

    roms = {
        "Reference": arguments.reference_rom or tool_rom_path("8700339"),
        "Probe": arguments.probe_rom or tool_rom_path("8700340"),
    }
    simulator, host, port = None, None, 8765
    if arguments.simulate:
        from .live_scenario import demo_simulator

        simulator, _ = demo_simulator()
        simulator.start()
        host, port = simulator.address[0], simulator.address[1]
    elif arguments.ndi:
        host, _, port_text = arguments.ndi.partition(":")
        port = int(port_text or 8765)

    def connect():
        return open_tracker(host, port, arguments.serial, roms)

    names = {"Probe": arguments.probe_name, "Reference": arguments.reference_name}
    server = TrackerServer(
        connect, arguments.host, arguments.port, arguments.rate, names=names, header_version=arguments.header_version
    )
    logger.info("serving OpenIGTLink on %s:%d", *server.address[:2])
    try:
        server.serve()
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
        if simulator is not None:
            simulator.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
