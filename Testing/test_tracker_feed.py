"""The live tracker chain on loopback: Vega simulator -> NDI driver -> OpenIGTLink server -> receiver -> MRML."""

import socket
import threading
import time

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from OpenIGTLinkBridgeLib import igtl_messages as igtl
from OpenIGTLinkBridgeLib.igtl_server import TrackerServer
from OpenIGTLinkBridgeLib.live_scenario import PROBE_TIP_MM, demo_simulator
from OpenIGTLinkBridgeLib.ndi_driver import NDITracker, TrackerConnectionError, open_tracker
from OpenIGTLinkBridgeLib.ndi_protocol import NDICommandError, crc16
from RAMSICPRegistrationLib.io.ndi_tools import tool_rom_path

from conftest import headless_scene

try:
    import slicer
except ImportError:  # slicer-core installs on Python >= 3.10 only
    slicer = None
from OpenIGTLinkBridgeLib.receiver import TrackerReceiver
from RAMSICPRegistrationLib.navigation.navigation import matrix_of

#: For the tests that write MRML nodes; the driver, server and serial-line tests need none and run everywhere.
needs_mrml = pytest.mark.skipif(slicer is None, reason="slicer-core (real MRML) needs Python >= 3.10")

POINTS = np.array([[0.0, 0.0, 0.0], [12.0, -3.0, 5.0], [-4.0, 9.0, 2.0], [7.0, 7.0, -6.0]])


def _tracker(simulator):
    return open_tracker("127.0.0.1", simulator.address[1], timeout_s=1.0)


@pytest.fixture
def chain(request):
    """Simulator, server and receiver, torn down after the test; options via indirect parametrisation."""
    options = getattr(request, "param", {})
    simulator, script = demo_simulator(POINTS, **options.get("simulator", {}))
    simulator.start()
    server = TrackerServer(lambda: _tracker(simulator), port=0, header_version=options.get("version", 1)).start()
    receiver = TrackerReceiver(headless_scene(), port=server.address[1], stale_after_s=options.get("stale", 1.0))
    yield simulator, script, server, receiver
    receiver.close()
    server.stop()
    simulator.stop()


def _run(receiver, seconds):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        receiver.poll()
        time.sleep(0.005)


def test_driver_reads_the_simulated_poses():
    simulator, script = demo_simulator(POINTS)
    simulator.start()
    try:
        tracker = _tracker(simulator)
        time.sleep(0.4)  # the script's first dwell
        poses, system_status = tracker.poses()
        assert system_status == 0 and set(poses) == {"Reference", "Probe"}
        np.testing.assert_allclose(poses["Reference"].matrix(), script.reference_to_tracker, atol=1e-3)
        assert poses["Probe"].state == "valid" and poses["Probe"].frame > 0
        tracker.close()
    finally:
        simulator.stop()


def test_driver_errors_have_ndi_meanings_and_timeouts():
    simulator, _ = demo_simulator(POINTS)
    simulator.start()
    try:
        tracker = NDITracker("127.0.0.1", simulator.address[1], timeout_s=1.0).connect()
        with pytest.raises(NDICommandError) as error:
            tracker.command("TX", "0001")  # before TSTART
        assert error.value.code == 0x0C and "current operating mode" in str(error.value)
        tracker.close()  # like a real tracker, the simulator serves one host at a time
        raw = socket.create_connection(simulator.address[:2], timeout=1.0)
        raw.sendall(b"INIT:0000\r")  # a wrong CRC
        reply = raw.recv(100)
        assert reply.startswith(b"ERROR04") and int(reply[7:11], 16) == crc16("ERROR04")
        raw.close()
    finally:
        simulator.stop()
    with pytest.raises(TrackerConnectionError, match="cannot reach the NDI tracker"):
        NDITracker("127.0.0.1", _free_port(), timeout_s=0.5).connect()
    silent = socket.create_server(("127.0.0.1", 0))
    start = time.monotonic()
    with pytest.raises(TrackerConnectionError, match="did not answer 'INIT:' within 0.3 s"):
        NDITracker("127.0.0.1", silent.getsockname()[1], timeout_s=0.3).connect()
    assert time.monotonic() - start < 2.0
    silent.close()


