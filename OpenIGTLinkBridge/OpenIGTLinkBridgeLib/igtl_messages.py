"""OpenIGTLink messages on the wire: header versions 1 and 2, TRANSFORM and STATUS, with their CRC-64.

Follows the OpenIGTLink protocol description (version 1 header, 58 bytes, big-endian; version 2 adds an
extended header and metadata after the content). Decoding never trusts the peer: a wrong CRC, a truncated or
oversized body, an unknown type or a bad field raises ``MessageError`` with the reason, and the caller decides
whether to skip the message or reset the connection.
"""

import struct
from dataclasses import dataclass, field

import numpy as np

HEADER_SIZE = 58
EXTENDED_HEADER_SIZE = 12
TRANSFORM_BODY_SIZE = 48
STATUS_FIXED_SIZE = 30  # code (2) + subcode (8) + error name (20)
#: Bodies larger than this are refused (a TRANSFORM is 48 bytes; STATUS a few hundred).
MAX_BODY_SIZE = 1 << 20
KNOWN_TYPES = ("TRANSFORM", "STATUS")

STATUS_CODES = {
    1: "OK",
    2: "UNKNOWN_ERROR",
    3: "PANIC",
    4: "NOT_FOUND",
    5: "ACCESS_DENIED",
    6: "BUSY",
    7: "TIME_OUT",
    8: "OVERFLOW",
    9: "CHECKSUM_ERROR",
    10: "CONFIG_ERROR",
    11: "RESOURCE_ERROR",
    12: "UNKNOWN_INSTRUCTION",
    13: "NOT_READY",
    14: "MANUAL_MODE",
    15: "DISABLED",
    16: "NOT_PRESENT",
    17: "UNKNOWN_VERSION",
    18: "HARDWARE_FAILURE",
    19: "SHUT_DOWN",
}

_HEADER = struct.Struct(">H12s20sQQQ")
_EXTENDED = struct.Struct(">HHII")
_CRC_POLYNOMIAL = 0x42F0E1EBA9EA3693  # CRC-64/ECMA-182, as the OpenIGTLink library computes it


class MessageError(ValueError):
    """A message that cannot be accepted; ``reason`` says why."""


def _crc_table():
    table = []
    for byte in range(256):
        crc = byte << 56
        for _ in range(8):
            crc = ((crc << 1) ^ _CRC_POLYNOMIAL) if crc & (1 << 63) else (crc << 1)
            crc &= 0xFFFFFFFFFFFFFFFF
        table.append(crc)
    return table


_TABLE = _crc_table()


def crc64(data, crc=0):
    """OpenIGTLink's CRC-64 (ECMA-182, MSB first, initial value 0, no final XOR) of ``data`` (bytes)."""
    for byte in data:
        crc = _TABLE[((crc >> 56) ^ byte) & 0xFF] ^ ((crc << 8) & 0xFFFFFFFFFFFFFFFF)
    return crc


@dataclass(frozen=True)
class Header:
    version: int
    type: str
    device: str
    timestamp_s: float
    body_size: int
    crc: int


@dataclass(frozen=True)
class Message:
    """A decoded message: type, device name, timestamp (s), content and, for version 2, its metadata."""

    type: str
    device: str
    timestamp_s: float
    content: object
    version: int = 1
    metadata: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Status:
    code: int
    subcode: int = 0
    error_name: str = ""
    text: str = ""


def encode_transform(device, matrix, timestamp_s=0.0, version=1, metadata=None, message_id=0):
    """A TRANSFORM message carrying the upper 3x4 of a (4, 4) matrix as 12 big-endian float32."""
    matrix = np.asarray(matrix, dtype=np.float64)
    if matrix.shape != (4, 4) or not np.isfinite(matrix).all():
        raise ValueError(f"TRANSFORM {device!r}: expected a finite 4x4 matrix, got shape {matrix.shape}")
    values = np.concatenate((matrix[:3, :3].T.ravel(), matrix[:3, 3]))  # R column by column, then t
    return _encode("TRANSFORM", device, struct.pack(">12f", *values), timestamp_s, version, metadata, message_id)


