"""Recorded sessions through the server (replay.ReplaySource), the server's back-off and its command line."""

import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from OpenIGTLinkBridgeLib import igtl_messages as igtl
from OpenIGTLinkBridgeLib.igtl_server import BACKOFF_MAX_S, TrackerServer, TrackerSource
from OpenIGTLinkBridgeLib.ndi_driver import TrackerConnectionError
from OpenIGTLinkBridgeLib.plus_sequence import Recording, TrackedFrame, read_sequence
from OpenIGTLinkBridgeLib.replay import ReplaySource, parse_renames, rename_devices

DATA = Path(__file__).parent / "Data"
CALIBRATION = DATA / "ReferenceToRASCalibration.igs.mha"


def _synthetic(count=40, rate_hz=20.0, invalid_every=5):
    """ProbeToTracker moving along x (x = frame number, mm), invalid every ``invalid_every`` frames; a fixed
    ReferenceToTracker."""
    frames = []
    for index in range(count):
        probe = np.eye(4)
        probe[:3, 3] = (float(index), 2.0, 3.0)
        valid = index % invalid_every != invalid_every - 1
        frames.append(
            TrackedFrame(
                100.0 + index / rate_hz,
                {"ReferenceToTracker": np.eye(4), "ProbeToTracker": probe},
                {"ReferenceToTracker": "OK", "ProbeToTracker": "OK" if valid else "INVALID"},
            )
        )
    return Recording(frames, {}, Path("synthetic.igs.mha"))


def _receive(port, until, timeout_s=10.0):
    """Decoded messages from the server until ``until(messages)`` holds (or the timeout)."""
    client = socket.create_connection(("127.0.0.1", port), timeout=timeout_s)
    buffer, messages, deadline = b"", [], time.monotonic() + timeout_s
    while not until(messages) and time.monotonic() < deadline:
        try:
            chunk = client.recv(65536)
        except socket.timeout:
            break
        if not chunk:
            break
        decoded, buffer = igtl.decode_available(buffer + chunk)
        messages.extend(decoded)
    client.close()
    return messages


def _transforms(messages):
    return [message for message in messages if message.type == "TRANSFORM"]


def _finished(messages):
    return any(m.type == "STATUS" and m.content.text.startswith("replay finished") for m in messages)


@pytest.mark.parametrize("version", [1, 2])
def test_a_replay_follows_the_version_rules_for_invalid_frames(version):
    """40 frames, every 5th probe pose INVALID: version 1 peers get 32 probe poses, version 2 peers all 40 with the
    8 invalid ones flagged; the reference always; time stamps keep the recorded 50 ms steps at any speed."""
    server = TrackerServer(source=ReplaySource(_synthetic(), speed=8.0), port=0, header_version=version).start()
    try:
        messages = _receive(server.address[1], _finished)
    finally:
        server.stop()
    transforms = _transforms(messages)
    probes = [m for m in transforms if m.device == "ProbeToTracker"]
    references = [m for m in transforms if m.device == "ReferenceToTracker"]
    assert len(references) == 40
    if version == 1:
        assert [m.content[0, 3] for m in probes] == [i for i in range(40) if i % 5 != 4]
    else:
        assert len(probes) == 40
        flags = [m.metadata["TransformValid"] for m in probes]
        assert flags == ["false" if i % 5 == 4 else "true" for i in range(40)]
        assert {m.metadata["TransformStatus"] for m in probes if m.metadata["TransformValid"] == "false"} == {"INVALID"}
    stamps = np.array([m.timestamp_s for m in references])
    np.testing.assert_allclose(np.diff(stamps), 0.05, atol=1e-6)  # OpenIGTLink stamps have 2^-32 s steps