def _free_port():
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@needs_mrml
def test_chain_keeps_probe_to_reference_and_drops_no_frame():
    """Every frame the server sends from the moment the receiver connects arrives: the frames sent by a moment are
    all received, counted exactly once the receiver has read what was still on its way."""
    from OpenIGTLinkBridgeLib.igtl_server import TrackerSource

    simulator, script = demo_simulator(POINTS)
    simulator.start()
    source = TrackerSource(lambda: _tracker(simulator), wait_for_client=True)
    server = TrackerServer(source=source, port=0).start()
    receiver = TrackerReceiver(headless_scene(), port=server.address[1])
    try:
        _run(receiver, 1.2)
        assert receiver.status("ProbeToTracker") == "valid" and receiver.last_status.text == "tracker connected"
        probe_to_reference = matrix_of(receiver.scene.GetFirstNodeByName("ProbeToReference"))
        sent = server.frames_sent  # every one of these must arrive
        deadline = time.monotonic() + 5.0
        while receiver.received["ProbeToTracker"] < sent and time.monotonic() < deadline:
            receiver.poll()
            time.sleep(0.005)
        counts = dict(receiver.received)
    finally:
        receiver.close()
        server.stop()
        simulator.stop()
    assert sent >= 55  # 60 Hz for over a second
    assert counts["ProbeToTracker"] >= sent and counts["ReferenceToTracker"] >= sent  # none lost
    assert counts["ProbeToTracker"] <= server.frames_sent  # and none twice
    # The pose is one the simulated tracker was shown; the TX reply rounds to 0.01 mm and to 1e-4 in the
    # quaternion: at most about 0.03 mm at the 110 mm tip.
    assert _distance_from_script_mm(script, probe_to_reference) < 0.05


def _distance_from_script_mm(script, probe_to_reference):
    """How far (mm) a received ProbeToReference is from the closest pose of the script, at the probe's tip, its
    origin and 50 mm along its x axis; the script's time is searched on a 1 ms grid, then refined."""
    probe_points = np.array([[*PROBE_TIP_MM, 1.0], [0.0, 0.0, 0.0, 1.0], [50.0, 0.0, 0.0, 1.0]]).T

    def distance(time_s):
        return np.linalg.norm((script.probe_to_reference(time_s) - probe_to_reference) @ probe_points, axis=0).max()

    times = np.arange(0.0, script.duration_s, 1e-3)
    nearest = times[np.argmin([distance(time_s) for time_s in times])]
    return minimize_scalar(distance, bounds=(nearest - 1e-3, nearest + 1e-3), method="bounded").fun


@needs_mrml
@pytest.mark.parametrize("chain", [{"version": 2, "simulator": {"dropout": lambda t: 0.5 < t < 1.5}}], indirect=True)
def test_version_2_flags_a_missing_probe(chain):
    _, _, _, receiver = chain
    _run(receiver, 1.0)
    assert receiver.status("ProbeToTracker") == "missing" and receiver.status("ReferenceToTracker") == "valid"
    _run(receiver, 1.0)
    assert receiver.status("ProbeToTracker") == "valid"


@needs_mrml
@pytest.mark.parametrize("chain", [{"stale": 0.2, "simulator": {"out_of_volume": lambda t: t > 0.5}}], indirect=True)
def test_version_1_sends_no_invalid_pose_so_the_probe_goes_stale(chain):
    _, _, _, receiver = chain
    _run(receiver, 1.2)
    assert receiver.status("ProbeToTracker") == "stale" and receiver.status("ReferenceToTracker") == "valid"


@needs_mrml
@pytest.mark.parametrize("chain", [{"simulator": {"disconnect_after_s": 0.4}}], indirect=True)
def test_tracker_disconnect_is_reported_and_tracking_resumes(chain):
    _, _, server, receiver = chain
    statuses = []
    end = time.monotonic() + 3.0
    while time.monotonic() < end:
        receiver.poll()
        if receiver.last_status is not None and (not statuses or statuses[-1] != receiver.last_status.text):
            statuses.append(receiver.last_status.text)
        time.sleep(0.005)
    assert any("not answering" in text for text in statuses)
    assert statuses[-1] == "tracker connected"
    before = receiver.received["ProbeToTracker"]
    _run(receiver, 0.3)
    assert receiver.received["ProbeToTracker"] > before