def encode_transforms(device, matrices):
    """TRANSFORM messages (header version 1, time stamp 0) of (N, 4, 4) matrices, all at once: the same bytes as
    ``encode_transform`` for each matrix, with the CRC-64 of every body computed together (one numpy step per byte
    position), so that a long tool path is encoded in a few milliseconds instead of 33 us a pose."""
    matrices = np.asarray(matrices, dtype=np.float64)
    if matrices.ndim != 3 or matrices.shape[1:] != (4, 4) or not np.isfinite(matrices).all():
        raise ValueError(f"TRANSFORM {device!r}: expected finite (N, 4, 4) matrices, got shape {matrices.shape}")
    encoded_device = device.encode("ascii")
    if len(encoded_device) > 20:
        raise ValueError(f"device name {device!r} is longer than OpenIGTLink's 20 characters")
    count = len(matrices)
    values = np.concatenate((matrices[:, :3, :3].transpose(0, 2, 1).reshape(count, 9), matrices[:, :3, 3]), axis=1)
    bodies = values.astype(">f4").view(np.uint8).reshape(count, 48)
    crc = np.zeros(count, dtype=np.uint64)
    table = np.array(_TABLE, dtype=np.uint64)
    for position in range(48):
        crc = table[((crc >> np.uint64(56)) ^ bodies[:, position].astype(np.uint64)) & np.uint64(0xFF)] ^ (
            crc << np.uint64(8)
        )
    header = _HEADER.pack(1, b"TRANSFORM", encoded_device, 0, 48, 0)[:-8]  # all but the CRC
    messages = np.empty((count, _HEADER.size + 48), dtype=np.uint8)
    messages[:, : _HEADER.size - 8] = np.frombuffer(header, dtype=np.uint8)
    messages[:, _HEADER.size - 8 : _HEADER.size] = crc.astype(">u8").view(np.uint8).reshape(count, 8)
    messages[:, _HEADER.size :] = bodies
    return messages.tobytes()


def encode_status(device, status, timestamp_s=0.0, version=1, metadata=None, message_id=0):
    """A STATUS message (code, subcode, error name, status string)."""
    body = struct.pack(">Hq20s", status.code, status.subcode, status.error_name.encode("ascii")[:20])
    body += status.text.encode("utf-8") + b"\0"
    return _encode("STATUS", device, body, timestamp_s, version, metadata, message_id)


def _encode(kind, device, content, timestamp_s, version, metadata, message_id):
    if version not in (1, 2):
        raise ValueError(f"OpenIGTLink header version {version}: use 1 or 2")
    encoded_device = device.encode("ascii")
    if len(encoded_device) > 20:
        raise ValueError(f"device name {device!r} is longer than OpenIGTLink's 20 characters")
    body = content
    if version == 2:
        body = _extended_header(metadata or {}, message_id) + content + _metadata(metadata or {})
    seconds = int(timestamp_s)
    fraction = int(round((timestamp_s - seconds) * 2**32)) & 0xFFFFFFFF
    header = _HEADER.pack(
        version, kind.encode("ascii"), encoded_device, (seconds << 32) | fraction, len(body), crc64(body)
    )
    return header + body


def _extended_header(metadata, message_id):
    entries = [(key.encode("utf-8"), str(value).encode("utf-8")) for key, value in metadata.items()]
    index_size = 2 + 8 * len(entries)
    data_size = sum(len(key) + len(value) for key, value in entries)
    return _EXTENDED.pack(EXTENDED_HEADER_SIZE, index_size, data_size, message_id)


def _metadata(metadata):
    entries = [(key.encode("utf-8"), str(value).encode("utf-8")) for key, value in metadata.items()]
    index = struct.pack(">H", len(entries))
    for key, value in entries:
        index += struct.pack(">HHI", len(key), 3, len(value))  # 3: US-ASCII value encoding (IANA MIBenum)
    return index + b"".join(key + value for key, value in entries)


def decode_header(data):
    """Decode a 58-byte header; raises MessageError for a bad version, type or size."""
    if len(data) != HEADER_SIZE:
        raise MessageError(f"header has {len(data)} bytes, not {HEADER_SIZE}")
    version, kind, device, timestamp, body_size, crc = _HEADER.unpack(data)
    if version not in (1, 2, 3):
        raise MessageError(f"unknown header version {version}")
    try:
        kind = kind.rstrip(b"\0").decode("ascii")
        device = device.rstrip(b"\0").decode("ascii")
    except UnicodeDecodeError:
        raise MessageError("type or device name is not ASCII") from None
    if body_size > MAX_BODY_SIZE:
        raise MessageError(f"{kind} body of {body_size} bytes is over the {MAX_BODY_SIZE}-byte limit")
    return Header(version, kind, device, (timestamp >> 32) + (timestamp & 0xFFFFFFFF) / 2**32, body_size, crc)


