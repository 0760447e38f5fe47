"""Interoperability with the OpenIGTLink C++ library (Debian's libopenigtlink-dev, installed by .ci/run):
our server to a C++ client and a C++ server to our receiver, matrices compared bit for bit (float32)."""

import dataclasses
import shutil
import struct
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from OpenIGTLinkBridgeLib.igtl_server import TrackerServer
from OpenIGTLinkBridgeLib.ndi_protocol import ToolPose
from OpenIGTLinkBridgeLib.ndi_simulator import matrix_to_quaternion

from conftest import headless_scene

SOURCES = Path(__file__).parent / "interop"
HEADERS = Path("/usr/include/openigtlink")
POSE = np.array([[0.36, 0.48, -0.8, 123.25], [-0.8, 0.6, 0.0, -45.5], [0.48, 0.64, 0.6, -1500.75], [0, 0, 0, 1.0]])


@pytest.fixture(scope="module")
def programs(tmp_path_factory):
    if not (HEADERS / "igtlTransformMessage.h").is_file() or shutil.which("g++") is None:
        pytest.skip(
            "the OpenIGTLink C++ library is not installed: apt-get install libopenigtlink-dev g++ (.ci/run does)"
        )
    folder = tmp_path_factory.mktemp("igtl")
    built = {}
    for name in ("igtl_transform_client", "igtl_transform_server"):
        built[name] = folder / name
        subprocess.run(
            ["g++", "-O1", "-o", str(built[name]), str(SOURCES / f"{name}.cxx"), f"-I{HEADERS}", "-lOpenIGTLink"],
            check=True,
            capture_output=True,
        )
    return built


def _bits(values):
    return [struct.unpack(">I", struct.pack(">f", value))[0] for value in values]


class _FixedTracker:
    """A tracker that always sees the probe at POSE (the pose travels exactly as NDI's TX would carry it), one
    new frame each time it is asked (the server sends a tracker frame only once)."""

    def __init__(self):
        self.pose = ToolPose(1, "valid", matrix_to_quaternion(POSE), tuple(POSE[:3, 3]), 0.1, 0x31, 1)

    def poses(self):
        self.pose = dataclasses.replace(self.pose, frame=self.pose.frame + 1)
        return {"Probe": self.pose}, 0

    def close(self):
        pass


def test_cpp_client_reads_our_transforms_bit_exactly(programs):
    tracker = _FixedTracker()
    server = TrackerServer(lambda: tracker, port=0).start()
    try:
        completed = subprocess.run(
            [str(programs["igtl_transform_client"]), "127.0.0.1", str(server.address[1]), "3"],
            capture_output=True,
            text=True,
            timeout=20,
            check=True,
        )
    finally:
        server.stop()
    lines = completed.stdout.split("\n")[:3]
    expected = tracker.pose.matrix()
    values = np.concatenate((expected[:3, :3].T.ravel(), expected[:3, 3]))  # column by column, then t
    for line in lines:
        device, *hexes, _ = line.split()
        assert device == "ProbeToTracker"
        assert [int(h, 16) for h in hexes] == _bits(values)


def test_our_receiver_reads_a_cpp_server_bit_exactly(programs):
    pytest.importorskip("slicer", reason="the receiver writes real MRML nodes: slicer-core needs Python >= 3.10")
    from RAMSICPRegistrationLib.navigation.navigation import matrix_of

    values = np.concatenate((POSE[:3, :3].T.ravel(), POSE[:3, 3]))
    hexes = [f"{bits:08x}" for bits in _bits(values)]
    port = _free_port()
    process = subprocess.Popen(
        [str(programs["igtl_transform_server"]), str(port), "ReferenceToTracker", *hexes],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert process.stdout.readline().strip() == "listening"
        from OpenIGTLinkBridgeLib.receiver import TrackerReceiver

        receiver = TrackerReceiver(headless_scene(), port=port)
        end = time.monotonic() + 5.0
        while time.monotonic() < end and not receiver.received:
            receiver.poll()
            time.sleep(0.01)
        received = matrix_of(receiver.scene.GetFirstNodeByName("ReferenceToTracker"))
        receiver.close()
    finally:
        process.wait(timeout=10)
    expected = np.eye(4)
    floats = np.array(values, dtype=np.float32).astype(np.float64)
    expected[:3, :3] = floats[:9].reshape(3, 3).T
    expected[:3, 3] = floats[9:]
    np.testing.assert_array_equal(received, expected)


def _free_port():
    import socket

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_a_replayed_recording_reaches_a_cpp_client_in_order_at_the_recorded_rate(programs, tmp_path):
    """The real PlusLibData recording, every 10th StylusToTracker marked INVALID, replayed by the command line
    (header version 1): the C++ client gets every valid pose and no other, with the recorded matrices as float32
    bit patterns, in the recorded order, and at the recorded frame rate within 10 %."""
    import sys

    from OpenIGTLinkBridgeLib.plus_sequence import read_sequence, write_sequence

    recording = read_sequence(Path(__file__).parent / "Data" / "ReferenceToRASCalibration.igs.mha")
    frames = [
        dataclasses.replace(frame, statuses={**frame.statuses, "StylusToTracker": "INVALID"}) if i % 10 == 5 else frame
        for i, frame in enumerate(recording.frames)
    ]
    path = write_sequence(tmp_path / "calibration.igs.mha", frames)
    expected = [
        (name, _bits(np.concatenate((matrix[:3, :3].T.ravel(), matrix[:3, 3]))), index)
        for index, frame in enumerate(frames)
        for name, matrix in frame.transforms.items()
        if frame.is_valid(name)
    ]
    assert len(expected) == 2 * 93 - 9
    port = _free_port()
    server = subprocess.Popen(
        [sys.executable, "-m", "OpenIGTLinkBridgeLib.tracker_server", "--replay", str(path), "--port", str(port)],
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 30
        while "serving OpenIGTLink" not in server.stderr.readline():
            assert time.monotonic() < deadline and server.poll() is None
        client = subprocess.run(
            [str(programs["igtl_transform_client"]), "127.0.0.1", str(port), str(len(expected))],
            capture_output=True,
            text=True,
            timeout=60,
            check=True,
        )
        assert server.wait(timeout=10) == 0  # the replay is over: the server exits by itself
    finally:
        server.kill()
        server.wait()
    received = [line.split() for line in client.stdout.splitlines()]
    assert [(fields[0], [int(h, 16) for h in fields[1:13]]) for fields in received] == [
        (name, bits) for name, bits, _ in expected
    ]
    arrival = {}  # frame index -> when its first message arrived (s, the client's steady clock)
    for fields, (_, _, index) in zip(received, expected):
        arrival.setdefault(index, float(fields[13]))
    recorded = recording.timestamps_s
    replayed_rate = (len(arrival) - 1) / (arrival[max(arrival)] - arrival[min(arrival)])
    recorded_rate = (len(recorded) - 1) / (recorded[-1] - recorded[0])
    assert replayed_rate == pytest.approx(recorded_rate, rel=0.10)