@needs_mrml
def test_a_client_that_disappears_does_not_stall_the_others(chain):
    _, _, server, receiver = chain
    rude = socket.create_connection(server.address[:2])
    _run(receiver, 0.3)
    rude.close()
    before = receiver.received.get("ProbeToTracker", 0)
    # Not stalled: the next 25 frames (0.42 s of the 60 Hz feed) arrive; a loaded machine may take longer to deliver
    # them, a stalled server never does.
    end = time.monotonic() + 10.0
    while receiver.received.get("ProbeToTracker", 0) - before < 25 and time.monotonic() < end:
        _run(receiver, 0.05)
    assert receiver.received["ProbeToTracker"] - before >= 25


class _ScriptedServer:
    """A raw OpenIGTLink peer that sends given byte chunks to the first client, for malformed-input tests."""

    def __init__(self, chunks):
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.chunks = chunks
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        client, _ = self.listener.accept()
        for chunk in self.chunks:
            client.sendall(chunk)
            time.sleep(0.05)
        time.sleep(0.5)
        client.close()


@needs_mrml
def test_receiver_skips_malformed_messages_and_keeps_the_connection():
    pose = np.eye(4)
    pose[:3, 3] = (1.0, 2.0, 3.0)
    good = igtl.encode_transform("ReferenceToTracker", pose)
    wrong_crc = good[:-1] + bytes([good[-1] ^ 1])
    unknown = igtl.encode_transform("X", pose).replace(b"TRANSFORM\0\0\0", b"POINTCLOUD\0\0", 1)
    later = pose.copy()
    later[:3, 3] = (4.0, 5.0, 6.0)
    final = igtl.encode_transform("ReferenceToTracker", later)
    peer = _ScriptedServer([good, wrong_crc, unknown, final[:30], final[30:]])
    receiver = TrackerReceiver(headless_scene(), port=peer.port)
    _run(receiver, 0.6)
    assert receiver.skipped == 2 and receiver.received["ReferenceToTracker"] == 2
    np.testing.assert_allclose(matrix_of(receiver.scene.GetFirstNodeByName("ReferenceToTracker"))[:3, 3], (4, 5, 6))
    receiver.close()


@needs_mrml
def test_receiver_resets_on_a_broken_stream_and_reuses_existing_nodes():
    oversized = bytearray(igtl.encode_transform("ReferenceToTracker", np.eye(4)))
    oversized[42:50] = (1 << 40).to_bytes(8, "big")
    peer = _ScriptedServer([bytes(oversized)])
    scene = headless_scene()
    existing = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ReferenceToTracker")  # SlicerOpenIGTLink's
    receiver = TrackerReceiver(scene, port=peer.port)
    _run(receiver, 0.3)
    assert receiver.skipped == 1 and receiver.status("ReferenceToTracker") == "disconnected"
    assert scene.GetFirstNodeByName("ReferenceToTracker") is existing
    receiver.close()


@needs_mrml
def test_idle_receiver_uses_almost_no_cpu():
    receiver = TrackerReceiver(headless_scene(), port=_free_port())
    start_cpu, start = time.process_time(), time.monotonic()
    while time.monotonic() - start < 1.0:
        receiver.poll()  # nothing to connect to: it retries twice a second, no busy loop
        time.sleep(0.02)  # the widget's timer period
    assert (time.process_time() - start_cpu) / (time.monotonic() - start) < 0.05


def _measured_tips(script, noise_mm, rate_hz, frames, seed=0):
    """The tip (reference coordinates) in each tracker frame as the simulated Vega measures it: the script's poses
    at the frame's time, the frame's noise, and NDI's TX rounding (4-decimal quaternion, 0.01 mm translation)."""
    from OpenIGTLinkBridgeLib.ndi_protocol import ToolPose, format_tx, parse_tx
    from OpenIGTLinkBridgeLib.ndi_simulator import matrix_to_quaternion

    tips = []
    for frame in frames:
        measured = []
        poses = (script.reference_to_tracker, script.reference_to_tracker @ script.probe_to_reference(frame / rate_hz))
        for handle, pose in enumerate(poses, start=1):
            noise = np.random.default_rng((seed, frame, handle)).normal(size=3) * noise_mm / np.sqrt(3)
            sent = ToolPose(handle, "valid", matrix_to_quaternion(pose), tuple(pose[:3, 3] + noise), 0.1, 0x31, frame)
            measured.append(parse_tx(format_tx([sent]))[0][0].matrix())
        probe_to_reference = np.linalg.inv(measured[0]) @ measured[1]
        tips.append(probe_to_reference[:3, :3] @ PROBE_TIP_MM + probe_to_reference[:3, 3])
    return np.array(tips)


