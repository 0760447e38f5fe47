"""A stand-in for an NDI Vega: the Combined API over TCP, byte for byte, with scripted tools.

Run it as its own process (``python -m OpenIGTLinkBridgeLib.ndi_simulator --port 8765``) or start
``VegaSimulator`` in a thread for tests. It answers INIT, APIREV, VER, BEEP, COMM, PHRQ, PVWR, PINIT, PENA,
PDIS, TSTART, TSTOP and TX (option 0001), checks every command's CRC (ERROR04 otherwise) and refuses commands in
the wrong mode with NDI's error codes. Tools are recognised by the ``.rom`` data written with PVWR and posed by
a ``Scenario``: a function of time giving each tool's ToolToTracker (or None: MISSING), with optional noise,
out-of-volume flags and a scripted disconnect. Tracking runs in frames of ``1 / rate_hz``: each TX answers the
current frame's poses, with noise drawn for that frame (and tool) from the scenario's seed.
"""

import argparse
import logging
import socket
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from .ndi_protocol import ToolPose, crc16, format_tx, frame_reply

logger = logging.getLogger(__name__)

VEGA_PORT = 8765
API_REVISION = "G.001.005"


def matrix_to_quaternion(matrix):
    """(q0, qx, qy, qz) of the rotation part of a (4, 4) matrix, q0 >= 0 (Shepperd's method)."""
    r = matrix[:3, :3]
    trace = np.trace(r)
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = (0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s)
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = 2.0 * np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = ((r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s)
    elif r[1, 1] > r[2, 2]:
        s = 2.0 * np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = ((r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s)
    else:
        s = 2.0 * np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = ((r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s)
    q = np.array(q) / np.linalg.norm(q)
    return tuple(-q if q[0] < 0 else q)


@dataclass
class Scenario:
    """What the simulated tracker sees. ``poses(time_s)`` maps a tool's ROM bytes to its ToolToTracker or None.

    ``out_of_volume(time_s, rom)`` flags a pose as out of the characterised volume; ``disconnect_after_s``
    closes the connection once, at that time after TSTART, as a cable pulled out would. ``stepped``: each TX
    answers the next frame whatever the time (a tracker read exactly once per frame), so that a session's
    frames do not depend on how punctually it is polled: reproducible demos and tests on a loaded machine.
    """

    poses: object
    out_of_volume: object = None
    noise_mm: float = 0.0
    seed: int = 0
    disconnect_after_s: float = None
    rate_hz: float = 60.0
    stepped: bool = False


@dataclass
class _Port:
    rom: bytearray = field(default_factory=lambda: bytearray(1024))  # a .rom is 752 bytes, written in 64-byte pieces
    initialized: bool = False
    enabled: bool = False


class VegaSimulator:
    """A TCP server speaking NDI's Combined API; ``start()`` runs it in a thread, ``stop()`` ends it."""

    def __init__(self, scenario, host="127.0.0.1", port=0):
        self.scenario = scenario
        self.server = socket.create_server((host, port))
        self.server.settimeout(0.2)  # here, not in serve(): stop() may close the socket before the thread runs
        self.address = self.server.getsockname()
        self._stop = threading.Event()
        self._thread = None
        self._disconnected_once = False
        self._frames_answered = 0

    def start(self):
        self._thread = threading.Thread(target=self.serve, name="VegaSimulator", daemon=True)
        self._thread.start()
        return self

    def stop(self):
        self._stop.set()
        self.server.close()
        if self._thread is not None:
            self._thread.join(timeout=5)

    def serve(self):
        while not self._stop.is_set():
            try:
                connection, _ = self.server.accept()
            except (TimeoutError, socket.timeout):
                continue
            except OSError:
                return
            with connection:
                self._session(connection)

    def _session(self, connection):
        ports, tracking_since, buffer = {}, None, b""
        connection.settimeout(0.2)
        while not self._stop.is_set():
            if (
                tracking_since is not None
                and self.scenario.disconnect_after_s is not None
                and not self._disconnected_once
                and time.monotonic() - tracking_since > self.scenario.disconnect_after_s
            ):
                self._disconnected_once = True
                logger.info("simulated disconnect")
                return
            try:
                chunk = connection.recv(4096)
            except (TimeoutError, socket.timeout):
                continue
            except OSError:
                return
            if not chunk:
                return
            buffer += chunk
            while b"\r" in buffer:
                line, buffer = buffer.split(b"\r", 1)
                reply, tracking_since = self._answer(line.decode("ascii", errors="replace"), ports, tracking_since)
                try:
                    connection.sendall(frame_reply(reply))
                except OSError:
                    return

    def _answer(self, line, ports, tracking_since):
        if ":" in line:
            name, rest = line.split(":", 1)
            if len(rest) < 4 or f"{crc16(name + ':' + rest[:-4]):04X}" != rest[-4:].upper():
                return "ERROR04", tracking_since
            arguments = rest[:-4]
        else:
            name, _, arguments = line.partition(" ")
        name = name.strip().upper()
        if name in ("INIT", "BEEP", "COMM", "RESET"):
            return ("0" if name == "BEEP" else "OKAY"), (None if name in ("INIT", "RESET") else tracking_since)
        if name == "APIREV":
            return API_REVISION, tracking_since
        if name == "VER":
            # The freeze tag of a Vega whose firmware answers TX: clients that choose TX or BX by it pick TX.
            return "Vega simulator (RAMSICP Navigator)\nFreeze Tag: Polaris Vega 008\nCombined API " + API_REVISION, (
                tracking_since
            )
        if name == "PHSR":
            return self._port_search(arguments, ports), tracking_since
        if name == "PHF":
            try:
                ports.pop(int(arguments[:2], 16), None)
            except ValueError:
                return "ERROR07", tracking_since
            return "OKAY", tracking_since
        if name == "PHRQ":
            handle = len(ports) + 1
            ports[handle] = _Port()
            return f"{handle:02X}", tracking_since
        if name in ("PVWR", "PINIT", "PENA", "PDIS"):
            return self._port_command(name, arguments, ports, tracking_since), tracking_since
        if name == "TSTART":
            self._frames_answered = 0
            return "OKAY", time.monotonic()
        if name == "TSTOP":
            return "OKAY", None
        if name == "TX":
            if tracking_since is None:
                return "ERROR0C", tracking_since
            return self._tx(ports, tracking_since), tracking_since
        return "ERROR01", tracking_since

    @staticmethod
    def _port_search(arguments, ports):
        """PHSR: 00 all handles, 01 to be freed (none), 02 not initialised, 03 initialised but not enabled."""
        kind = arguments[:2] or "00"
        wanted = {
            "00": lambda port: True,
            "01": lambda port: False,
            "02": lambda port: not port.initialized,
            "03": lambda port: port.initialized and not port.enabled,
            "04": lambda port: port.enabled,
        }.get(kind)
        if wanted is None:
            return "ERROR07"
        found = [(handle, port) for handle, port in sorted(ports.items()) if wanted(port)]
        status = lambda port: 0x001 | (0x010 if port.initialized else 0) | (0x020 if port.enabled else 0)  # noqa: E731
        return f"{len(found):02X}" + "".join(f"{handle:02X}{status(port):03X}" for handle, port in found)

    def _port_command(self, name, arguments, ports, tracking_since):
        try:
            handle = int(arguments[:2], 16)
        except ValueError:
            return "ERROR07"
        if handle not in ports:
            return "ERROR08"
        port = ports[handle]
        if name == "PVWR":
            try:
                address, data = int(arguments[2:6], 16), bytes.fromhex(arguments[6:])
            except ValueError:
                return "ERROR23"
            if len(data) != 64 or address + 64 > len(port.rom):
                return "ERROR23"
            port.rom[address : address + 64] = data
            return "OKAY"
        if name == "PINIT":
            port.initialized = True
            return "OKAY"
        if name == "PENA":
            if not port.initialized:
                return "ERROR0E"
            port.enabled = True
            return "OKAY"
        port.enabled = False  # PDIS
        return "OKAY"

    def _tx(self, ports, tracking_since):
        # Like a real tracker, one measurement per frame: the poses are taken at the frame's time and its noise
        # is drawn for that frame, so asking twice within a frame returns the same answer.
        if self.scenario.stepped:
            frame, self._frames_answered = self._frames_answered, self._frames_answered + 1
        else:
            frame = int((time.monotonic() - tracking_since) * self.scenario.rate_hz)
        elapsed = frame / self.scenario.rate_hz
        poses_now = self.scenario.poses(elapsed)
        replies = []
        for handle, port in sorted(ports.items()):
            if not port.enabled:
                replies.append(ToolPose(handle, "disabled"))
                continue
            rom = next((key for key in poses_now if bytes(port.rom[: len(key)]) == key), None)
            matrix = None if rom is None else poses_now[rom]
            if matrix is None:
                replies.append(ToolPose(handle, "missing", port_status=0x11, frame=frame))
                continue
            noise = np.random.default_rng((self.scenario.seed, frame, handle)).normal(size=3)
            translation = matrix[:3, 3] + noise * self.scenario.noise_mm / np.sqrt(3)
            status = 0x31
            if self.scenario.out_of_volume is not None and self.scenario.out_of_volume(elapsed, rom):
                status |= 0x80
            replies.append(
                ToolPose(handle, "valid", matrix_to_quaternion(matrix), tuple(translation), 0.12, status, frame)
            )
        return format_tx(replies)


def _main():
    from RAMSICPRegistrationLib.io.ndi_tools import tool_rom_path

    parser = argparse.ArgumentParser(description="NDI Vega simulator (Combined API over TCP) on loopback")
    parser.add_argument("--port", type=int, default=VEGA_PORT)
    parser.add_argument("--noise", type=float, default=0.0, help="translation noise, mm RMS")
    arguments = parser.parse_args()
    reference = tool_rom_path("8700339").read_bytes()
    probe = tool_rom_path("8700340").read_bytes()
    reference_pose = np.eye(4)
    reference_pose[:3, 3] = (0.0, 0.0, -1500.0)

    def poses(time_s):
        probe_pose = np.eye(4)
        probe_pose[:3, 3] = (50.0 * np.sin(time_s), 30.0, -1450.0)
        return {reference: reference_pose, probe: probe_pose}

    simulator = VegaSimulator(Scenario(poses, noise_mm=arguments.noise), port=arguments.port)
    logging.basicConfig(level=logging.INFO)
    logger.info("Vega simulator listening on %s:%d", *simulator.address)
    simulator.serve()


if __name__ == "__main__":
    _main()
