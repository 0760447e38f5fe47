"""Wire formats of the tracker feed: OpenIGTLink (CRC-64, TRANSFORM, STATUS, header v1/v2) and NDI's Combined API."""

import struct

import numpy as np
import pytest

from OpenIGTLinkBridgeLib import igtl_messages as igtl
from OpenIGTLinkBridgeLib import ndi_protocol as ndi
from RAMSICPRegistrationLib.core.transforms import make_transform, rotation_about_axis

POSE = make_transform(rotation_about_axis((1.0, -2.0, 0.5), 0.7), (123.25, -45.5, -1500.75))


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