@needs_mrml
def test_live_demo_collects_every_touch_through_the_chain(tibia_patient, tibia_index, tmp_path):
    """Deterministic (issue 17): the simulated tracker measures each frame once (noise drawn per frame) and is read
    once per frame however loaded the machine, the server sends each tracker frame once from the moment the
    receiver connects, and a touch is the mean of its whole hold: the collected points are known exactly."""
    import dataclasses

    from OpenIGTLinkBridgeLib.live_demo import TRACKER_RATE_HZ, run_live_demo
    from OpenIGTLinkBridgeLib.live_scenario import DEFAULT_REFERENCE_TO_TRACKER, TouchScript

    trial = tibia_patient.simulate_trial(np.random.default_rng(3), 1.0, probe_noise_mm=0.0)
    trial = dataclasses.replace(trial, ppc=trial.ppc[::5])  # one touch per sub-area: 8 points
    path = tmp_path / "session.igs.mha"
    result = run_live_demo(slicer.vtkMRMLScene(), tibia_patient, tibia_index, trial, probe_noise_mm=0.25, record=path)
    assert len(result.collected) == 8
    assert np.sqrt(np.mean(result.collection_error_mm**2)) < 0.2  # hold means of 0.25 mm noise
    # The known answer: each touch is the mean of the tracker's own measurements over the frames in which the
    # script holds the tip on that point, every one of them delivered (float32 on the wire: 1e-3 mm).
    script = TouchScript(trial.ppc, DEFAULT_REFERENCE_TO_TRACKER, dwell_s=0.25, move_s=0.1)
    for number, touch in enumerate(result.touches):
        start, end = script.touch_interval(number)
        frames = np.arange(int(start * TRACKER_RATE_HZ) - 2, int(end * TRACKER_RATE_HZ) + 3)
        frames = [k for k in frames if np.linalg.norm(script.tip(k / TRACKER_RATE_HZ) - trial.ppc[number]) < 1e-9]
        expected = _measured_tips(script, 0.25 / np.sqrt(2), TRACKER_RATE_HZ, frames).mean(axis=0)
        assert touch.frames == len(frames) == 16
        np.testing.assert_allclose(touch.position, expected, atol=1e-3)
    assert abs(result.live.tre_mm - result.reference.tre_mm) < 0.5
    # The recorded session replays through the server into the same touches and the same registration.
    from OpenIGTLinkBridgeLib.live_demo import replay_server
    from OpenIGTLinkBridgeLib.plus_sequence import read_sequence

    recording = read_sequence(path)
    assert recording.transform_names == ["ReferenceToTracker", "ProbeToTracker"] and len(recording.frames) >= 170
    # ramsicp collect on the project's own recording, with its defaults (the tool found in the file): the same
    # eight touches as the live collection (its 0.8 mm and 0.15 s against 1.5 mm and 0.2 s: the same frames).
    from OpenIGTLinkBridgeLib.recorded_touches import find_recorded_touches

    collected = find_recorded_touches(recording, tip_mm=PROBE_TIP_MM)
    assert collected.tool == "ProbeToTracker" and [t.kind for t in collected.touches] == ["hold"] * 8
    offline = np.array([touch.position for touch in collected.touches])
    assert np.abs(offline - result.collected).max() < 0.05
    replayed = run_live_demo(
        slicer.vtkMRMLScene(), tibia_patient, tibia_index, trial, server_factory=lambda: replay_server(path)
    )
    assert replayed.collected.tobytes() == result.collected.tobytes()
    assert [t.frames for t in replayed.touches] == [t.frames for t in result.touches]
    np.testing.assert_array_equal(replayed.live.reference_to_image, result.live.reference_to_image)
    assert replayed.live.tre_mm == result.live.tre_mm