def decode_body(header, body):
    """Decode a body for its header: checks the CRC, then the type's fields. Returns a Message."""
    if len(body) != header.body_size:
        raise MessageError(f"{header.type} {header.device!r}: body has {len(body)} of {header.body_size} bytes")
    if crc64(body) != header.crc:
        raise MessageError(f"{header.type} {header.device!r}: CRC mismatch (the message was corrupted)")
    if header.type not in KNOWN_TYPES:
        raise MessageError(f"unknown message type {header.type!r} from {header.device!r}")
    content, metadata = body, {}
    if header.version >= 2:
        content, metadata = _split_version2(header, body)
    if header.type == "TRANSFORM":
        if len(content) != TRANSFORM_BODY_SIZE:
            raise MessageError(f"TRANSFORM {header.device!r}: {len(content)} content bytes, not {TRANSFORM_BODY_SIZE}")
        values = np.array(struct.unpack(">12f", content), dtype=np.float64)
        if not np.isfinite(values).all():
            raise MessageError(f"TRANSFORM {header.device!r}: contains NaN or infinity")
        matrix = np.eye(4)
        matrix[:3, :3] = values[:9].reshape(3, 3).T
        matrix[:3, 3] = values[9:]
        parsed = matrix
    else:
        if len(content) < STATUS_FIXED_SIZE:
            raise MessageError(f"STATUS {header.device!r}: {len(content)} content bytes, at least {STATUS_FIXED_SIZE}")
        code, subcode, name = struct.unpack(">Hq20s", content[:STATUS_FIXED_SIZE])
        text = content[STATUS_FIXED_SIZE:].split(b"\0", 1)[0].decode("utf-8", errors="replace")
        parsed = Status(code, subcode, name.rstrip(b"\0").decode("ascii", errors="replace"), text)
    return Message(header.type, header.device, header.timestamp_s, parsed, header.version, metadata)


def decode(data):
    """Decode one complete message (header + body) from bytes."""
    header = decode_header(data[:HEADER_SIZE])
    return decode_body(header, data[HEADER_SIZE : HEADER_SIZE + header.body_size])


def decode_available(buffer):
    """Decode every complete message at the start of ``buffer`` (bytes): returns (messages, the bytes left over).

    Raises MessageError at the first message that cannot be decoded (a client that trusts its peer less, like
    the receiver, decodes message by message instead).
    """
    messages = []
    while len(buffer) >= HEADER_SIZE:
        header = decode_header(buffer[:HEADER_SIZE])
        end = HEADER_SIZE + header.body_size
        if len(buffer) < end:
            break
        messages.append(decode_body(header, buffer[HEADER_SIZE:end]))
        buffer = buffer[end:]
    return messages, buffer


def _split_version2(header, body):
    if len(body) < EXTENDED_HEADER_SIZE:
        raise MessageError(f"{header.type} {header.device!r}: version 2 body shorter than its extended header")
    extended_size, index_size, data_size, _ = _EXTENDED.unpack(body[:EXTENDED_HEADER_SIZE])
    content_end = len(body) - index_size - data_size
    if extended_size < EXTENDED_HEADER_SIZE or content_end < extended_size:
        raise MessageError(f"{header.type} {header.device!r}: extended header sizes do not fit the body")
    content = body[extended_size:content_end]
    metadata = {}
    if index_size >= 2:
        index = body[content_end : content_end + index_size]
        (count,) = struct.unpack(">H", index[:2])
        if 2 + 8 * count != index_size:
            raise MessageError(f"{header.type} {header.device!r}: metadata index does not match its size")
        position = content_end + index_size
        for entry in range(count):
            key_size, _, value_size = struct.unpack(">HHI", index[2 + 8 * entry : 10 + 8 * entry])
            key = body[position : position + key_size].decode("utf-8", errors="replace")
            position += key_size
            metadata[key] = body[position : position + value_size].decode("utf-8", errors="replace")
            position += value_size
    return content, metadata
