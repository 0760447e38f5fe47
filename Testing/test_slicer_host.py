"""Real-time I/O as it behaves in Slicer's own process, where PythonQt keeps Python's lock while Qt's event loop
waits: Python threads advance only while the GUI thread runs Python.

The emulation (``hold_the_lock_between_polls``): the test's thread polls every 20 ms, as the OpenIGTLink Bridge
module's timer does, and waits between polls in a C call that keeps the lock (``usleep`` through
``ctypes.PyDLL``, which, unlike ``ctypes.CDLL``, does not release it). Under it a tracker server and simulator run
as threads of this process get 15 to 18 of their 60 frames a second into the scene; in a process of their own
(``tracker_process``, what the module starts) all of them arrive. What the modules still do in threads of
Slicer's process (looking up a host name) and what they do on the GUI thread (recording the feed) are checked
under the same loop.
"""

import ctypes
import socket
import subprocess
import sys
import time

import pytest

from conftest import headless_scene

slicer = pytest.importorskip("slicer", reason="slicer-core (real MRML) needs Python >= 3.10")
from OpenIGTLinkBridgeLib.bridge_controller import BridgeController  # noqa: E402
from OpenIGTLinkBridgeLib.plus_sequence import read_sequence  # noqa: E402
from OpenIGTLinkBridgeLib.receiver import TrackerReceiver  # noqa: E402
from OpenIGTLinkBridgeLib.robot_link import RobotLink  # noqa: E402
from OpenIGTLinkBridgeLib.tracker_process import TrackerProcess  # noqa: E402

#: The OpenIGTLink Bridge module's poll timer (OpenIGTLinkBridge.POLL_INTERVAL_MS).
POLL_INTERVAL_S = 0.020
#: Frames a second the simulated tracker measures and the server sends.
TRACKER_RATE_HZ = 60.0
MEASURED_S = 3.0


def hold_the_lock_between_polls(poll, seconds, interval_s=POLL_INTERVAL_S):
    """Call ``poll()`` every ``interval_s`` for ``seconds``, waiting in between in a C call that keeps Python's
    lock, as Slicer's GUI thread waits in Qt's event loop under PythonQt; returns the number of polls."""
    usleep = ctypes.PyDLL(None).usleep  # PyDLL: the lock stays held during the call
    usleep.argtypes = [ctypes.c_uint]
    polls, end = 0, time.monotonic() + seconds
    while time.monotonic() < end:
        usleep(int(interval_s * 1e6))
        poll()
        polls += 1
    return polls


def poll_until(poll, condition, seconds=30.0):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        poll()
        if condition():
            return True
        time.sleep(0.01)
    return False


def probe_valid(controller):
    return dict(controller.status().tools)["ProbeToTracker"] == "valid"


def poses_per_second_under_the_emulation(controller, recording):
    """Start recording, then poll under the emulation for ``MEASURED_S``: (new ProbeToReference poses in the
    scene per second, frames recorded per second)."""
    scene = controller.scene
    node = scene.GetFirstNodeByName("ProbeToReference")
    poses = []
    tag = node.AddObserver(node.TransformModifiedEvent, lambda caller, event: poses.append(time.monotonic()))
    controller.start_recording(recording)
    try:
        hold_the_lock_between_polls(controller.poll, MEASURED_S)
        frames = controller.receiver.recorder.frames
    finally:
        node.RemoveObserver(tag)
        controller.stop_recording()
    return len(poses) / MEASURED_S, frames / MEASURED_S


def test_the_tracker_in_its_own_process_feeds_the_scene_at_its_rate_while_the_gui_thread_holds_the_lock(tmp_path):
    """What 'start the tracker' does in the module: ramsicp-tracker-server in its own process (here run by this
    Python, in Slicer by PythonSlicer), connected to as to PLUS. Under the emulation at least 50 of its 60 poses a
    second reach the scene and the recording (60 measured here); its log is shown; stopping it ends it cleanly."""
    controller = BridgeController(headless_scene(), tracker_python=sys.executable, log_directory=tmp_path)
    controller.parameters.trackerSource = "simulator"
    try:
        assert controller.run("start_tracker", 0) is None and not controller.status().message_is_error
        port = controller.process_port
        assert controller.status().tracker == f"tracker running in process {controller.process.process.pid}, on " + (
            f"127.0.0.1:{port}"
        )
        assert poll_until(controller.poll, lambda: probe_valid(controller)), controller.status()
        poses, frames = poses_per_second_under_the_emulation(controller, tmp_path / "feed.igs.mha")
        assert poses >= 50.0, f"{poses:.1f} poses/s reached the scene"
        assert frames >= 50.0, f"{frames:.1f} frames/s were recorded"
        log = controller.status().tracker_log
        assert any(line.endswith(f"INFO serving OpenIGTLink on 127.0.0.1:{port}") for line in log), log
        process = controller.process
    finally:
        controller.close()
    assert process.exit_code == 0  # SIGTERM stops it as Ctrl-C does: tracker and clients closed
    recording = read_sequence(tmp_path / "feed.igs.mha")
    assert len(recording.frames) >= 50 * MEASURED_S and {"ProbeToTracker", "ReferenceToTracker"} <= set(
        recording.transform_names
    )


