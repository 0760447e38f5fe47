"""NDI Combined API text protocol (Polaris, Vega): framing with CRC-16 both ways, errors, and the ``TX`` reply.

A command with CRC is ``NAME:args`` + 4 hex CRC digits + CR; every reply ends with its own 4 hex CRC digits + CR.
The CRC is CRC-16 with polynomial 0x8005, reflected (0xA001), initial value 0: what NDI's devices compute.
``TX`` (option 0x0001) answers, per port handle, a quaternion (4 x 6 characters, 4 implied decimals), a
translation (3 x 7 characters, mm with 2 implied decimals), the RMS fit error (6 characters, 4 decimals), the
port status and frame number (8 hex each), or ``MISSING`` (with status and frame) or ``DISABLED``; then the
system status (4 hex).
"""

from dataclasses import dataclass

import numpy as np

#: NDI's meanings of the ERROR codes a tracker returns (Combined API guide), for exceptions that explain.
ERROR_MEANINGS = {
    0x01: "invalid command",
    0x02: "command too long",
    0x03: "command too short",
    0x04: "invalid CRC calculated for command",
    0x05: "time-out on command execution",
    0x06: "unable to set up new communication parameters",
    0x07: "incorrect number of parameters",
    0x08: "invalid port handle selected",
    0x09: "invalid mode selected",
    0x0A: "invalid LED selected",
    0x0B: "invalid LED state selected",
    0x0C: "command is invalid while in the current operating mode",
    0x0D: "no tool is assigned to the selected port handle",
    0x0E: "selected port handle not initialized",
    0x0F: "selected port handle not enabled",
    0x10: "system not initialized",
    0x11: "unable to stop tracking",
    0x12: "unable to start tracking",
    0x13: "hardware error: tool definition",
    0x14: "invalid Position Sensor characterization parameters",
    0x15: "unable to initialize the system",
    0x16: "unable to start diagnostic mode",
    0x17: "unable to stop diagnostic mode",
    0x19: "unable to read device's firmware revision information",
    0x1A: "internal system error",
    0x1D: "unable to search for SROM IDs",
    0x1E: "unable to read SROM data",
    0x1F: "unable to write SROM data",
    0x23: "invalid command parameter",
    0x24: "unknown tool type or model",
    0x25: "port handles exhausted",
    0x26: "tool definition not loaded",
    0x2A: "tool definition too large",
    0x2B: "volume not supported",
    0x2C: "Position Sensor is not in the required state",
    0x31: "invalid system status request",
}

PORT_STATUS_OUT_OF_VOLUME = 0x80  # bit 7 of the port status: the tool is outside the characterised volume


class NDIProtocolError(ValueError):
    """A reply that breaks the protocol (bad CRC, bad field); the link should be reset."""


class NDICommandError(RuntimeError):
    """An ``ERRORxx`` reply: ``code`` and NDI's ``meaning``."""

    def __init__(self, command, code):
        self.command, self.code = command, code
        self.meaning = ERROR_MEANINGS.get(code, "unknown error code")
        super().__init__(f"NDI tracker refused {command!r}: ERROR{code:02X} ({self.meaning})")


def crc16(text):
    """NDI's CRC-16 of an ASCII string (or bytes): polynomial 0x8005 reflected, initial 0."""
    data = text.encode("ascii") if isinstance(text, str) else text
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def frame_command(name, arguments=""):
    """``NAME:args`` with its CRC and CR, as bytes ready to send."""
    body = f"{name}:{arguments}"
    return f"{body}{crc16(body):04X}\r".encode("ascii")


def frame_reply(text):
    """A reply body with its CRC and CR (what a tracker, or our simulator, sends)."""
    return f"{text}{crc16(text):04X}\r".encode("ascii")


def check_reply(raw, command="command"):
    """Strip and verify a reply's CRC; returns the reply text. Raises NDIProtocolError or NDICommandError."""
    text = raw.decode("ascii", errors="replace").rstrip("\r")
    if len(text) < 4:
        raise NDIProtocolError(f"reply to {command!r} is too short: {text!r}")
    body, crc_text = text[:-4], text[-4:]
    try:
        received = int(crc_text, 16)
    except ValueError:
        raise NDIProtocolError(f"reply to {command!r} has no CRC: {text!r}") from None
    if received != crc16(body):
        raise NDIProtocolError(f"reply to {command!r} has a wrong CRC ({crc_text}, expected {crc16(body):04X})")
    if body.startswith("ERROR"):
        try:
            code = int(body[5:7], 16)
        except ValueError:
            raise NDIProtocolError(f"malformed ERROR reply to {command!r}: {body!r}") from None
        raise NDICommandError(command, code)
    return body