def test_scikit_surgery_nditracker_reads_the_simulator_process(tmp_path):
    """The simulator must be its own process here: ndicapi's PVWR holds the GIL while it waits for replies."""
    import shutil
    import subprocess
    import sys

    pytest.importorskip("sksurgerynditracker", reason="scikit-surgerynditracker does not install here")
    if shutil.which("ping") is None:
        pytest.skip("scikit-surgerynditracker pings a network tracker first; install iputils-ping")
    from sksurgerynditracker.nditracker import NDITracker as SksTracker

    port = _free_port()
    process = subprocess.Popen(
        [sys.executable, "-m", "OpenIGTLinkBridgeLib.ndi_simulator", "--port", str(port)],
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert "listening" in process.stderr.readline()
        tracker = SksTracker(
            {
                "tracker type": "vega",
                "ip address": "127.0.0.1",
                "port": port,
                "romfiles": [str(tool_rom_path("8700339")), str(tool_rom_path("8700340"))],
            }
        )
        tracker.start_tracking()
        time.sleep(0.3)
        handles, _, frames, matrices, quality = tracker.get_frame()
        tracker.stop_tracking()
        tracker.close()
    finally:
        process.terminate()
        process.wait(timeout=10)
    assert list(handles) == [1, 2] and frames[0] > 0
    expected = np.eye(4)
    expected[:3, 3] = (0.0, 0.0, -1500.0)  # the simulator process's reference body
    np.testing.assert_allclose(matrices[0], expected, atol=1e-3)


def test_idle_server_uses_almost_no_cpu():
    """No tracker to talk to and no client: the server waits (select, back-off), it does not spin."""

    def unreachable():
        raise TrackerConnectionError("no tracker on this test bench")

    server = TrackerServer(unreachable, port=0).start()
    try:
        time.sleep(0.3)
        start_cpu, start = time.process_time(), time.monotonic()
        time.sleep(1.5)
        assert (time.process_time() - start_cpu) / (time.monotonic() - start) < 0.05
    finally:
        server.stop()


def test_tracker_server_command_streams_the_simulator(tmp_path):
    import subprocess
    import sys

    port = _free_port()
    process = subprocess.Popen(
        [sys.executable, "-m", "OpenIGTLinkBridgeLib.tracker_server", "--simulate", "--port", str(port)],
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 30
        while "serving OpenIGTLink" not in process.stderr.readline():
            assert time.monotonic() < deadline and process.poll() is None
        client = socket.create_connection(("127.0.0.1", port), timeout=5)
        data = b""
        while len(data) < 3 * (igtl.HEADER_SIZE + 48):
            data += client.recv(65536)
        client.close()
    finally:
        process.terminate()
        process.wait(timeout=10)
    devices = {message.device for message in igtl.decode_available(data)[0]}
    assert {"ProbeToTracker", "ReferenceToTracker"} <= devices


def test_driver_over_a_serial_line():
    """A pseudo-terminal stands in for the Polaris cable; a bridge carries its bytes to the simulator."""
    import os
    import tty

    simulator, script = demo_simulator(POINTS)
    simulator.start()
    master, slave = os.openpty()
    tty.setraw(slave)
    link = socket.create_connection(simulator.address[:2])
    stop = threading.Event()

    def bridge():
        link.settimeout(0.01)
        while not stop.is_set():
            try:
                data = os.read(master, 4096) if _readable(master) else b""
                if data:
                    link.sendall(data)
                os.write(master, link.recv(4096))
            except (TimeoutError, socket.timeout):
                continue
            except OSError:
                return

    thread = threading.Thread(target=bridge, daemon=True)
    thread.start()
    try:
        tracker = open_tracker(serial_device=os.ttyname(slave), timeout_s=2.0)
        time.sleep(0.4)
        poses, _ = tracker.poses()
        np.testing.assert_allclose(poses["Reference"].matrix(), script.reference_to_tracker, atol=1e-3)
        tracker.close()
    finally:
        stop.set()
        thread.join(timeout=2)
        link.close()
        os.close(master)
        os.close(slave)
        simulator.stop()


def _readable(fd):
    import select

    return bool(select.select([fd], [], [], 0.01)[0])
