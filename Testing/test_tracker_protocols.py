"""Wire formats of the tracker feed: OpenIGTLink (CRC-64, TRANSFORM, STATUS, header v1/v2) and NDI's Combined API."""

import struct

import numpy as np
import pytest

from OpenIGTLinkBridgeLib import igtl_messages as igtl
from OpenIGTLinkBridgeLib import ndi_protocol as ndi
from RAMSICPRegistrationLib.core.transforms import make_transform, rotation_about_axis

POSE = make_transform(rotation_about_axis((1.0, -2.0, 0.5), 0.7), (123.25, -45.5, -1500.75))

# TRANSFORM messages written out by hand from the OpenIGTLink protocol description (github.com/openigtlink/
# OpenIGTLink, Documents/Protocol/header.md and transform.md): big-endian numbers, NUL-padded names, and the
# upper 3x4 of the matrix as IEEE-754 float32 in the order R11 R21 R31 R12 R22 R32 R13 R23 R33 TX TY TZ (column
# by column, then the translation). The matrix is not symmetric and no value repeats, so any other order shows;
# every value is exact in float32. The CRC-64 (ECMA-182) of each body was computed with OpenIGTLink's own crc64
# (igtl_util.c, via libopenigtlink), and the version 1 message is what its igtl::TransformMessage::Pack() writes,
# but for the timestamp's fraction: 0.25 s is 0x40000000 (2^30 / 2^32), where its igtl_nanosec_to_frac gives
# 0x3FFFFFFF for 250,000,000 ns. In version 2, META_HEADER_SIZE counts INDEX_COUNT and the entries and META_SIZE
# the keys and values, as in the library's own test message (Testing/igtlutil/igtl_test_data_transformFormat2.h).
SPEC_MATRIX = np.array(
    [[1.0, -2.0, 0.5, 10.5], [4.0, 0.25, -8.0, -20.25], [-0.125, 16.0, 3.0, -1500.75], [0.0, 0.0, 0.0, 1.0]]
)
SPEC_TIMESTAMP_S = 1700000000.25
SPEC_CONTENT = bytes.fromhex(
    "3f800000 40800000 be000000"  # R11 = 1, R21 = 4, R31 = -0.125: the first column
    "c0000000 3e800000 41800000"  # R12 = -2, R22 = 0.25, R32 = 16
    "3f000000 c1000000 40400000"  # R13 = 0.5, R23 = -8, R33 = 3
    "41280000 c1a20000 c4bb9800"  # TX = 10.5, TY = -20.25, TZ = -1500.75
)
SPEC_VERSION_1 = (
    bytes.fromhex(
        "0001"  # V: header version 1
        "5452414e53464f524d 000000"  # TYPE: "TRANSFORM", padded to 12
        "50726f6265546f547261636b6572 000000000000"  # DEVICE_NAME: "ProbeToTracker", padded to 20
        "6553f100 40000000"  # TIME_STAMP: 1,700,000,000 s = 0x6553F100, then the fraction 0.25 = 0x40000000
        "0000000000000030"  # BODY_SIZE: 48
        "2241ccade0273325"  # CRC of the body
    )
    + SPEC_CONTENT
)
SPEC_VERSION_2 = (
    bytes.fromhex(
        "0002"  # V: header version 2 (protocol 3)
        "5452414e53464f524d 000000"  # TYPE: "TRANSFORM"
        "5374796c7573546f547261636b6572 0000000000"  # DEVICE_NAME: "StylusToTracker"
        "6553f100 40000000"  # TIME_STAMP
        "0000000000000057"  # BODY_SIZE: 12 (extended header) + 48 (content) + 10 + 17 (metadata) = 87
        "a93fb56cdc199dad"  # CRC of the whole body
        "000c 000a 00000011 00000007"  # EXT_HEADER_SIZE 12, META_HEADER_SIZE 2 + 8, META_SIZE 15 + 2, MSG_ID 7
    )
    + SPEC_CONTENT
    + bytes.fromhex(
        "0001"  # INDEX_COUNT
        "000f 0003 00000002"  # KEY_SIZE 15, VALUE_ENCODING 3 (US-ASCII), VALUE_SIZE 2
        "5472616e73666f726d537461747573 4f4b"  # "TransformStatus", "OK"
    )
)


