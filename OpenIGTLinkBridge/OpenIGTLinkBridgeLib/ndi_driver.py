"""NDI Polaris/Vega driver: Combined API over TCP (Vega, port 8765) or a serial line (Polaris Spectra/Vicra).

Written on our own ``ndi_protocol`` rather than ``ndicapi``: ndicapi has no read timeout (a silent tracker
hangs the call), its BX parsing crashes with three or more tools under Python 3, ``ndiOpenNetwork`` succeeds
when nothing listens, and ``ndiPVWRFromFile`` holds the GIL. Here every read has a timeout, every reply's CRC
is checked, and ERROR replies become ``NDICommandError`` with NDI's meaning.
"""

import logging
import socket
from pathlib import Path

from .ndi_protocol import check_reply, frame_command, parse_tx

logger = logging.getLogger(__name__)

DEFAULT_TIMEOUT_S = 2.0
#: NDI Vega's Combined API port.
NDI_PORT = 8765


class TrackerConnectionError(ConnectionError):
    """The tracker did not answer, or the link broke; reconnecting may help."""


class _TcpLink:
    def __init__(self, host, port, timeout_s):
        try:
            self.socket = socket.create_connection((host, port), timeout=timeout_s)
        except OSError as error:
            raise TrackerConnectionError(
                f"cannot reach the NDI tracker at {host}:{port} ({error}); check the "
                "address, the cable and that the tracker is switched on"
            ) from None
        self.socket.settimeout(timeout_s)
        self.buffer = b""

    def send(self, data):
        self.socket.sendall(data)

    def read_reply(self):
        while b"\r" not in self.buffer:
            chunk = self.socket.recv(4096)
            if not chunk:
                raise TrackerConnectionError("the NDI tracker closed the connection")
            self.buffer += chunk
        reply, self.buffer = self.buffer.split(b"\r", 1)
        return reply + b"\r"

    def close(self):
        self.socket.close()


class _SerialLink:
    def __init__(self, device, timeout_s):
        try:
            import serial
        except ImportError:
            raise TrackerConnectionError("serial trackers need pyserial: pip install pyserial") from None
        try:
            self.port = serial.Serial(device, baudrate=9600, timeout=timeout_s)
        except serial.SerialException as error:
            raise TrackerConnectionError(f"cannot open {device} ({error})") from None
        self.buffer = b""

    def send(self, data):
        self.port.write(data)

    def read_reply(self):
        while b"\r" not in self.buffer:
            chunk = self.port.read(self.port.in_waiting or 1)
            if not chunk:
                raise TrackerConnectionError("the NDI tracker did not answer in time")
            self.buffer += chunk
        reply, self.buffer = self.buffer.split(b"\r", 1)
        return reply + b"\r"

    def close(self):
        self.port.close()


class NDITracker:
    """One NDI tracker: ``connect``, ``load_tool`` (a .rom), ``start``, ``poses`` (TX), ``stop``, ``close``."""

    def __init__(self, host=None, port=NDI_PORT, serial_device=None, timeout_s=DEFAULT_TIMEOUT_S):
        if (host is None) == (serial_device is None):
            raise ValueError("give the tracker's network host or its serial device, not both")
        self.host, self.port, self.serial_device, self.timeout_s = host, port, serial_device, timeout_s
        self.link = None
        self.handles = {}

    def connect(self):
        self.link = (
            _TcpLink(self.host, self.port, self.timeout_s)
            if self.serial_device is None
            else _SerialLink(self.serial_device, self.timeout_s)
        )
        self.command("INIT")
        logger.info("NDI tracker API revision %s", self.command("APIREV"))
        return self

    def command(self, name, arguments=""):
        """Send one command with CRC and return the checked reply text."""
        if self.link is None:
            raise TrackerConnectionError("not connected; call connect() first")
        label = f"{name}:{arguments}"
        try:
            self.link.send(frame_command(name, arguments))
            raw = self.link.read_reply()
        except (socket.timeout, TimeoutError):
            raise TrackerConnectionError(
                f"the NDI tracker did not answer {label!r} within {self.timeout_s} s"
            ) from None
        except OSError as error:
            raise TrackerConnectionError(f"link to the NDI tracker broke during {label!r} ({error})") from None
        return check_reply(raw, label)

    def load_tool(self, rom, name):
        """Load a passive tool definition (``.rom`` bytes or path), initialise and enable it; returns its handle."""
        data = Path(rom).read_bytes() if isinstance(rom, (str, Path)) else bytes(rom)
        data = data + bytes(-len(data) % 64)
        handle = int(self.command("PHRQ", "*********1****"), 16)
        for address in range(0, len(data), 64):
            self.command("PVWR", f"{handle:02X}{address:04X}{data[address : address + 64].hex().upper()}")
        self.command("PINIT", f"{handle:02X}")
        self.command("PENA", f"{handle:02X}D")
        self.handles[name] = handle
        return handle

    def start(self):
        self.command("TSTART")

    def stop(self):
        self.command("TSTOP")

    def poses(self):
        """One TX: {tool name: ToolPose}, and the system status."""
        entries, system_status = parse_tx(self.command("TX", "0001"))
        by_handle = {pose.handle: pose for pose in entries}
        return {name: by_handle.get(handle) for name, handle in self.handles.items()}, system_status

    def close(self):
        if self.link is not None:
            try:
                self.link.close()
            finally:
                self.link = None


def parse_ndi_address(text):
    """'HOST' or 'HOST:PORT' of an NDI Vega -> (host, port); ValueError saying what is wrong."""
    host, _, port_text = str(text).strip().partition(":")
    if not host:
        raise ValueError(f"{text!r}: give the tracker's address, e.g. 169.254.8.50 (port {NDI_PORT} by default)")
    try:
        port = int(port_text or NDI_PORT)
    except ValueError:
        port = -1
    if not 1 <= port <= 65535:
        raise ValueError(f"{text}: the port after ':' must be a number from 1 to 65535")
    return host, port


def open_tracker(host=None, port=NDI_PORT, serial_device=None, roms=None, timeout_s=DEFAULT_TIMEOUT_S):
    """Connect, load the tools and start tracking; returns the NDITracker.

    ``roms``: tool name -> .rom path or bytes; by default the reference body NDI 8700339 as 'Reference' and
    the probe NDI 8700340 as 'Probe' (shipped with the package).
    """
    if roms is None:
        from RAMSICPRegistrationLib.io.ndi_tools import tool_rom_path

        roms = {"Reference": tool_rom_path("8700339"), "Probe": tool_rom_path("8700340")}
    tracker = NDITracker(host, port, serial_device, timeout_s).connect()
    for name, rom in roms.items():
        tracker.load_tool(rom, name)
    tracker.start()
    return tracker