def test_a_looped_replay_starts_again_one_interval_after_the_last_frame():
    source = ReplaySource(_synthetic(count=4, invalid_every=99), loop=True, speed=20.0)
    server = TrackerServer(source=source, port=0).start()
    try:
        messages = _receive(server.address[1], lambda got: len(_transforms(got)) >= 2 * 10)
    finally:
        server.stop()
    probes = [m for m in _transforms(messages) if m.device == "ProbeToTracker"][:10]
    assert [m.content[0, 3] for m in probes] == [0, 1, 2, 3, 0, 1, 2, 3, 0, 1]
    np.testing.assert_allclose(np.diff([m.timestamp_s for m in probes]), 0.05, atol=1e-6)


def test_renames_map_plus_names_onto_ours_and_refuse_what_cannot_work():
    names = ["ReferenceToTracker", "StylusToTracker"]
    assert rename_devices(names, parse_renames(["Stylus=Probe"])) == {
        "ReferenceToTracker": "ReferenceToTracker",
        "StylusToTracker": "ProbeToTracker",
    }
    assert rename_devices(names, parse_renames(["StylusToTracker=ProbeToTracker"]))["StylusToTracker"] == (
        "ProbeToTracker"
    )
    with pytest.raises(ValueError, match="has no Needle transform .it has ReferenceToTracker, StylusToTracker"):
        rename_devices(names, parse_renames(["Needle=Probe"]))
    with pytest.raises(ValueError, match="two transforms the name ReferenceToTracker"):
        rename_devices(names, parse_renames(["Stylus=Reference"]))
    with pytest.raises(ValueError, match="longer than OpenIGTLink's 20 characters"):
        rename_devices(names, parse_renames(["Stylus=AVeryLongProbeName"]))
    for bad in ("Stylus", "=Probe", "Stylus=", "Sty lus=Probe"):
        with pytest.raises(ValueError, match="write OLD=NEW"):
            parse_renames([bad])


def test_a_tracker_that_keeps_failing_is_retried_less_and_less_often_and_says_why():
    calls = []

    def failing():
        calls.append(time.monotonic())
        raise TrackerConnectionError("cannot reach the NDI tracker at 10.0.0.9:8765 (timed out)")

    source = TrackerSource(failing)
    waits = []
    for _ in range(8):
        assert source.read() == []
        waits.append(source.backoff_s)
    assert waits == [0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 8.0, 8.0] and BACKOFF_MAX_S == 8.0
    code, name, text = source.status
    assert (code, name) == (16, "DISCONNECTED") and "10.0.0.9:8765 (timed out); next try in 8 s" in text
    assert source.next_due() - time.monotonic() == pytest.approx(8.0, abs=0.5)
    server = TrackerServer(failing, port=0).start()  # served: the tries thin out (0.25 + 0.5 + 1 s ...)
    try:
        calls.clear()
        time.sleep(1.6)
    finally:
        server.stop()
    assert 2 <= len(calls) <= 4