def test_the_emulation_starves_a_tracker_run_as_threads_of_this_process(tmp_path):
    """The control: the same simulator and server as threads of the polling process, the old 'start the tracker'
    inside Slicer. Few poses get through (15 to 18 a second measured here), which is why the module starts a
    process; this also shows that the emulation does hold the lock."""
    controller = BridgeController(headless_scene())
    controller.parameters.trackerSource = "simulator"
    try:
        controller.run("start_tracker", 0)
        assert poll_until(controller.poll, lambda: probe_valid(controller))
        poses, frames = poses_per_second_under_the_emulation(controller, tmp_path / "feed.igs.mha")
    finally:
        controller.close()
    assert poses < 40.0 and frames < 40.0, f"{poses:.1f} poses/s, {frames:.1f} frames/s"


def test_a_host_name_is_looked_up_while_the_gui_thread_holds_the_lock():
    """The receiver and the robot link look a host name up in a thread of Slicer's process: that thread needs the
    lock only to start and to hand over the address, so it finishes within a few polls under the emulation."""
    with socket.create_server(("127.0.0.1", 0)) as server:
        port = server.getsockname()[1]
        receiver = TrackerReceiver(headless_scene(), host="localhost", port=port)
        link = RobotLink("localhost", port, timeout_s=5.0)
        started = time.monotonic()
        hold_the_lock_between_polls(lambda: (receiver.poll(), link.poll()), 1.0)
        assert receiver.connected and link.connected, (receiver.resolution_error, link.status_text)
        assert time.monotonic() - started < 1.5
        receiver.close()
        link.close()


def test_a_tracker_process_that_dies_or_cannot_start_is_shown_with_why(tmp_path):
    controller = BridgeController(headless_scene(), tracker_python=sys.executable, log_directory=tmp_path)
    controller.parameters.trackerSource = "simulator"
    try:
        controller.run("start_tracker", 0)
        assert poll_until(controller.poll, lambda: probe_valid(controller))
        pid = controller.process.process.pid
        controller.process.process.kill()  # the server dies (a crash, the system killing it)
        controller.process.process.wait()
        tracker = controller.status().tracker
        assert tracker.startswith(f"tracker process {pid} ended (exit code -9): ") and "INFO" in tracker
    finally:
        controller.close()
    controller = BridgeController(headless_scene(), tracker_python=tmp_path / "no-python", log_directory=tmp_path)
    controller.parameters.trackerSource = "simulator"
    assert controller.run("start_tracker", 0) is None
    assert controller.status().message.startswith(f"cannot start the tracker server with {tmp_path / 'no-python'}")
    with socket.create_server(("127.0.0.1", 0)) as busy:  # a busy port is said at once, not in a log later
        port = busy.getsockname()[1]
        controller.run("start_tracker", port)
        assert controller.status().message.startswith(f"cannot serve OpenIGTLink on 127.0.0.1:{port} (")
        assert controller.process is None
    controller.close()


def test_a_server_with_bad_arguments_ends_and_its_log_says_why(tmp_path):
    process = TrackerProcess(sys.executable, ["--simulate", "--rate", "0"], tmp_path / "server.log").start()
    process.process.wait(30)
    assert process.exit_code == 2
    assert process.log_lines()[-1] == (
        "ramsicp-tracker-server: error: --rate 0: give a rate above 0 and at most 1000 per second"
    )


def test_the_tracker_process_ends_when_the_process_that_started_it_goes(tmp_path):
    """Slicer crashing must not leave a server holding the port and the tracker: the child watches its standard
    input, which closes when its parent is gone."""
    script = (
        "import signal, sys, time\n"
        "signal.signal(signal.SIGINT, signal.SIG_IGN)\n"  # a parent ignoring Ctrl-C passes that on through exec
        "from OpenIGTLinkBridgeLib.tracker_process import TrackerProcess\n"
        "process = TrackerProcess(sys.executable, ['--simulate', '--port', '0'], sys.argv[1]).start()\n"
        "print(process.process.pid, flush=True)\n"
        "time.sleep(60)\n"
    )
    parent = subprocess.Popen([sys.executable, "-c", script, str(tmp_path / "server.log")], stdout=subprocess.PIPE)
    child = int(parent.stdout.readline())
    assert poll_until(lambda: None, lambda: "serving OpenIGTLink" in (tmp_path / "server.log").read_text())
    parent.kill()  # no clean-up at all: the parent simply vanishes
    parent.wait()
    # It notices at once (its stdin reader sees end-of-file); the margin is for a loaded machine starting Python.
    assert poll_until(lambda: None, lambda: not _alive(child), seconds=30.0)
    assert "KeyboardInterrupt" not in (tmp_path / "server.log").read_text()  # it stopped as Ctrl-C stops it


def _alive(pid):
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().split()[2] != "Z"  # a zombie has ended, its parent gone
    except FileNotFoundError:
        return False