@dataclass(frozen=True)
class ToolPose:
    """One port handle's answer in a ``TX`` reply.

    ``state`` is 'valid', 'missing' or 'disabled'; for a valid pose ``quaternion`` (q0, qx, qy, qz),
    ``translation_mm`` (3,) and ``rms_error_mm``; ``port_status`` and ``frame`` when the tracker sent them.
    """

    handle: int
    state: str
    quaternion: tuple = None
    translation_mm: tuple = None
    rms_error_mm: float = None
    port_status: int = None
    frame: int = None

    @property
    def out_of_volume(self):
        return self.port_status is not None and bool(self.port_status & PORT_STATUS_OUT_OF_VOLUME)

    def matrix(self):
        """(4, 4) ToolToTracker of a valid pose."""
        if self.state != "valid":
            raise ValueError(f"port handle {self.handle:02X} is {self.state}: it has no pose")
        q0, qx, qy, qz = np.array(self.quaternion) / np.linalg.norm(self.quaternion)
        rotation = np.array(
            [
                [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - q0 * qz), 2 * (qx * qz + q0 * qy)],
                [2 * (qx * qy + q0 * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - q0 * qx)],
                [2 * (qx * qz - q0 * qy), 2 * (qy * qz + q0 * qx), 1 - 2 * (qx * qx + qy * qy)],
            ]
        )
        transform = np.eye(4)
        transform[:3, :3] = rotation
        transform[:3, 3] = self.translation_mm
        return transform


def format_tx(poses, system_status=0):
    """The text of a ``TX`` (0x0001) reply for ToolPose entries (without CRC): what a tracker sends."""
    lines = [f"{len(poses):02X}"]
    for pose in poses:
        if pose.state == "disabled":
            lines.append(f"{pose.handle:02X}DISABLED")
            continue
        if pose.state == "missing":
            lines.append(f"{pose.handle:02X}MISSING{pose.port_status:08X}{pose.frame:08X}")
            continue
        quaternion = "".join(_signed(value * 10_000, 5) for value in pose.quaternion)
        translation = "".join(_signed(value * 100, 6) for value in pose.translation_mm)
        lines.append(
            f"{pose.handle:02X}{quaternion}{translation}{_signed(pose.rms_error_mm * 10_000, 5)}"
            f"{pose.port_status:08X}{pose.frame:08X}"
        )
    return lines[0] + "".join(record + "\n" for record in lines[1:]) + f"{system_status:04X}"


def parse_tx(text):
    """Parse a ``TX`` (0x0001) reply text (CRC already checked) into (list of ToolPose, system status)."""
    try:
        count = int(text[:2], 16)
        records = text[2:].split("\n")
        if len(records) != count + 1:
            raise NDIProtocolError(f"TX reply announces {count} handles but holds {len(records) - 1}")
        poses = [_parse_record(record) for record in records[:count]]
        return poses, int(records[count], 16)
    except (ValueError, IndexError) as error:
        if isinstance(error, NDIProtocolError):
            raise
        raise NDIProtocolError(f"malformed TX reply ({error}): {text[:60]!r}") from None


def _parse_record(record):
    handle = int(record[:2], 16)
    rest = record[2:]
    if rest.startswith("DISABLED"):
        return ToolPose(handle, "disabled")
    if rest.startswith("MISSING"):
        return ToolPose(handle, "missing", port_status=int(rest[7:15], 16), frame=int(rest[15:23], 16))
    if len(rest) != 4 * 6 + 3 * 7 + 6 + 8 + 8:
        raise NDIProtocolError(f"TX record for handle {handle:02X} has {len(rest)} characters, not 67")
    quaternion = tuple(int(rest[6 * i : 6 * i + 6]) / 10_000 for i in range(4))
    translation = tuple(int(rest[24 + 7 * i : 31 + 7 * i]) / 100 for i in range(3))
    error = int(rest[45:51]) / 10_000
    return ToolPose(handle, "valid", quaternion, translation, error, int(rest[51:59], 16), int(rest[59:67], 16))


def _signed(value, digits):
    number = int(round(value))
    limit = 10**digits - 1
    if abs(number) > limit:
        raise ValueError(f"{value} does not fit a {digits}-digit TX field")
    return f"{'+' if number >= 0 else '-'}{abs(number):0{digits}d}"
