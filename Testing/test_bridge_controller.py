"""The OpenIGTLinkBridge module's controller: a tracker started from Slicer, the feed into a real scene, mistakes.

Real parts only: the Vega simulator speaks NDI's protocol over TCP, our server speaks OpenIGTLink, the receiver
writes a slicer-core scene. The known answers are the simulator's scripted poses.
"""

import socket
import time

import numpy as np
import pytest

from conftest import headless_scene

slicer = pytest.importorskip("slicer", reason="slicer-core (real MRML) needs Python >= 3.10")
from OpenIGTLinkBridgeLib.bridge_controller import BridgeController  # noqa: E402
from OpenIGTLinkBridgeLib.live_scenario import DEFAULT_REFERENCE_TO_TRACKER  # noqa: E402
from OpenIGTLinkBridgeLib.ndi_driver import parse_ndi_address  # noqa: E402
from RAMSICPRegistrationLib.navigation.navigation import matrix_of  # noqa: E402


def poll_until(controller, condition, seconds=5.0):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        controller.poll()
        if condition():
            return True
        time.sleep(0.01)
    return False


def tool_states(controller):
    return dict(controller.status().tools)


@pytest.fixture
def free_port():
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def test_start_the_simulated_tracker_from_the_module_and_receive_its_poses(free_port):
    scene = headless_scene()
    controller = BridgeController(scene)
    controller.parameters.trackerSource = "simulator"
    controller.parameters.port = free_port
    try:
        assert controller.run("start_tracker") is None and not controller.status().message_is_error
        assert poll_until(controller, lambda: tool_states(controller)["ReferenceToTracker"] == "valid")
        assert controller.status().connection == f"connected to 127.0.0.1:{free_port}"
        reference = scene.GetFirstNodeByName("ReferenceToTracker")
        np.testing.assert_allclose(matrix_of(reference), DEFAULT_REFERENCE_TO_TRACKER, atol=1e-4)  # float32 wire
        assert controller.parameters.host == "127.0.0.1" and controller.parameters.port == free_port
        scene.Clear(0)  # the nodes go; the feed comes back into the new scene by itself
        assert poll_until(controller, lambda: scene.GetFirstNodeByName("ReferenceToTracker") is not None)
        assert controller.parameters.port == free_port  # restored after the close reset the parameter node
    finally:
        controller.close()
    assert tool_states(controller) == {"ReferenceToTracker": "disconnected", "ProbeToTracker": "disconnected"}


def test_a_busy_port_and_bad_addresses_are_messages(free_port):
    controller = BridgeController(headless_scene())
    with socket.create_server(("127.0.0.1", free_port)):
        controller.parameters.trackerSource = "simulator"
        controller.parameters.port = free_port
        assert controller.run("start_tracker") is None
        status = controller.status()
        assert status.message_is_error and f"cannot serve OpenIGTLink on 127.0.0.1:{free_port}" in status.message
        assert "choose another port" in status.message and controller.simulator is None
    controller.parameters.trackerSource = "ndi-network"
    controller.parameters.trackerAddress = "10.0.0.5:abc"
    controller.run("start_tracker")
    assert "10.0.0.5:abc: the port after ':' must be a number from 1 to 65535" in controller.status().message
    controller.parameters.trackerSource = "ndi-serial"
    controller.parameters.trackerAddress = " "
    controller.run("start_tracker")
    assert controller.status().message == "give the Polaris's serial device, e.g. /dev/ttyUSB0 or COM3"
    controller.close()


def test_parse_ndi_address():
    assert parse_ndi_address("vega.local") == ("vega.local", 8765)
    assert parse_ndi_address("169.254.9.239:8766") == ("169.254.9.239", 8766)
    for bad in ("", ":8765", "host:0", "host:70000"):
        with pytest.raises(ValueError):
            parse_ndi_address(bad)


def test_a_host_name_is_resolved_off_the_calling_thread(monkeypatch):
    """Name resolution can take seconds: polling (Slicer's GUI thread) must never wait for it."""
    import threading

    release = threading.Event()
    resolving_threads = []

    def slow_lookup(host):
        resolving_threads.append(threading.current_thread())
        release.wait(10)
        raise socket.gaierror(-2, "Name or service not known")

    monkeypatch.setattr(socket, "gethostbyname", slow_lookup)
    controller = BridgeController(headless_scene())
    controller.run("connect", "tracker.example", 18944)
    for _ in range(20):
        controller.poll()  # returns at once although the lookup has not answered
    assert controller.status().connection == "connecting to tracker.example:18944 ..."
    assert resolving_threads and threading.current_thread() not in resolving_threads
    release.set()
    assert poll_until(
        controller, lambda: "cannot resolve the host name 'tracker.example'" in (controller.status().connection)
    )
    controller.close()


def test_record_the_feed_from_the_module_and_read_it_back(free_port, tmp_path):
    from OpenIGTLinkBridgeLib.plus_sequence import read_sequence

    scene = headless_scene()
    controller = BridgeController(scene)
    controller.parameters.trackerSource = "simulator"
    controller.parameters.port = free_port
    path = tmp_path / "session.igs.mha"
    try:
        assert controller.run("start_recording", path) is None
        assert (
            controller.status().message
            == "connect to a tracker first: the recording holds what the connection receives"
        )
        controller.run("start_tracker")
        assert poll_until(controller, lambda: tool_states(controller)["ReferenceToTracker"] == "valid")
        controller.run("start_recording", path)
        assert poll_until(
            controller,
            lambda: (
                "recording: " in controller.status().recording and int(controller.status().recording.split()[1]) >= 20
            ),
        )
        assert controller.run("stop_recording") == path
        assert controller.status().message.startswith("recorded ") and controller.status().recording == ""
    finally:
        controller.close()
    recording = read_sequence(path)
    assert {"ReferenceToTracker", "ProbeToTracker"} <= set(recording.transform_names) and len(recording.frames) >= 20
    matrices, valid = recording.matrices("ReferenceToTracker")
    assert valid.all()
    np.testing.assert_allclose(matrices[-1], DEFAULT_REFERENCE_TO_TRACKER, atol=1e-4)  # float32 on the wire