def _server_command(*arguments, timeout=20):
    return subprocess.run(
        [sys.executable, "-m", "OpenIGTLinkBridgeLib.tracker_server", *arguments],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _free_port():
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.mark.parametrize(
    "arguments, expected",
    [
        (["--ndi", "127.0.0.1:abc"], "--ndi 127.0.0.1:abc: the port after ':' must be a number from 1 to 65535"),
        (["--simulate", "--rate", "0"], "--rate 0: give a rate above 0"),
        (["--simulate", "--rate", "-5"], "--rate -5: give a rate above 0"),
        (["--simulate", "--port", "99999"], "--port 99999: give a port from 1 to 65535"),
        (["--simulate", "--reference-rom", "missing.rom"], "--reference-rom missing.rom: no such file"),
        (["--simulate", "--probe-rom", "{garbage}"], "not an NDI tool definition"),
        (["--simulate", "--tool-rom", "{folder}"], "is a folder; give the tool's .rom file"),
        (["--replay", "missing.igs.mha"], "missing.igs.mha: no such file"),
        (["--replay", "{truncated}"], "the file was cut short"),
        (["--replay", str(CALIBRATION), "--speed", "0"], "replay speed 0.0: give a number above 0"),
        (["--replay", str(CALIBRATION), "--rename", "Needle=Probe"], "the recording has no Needle transform"),
        (["--simulate", "--loop"], "--loop, --speed and --rename only apply to --replay FILE"),
        ([], "one of the arguments --ndi --serial --simulate --replay is required (see ramsicp-tracker-server --help)"),
        (["--simulate", "--port", "abc"], "argument --port: invalid int value: 'abc'"),
    ],
)
def test_bad_arguments_and_files_give_one_line_and_exit_2_before_anything_starts(tmp_path, arguments, expected):
    garbage = tmp_path / "garbage.rom"
    garbage.write_bytes(b"this is not a tool definition" * 10)
    truncated = tmp_path / "truncated.igs.mha"
    truncated.write_text(CALIBRATION.read_text()[:300])  # cut before its first frame
    arguments = [a.format(garbage=garbage, truncated=truncated, folder=tmp_path) for a in arguments]
    start = time.monotonic()
    port = [] if "--port" in arguments else ["--port", str(_free_port())]
    completed = _server_command(*arguments, *port)
    assert completed.returncode == 2, completed.stderr
    lines = completed.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ramsicp-tracker-server: error: ") and expected in lines[0]
    assert "Traceback" not in completed.stderr and "tracker connected" not in completed.stderr
    assert time.monotonic() - start < 10


def test_a_busy_port_is_refused_in_one_line():
    busy = socket.create_server(("127.0.0.1", 0))
    port = busy.getsockname()[1]
    try:
        completed = _server_command("--simulate", "--port", str(port))
    finally:
        busy.close()
    assert completed.returncode == 2
    assert completed.stderr == (
        f"ramsicp-tracker-server: error: port {port} on 127.0.0.1 is in use (another ramsicp-tracker-server or "
        "PlusServer?); stop it or give another --port\n"
    )


def test_help_explains_every_option():
    completed = _server_command("--help")
    text = " ".join(completed.stdout.split())
    assert completed.returncode == 0
    assert "to every client (3D Slicer with SlicerOpenIGTLink, or the OpenIGTLinkBridge module)." in text
    assert "device name of the reference body's pose (default ReferenceToTracker)" in text
    assert "OpenIGTLink port to serve on (default 18944)" in text
    assert "--replay FILE" in text and "--rename OLD=NEW" in text and "--speed SPEED" in text


@pytest.mark.parametrize("version", [1, 2])
def test_the_receiver_records_a_replayed_session_frame_for_frame(tmp_path, version):
    """Replay -> our receiver, recording: the same frames, times and statuses come back in the file (a version 1
    stream carries no invalid pose, so those are recorded as INVALID with an identity matrix)."""
    pytest.importorskip("slicer", reason="the receiver writes real MRML nodes: slicer-core needs Python >= 3.10")
    from OpenIGTLinkBridgeLib.receiver import TrackerReceiver

    from conftest import headless_scene

    original = _synthetic()
    server = TrackerServer(source=ReplaySource(original, speed=8.0), port=0, header_version=version).start()
    receiver = TrackerReceiver(headless_scene(), port=server.address[1])
    path = tmp_path / "received.igs.mha"
    receiver.start_recording(path)
    deadline = time.monotonic() + 10
    while not (receiver.last_status and receiver.last_status.text.startswith("replay finished")):
        assert time.monotonic() < deadline
        receiver.poll()
        time.sleep(0.005)
    assert receiver.stop_recording() == path
    receiver.close()
    server.stop()
    recorded = read_sequence(path)
    assert len(recorded.frames) == 40 and recorded.transform_names == ["ReferenceToTracker", "ProbeToTracker"]
    stamps = recorded.timestamps_s
    np.testing.assert_allclose(np.diff(stamps), 0.05, atol=1e-6)
    for before, after in zip(original.frames, recorded.frames):
        assert after.statuses == before.statuses
        valid = before.is_valid("ProbeToTracker")
        expected = before.transforms["ProbeToTracker"] if valid or version == 2 else np.eye(4)
        np.testing.assert_array_equal(after.transforms["ProbeToTracker"], expected)