def test_crc_check_values():
    assert igtl.crc64(b"123456789") == 0x6C40DF5F0B497347  # CRC-64/ECMA-182 check value
    assert ndi.crc16("123456789") == 0xBB3D  # CRC-16/ARC check value


def test_transform_round_trip_v1_layout_by_hand():
    data = igtl.encode_transform("ProbeToTracker", POSE, timestamp_s=1700000000.25)
    assert len(data) == igtl.HEADER_SIZE + 48
    version, kind, device = struct.unpack(">H12s20s", data[:34])
    assert (version, kind.rstrip(b"\0"), device.rstrip(b"\0")) == (1, b"TRANSFORM", b"ProbeToTracker")
    first = struct.unpack(">3f", data[58:70])  # the first column of R comes first
    np.testing.assert_allclose(first, POSE[:3, 0], rtol=1e-6)
    message = igtl.decode(data)
    assert message.type == "TRANSFORM" and message.device == "ProbeToTracker"
    assert message.timestamp_s == pytest.approx(1700000000.25)
    np.testing.assert_allclose(message.content, POSE, atol=1e-4)  # float32 on the wire
    assert np.array_equal(message.content, igtl.decode(igtl.encode_transform("x", message.content)).content)


def test_transform_bytes_are_the_specifications_written_out_by_hand():
    encoded = igtl.encode_transform("ProbeToTracker", SPEC_MATRIX, timestamp_s=SPEC_TIMESTAMP_S)
    assert encoded.hex(" ", 4) == SPEC_VERSION_1.hex(" ", 4)  # hex, so that a failure shows the differing words
    message = igtl.decode(SPEC_VERSION_1)
    assert (message.type, message.device, message.version) == ("TRANSFORM", "ProbeToTracker", 1)
    assert message.timestamp_s == SPEC_TIMESTAMP_S
    np.testing.assert_array_equal(message.content, SPEC_MATRIX)


def test_transforms_encoded_together_are_the_same_bytes_as_one_by_one(rng):
    """The tool path's batch encoder (its CRC-64 of every body computed at once) against the per-message one."""
    from conftest import random_transform

    matrices = np.array([random_transform(rng) for _ in range(257)])
    together = igtl.encode_transforms("PlanToolToRobotBase", matrices)
    assert together == b"".join(igtl.encode_transform("PlanToolToRobotBase", matrix) for matrix in matrices)
    assert igtl.encode_transforms("x", np.zeros((0, 4, 4))) == b""
    with pytest.raises(ValueError, match="finite"):
        igtl.encode_transforms("x", np.full((2, 4, 4), np.nan))


def test_version_2_transform_bytes_are_the_specifications_written_out_by_hand():
    encoded = igtl.encode_transform(
        "StylusToTracker", SPEC_MATRIX, SPEC_TIMESTAMP_S, version=2, metadata={"TransformStatus": "OK"}, message_id=7
    )
    assert encoded.hex(" ", 4) == SPEC_VERSION_2.hex(" ", 4)
    message = igtl.decode(SPEC_VERSION_2)
    assert (message.device, message.version, message.metadata) == ("StylusToTracker", 2, {"TransformStatus": "OK"})
    np.testing.assert_array_equal(message.content, SPEC_MATRIX)


def test_version_2_carries_metadata():
    data = igtl.encode_transform(
        "StylusToTracker",
        POSE,
        version=2,
        metadata={"TransformStatus": "INVALID", "TransformValid": "false"},
        message_id=7,
    )
    message = igtl.decode(data)
    assert message.version == 2
    assert message.metadata == {"TransformStatus": "INVALID", "TransformValid": "false"}
    np.testing.assert_allclose(message.content, POSE, atol=1e-4)


def test_status_round_trip():
    status = igtl.Status(code=13, subcode=2, error_name="TRACKER", text="ReferenceToTracker missing")
    message = igtl.decode(igtl.encode_status("Tracker", status))
    assert message.content == status and igtl.STATUS_CODES[message.content.code] == "NOT_READY"


@pytest.mark.parametrize(
    "corrupt, reason",
    [
        (lambda d: d[:-5], "body has 43 of 48 bytes"),
        (lambda d: d[:60] + bytes([d[60] ^ 0xFF]) + d[61:], "CRC mismatch"),
        (lambda d: d[:2] + b"IMAGEX\0\0\0\0\0\0" + d[14:], "unknown message type 'IMAGEX'"),
        (lambda d: struct.pack(">H", 9) + d[2:], "unknown header version 9"),
        (lambda d: d[:42] + struct.pack(">Q", 1 << 40) + d[50:], "over the 1048576-byte limit"),
        (lambda d: d[:20] + b"\xff" + d[21:], "not ASCII"),  # a byte of the device name
    ],
)
def test_malformed_messages_are_refused_with_a_reason(corrupt, reason):
    data = igtl.encode_transform("ProbeToTracker", POSE)
    with pytest.raises(igtl.MessageError) as error:
        igtl.decode(corrupt(data))
    assert reason in str(error.value)


def test_ndi_command_and_reply_framing():
    assert ndi.frame_command("TX", "0001") == f"TX:0001{ndi.crc16('TX:0001'):04X}\r".encode()
    assert ndi.check_reply(ndi.frame_reply("OKAY"), "INIT") == "OKAY"
    with pytest.raises(ndi.NDIProtocolError, match="wrong CRC"):
        ndi.check_reply(b"OKAY0000\r", "INIT")
    with pytest.raises(ndi.NDICommandError) as error:
        ndi.check_reply(ndi.frame_reply("ERROR0D"), "PENA:01D")
    assert error.value.code == 0x0D and "no tool is assigned" in str(error.value)


def test_tx_reply_round_trip_and_pose():
    quaternion = (0.7071, 0.0, 0.7071, 0.0)  # 90 degrees about y
    valid = ndi.ToolPose(1, "valid", quaternion, (10.5, -20.25, -1800.0), 0.1234, 0x31, 1234)
    missing = ndi.ToolPose(2, "missing", port_status=0x11, frame=1234)
    out = ndi.ToolPose(3, "valid", (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, -3000.0), 0.2, 0x31 | 0x80, 1234)
    text = ndi.format_tx([valid, missing, out, ndi.ToolPose(4, "disabled")], system_status=0x0001)
    poses, system_status = ndi.parse_tx(text)
    assert system_status == 1 and [p.state for p in poses] == ["valid", "missing", "valid", "disabled"]
    assert poses[0] == valid and poses[1] == missing and poses[2].out_of_volume and not poses[0].out_of_volume
    matrix = poses[0].matrix()
    np.testing.assert_allclose(matrix[:3, :3] @ (1.0, 0.0, 0.0), (0.0, 0.0, -1.0), atol=1e-4)
    np.testing.assert_allclose(matrix[:3, 3], (10.5, -20.25, -1800.0))
    with pytest.raises(ValueError, match="is missing: it has no pose"):
        poses[1].matrix()
    assert ndi.parse_tx(ndi.format_tx([])) == ([], 0)


@pytest.mark.parametrize(
    "text, reason",
    [
        ("02" + "01DISABLED\n" + "0000", "announces 2 handles but holds 1"),
        ("01" + "01+10000\n0000", "has 6 characters, not 67"),
        ("zz", "malformed TX reply"),
    ],
)
def test_malformed_tx_replies(text, reason):
    with pytest.raises(ndi.NDIProtocolError, match=reason):
        ndi.parse_tx(text)
