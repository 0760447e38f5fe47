"""The tool path over a real socket to the robot simulator and back: every pose arrives, the robot's TCP follows
the planned polyline at the set speed, bad paths are refused with the reason, STOP and a lost connection stop
the robot, and the simulated tracker sees the tool where the robot moved it."""

import socket
import time

import numpy as np
import pytest

from OpenIGTLinkBridgeLib import igtl_messages as igtl
from OpenIGTLinkBridgeLib.robot_link import PATH_DEVICE, PathAssembler, PathError, RobotLink, encode_path
from OpenIGTLinkBridgeLib.robot_simulator import RobotSimulator
from RAMSICPRegistrationLib.core.transforms import make_transform, rotation_about_axis

TCP = np.array([0.5, -1.0, 180.0])
ORIENTATION = rotation_about_axis((1.0, 2.0, 0.5), 2.0)


def zigzag(passes=4, depth_mm=30.0, step_mm=2.0, spacing_mm=8.0, start=(400.0, -100.0, 250.0)):
    """A path of passes like a cut's: in along z' and back out, then across along x' (one orientation)."""
    poses = []
    for number in range(passes):
        depths = np.arange(0.0, depth_mm + 1e-9, step_mm)
        for depth in np.concatenate((depths, depths[-2::-1])):
            local = np.array([number * spacing_mm, 0.0, depth])
            poses.append(make_transform(ORIENTATION, np.asarray(start) + ORIENTATION @ local))
    return np.array(poses)


@pytest.fixture
def robot():
    simulator = RobotSimulator(
        speed_mm_s=50.0,
        rate_hz=100.0,
        tcp_in_flange=TCP,
        realtime=False,
        start_pose=make_transform(ORIENTATION, (400.0, -100.0, 240.0)),
    ).start()
    yield simulator
    simulator.stop()


def _distance_to_polyline(points, vertices):
    """Distance (mm) of each point (N, 3) to the polyline through ``vertices`` (M, 3)."""
    first, second = vertices[:-1], vertices[1:]
    direction = second - first
    length2 = np.maximum((direction**2).sum(axis=1), 1e-30)
    fraction = np.clip(np.einsum("nmk,mk->nm", points[:, None] - first[None], direction) / length2, 0.0, 1.0)
    nearest = first[None] + fraction[..., None] * direction[None]
    return np.linalg.norm(points[:, None] - nearest, axis=2).min(axis=1)


def test_the_robot_receives_the_whole_path_and_its_tcp_follows_it_at_the_set_speed(robot):
    path = zigzag()
    link = RobotLink(*robot.address[:2], keep_poses=True)
    path_id = link.send_path(path)
    assert link.wait_for(("DONE", "REFUSED"), 20.0) == "DONE", link.status_text
    received = robot.paths[-1]
    assert received.path_id == path_id and received.poses.shape == path.shape
    np.testing.assert_allclose(received.poses, path, atol=1e-4)  # float32 on the wire: 0.03 um at 500 mm
    reported = np.array(link.poses)
    approach = 10.0  # from the start pose to the path's first pose
    length = approach + np.linalg.norm(np.diff(path[:, :3, 3], axis=0), axis=1).sum()
    assert len(reported) == int(np.ceil(length / 0.5))  # 50 mm/s at 100 reports a second: 0.5 mm each
    on_path = reported[int(approach / 0.5) :, :3, 3]
    assert _distance_to_polyline(on_path, path[:, :3, 3]).max() < 1e-3  # the TCP stays on the planned polyline
    np.testing.assert_allclose(reported[:, :3, :3], np.broadcast_to(ORIENTATION, reported[:, :3, :3].shape), atol=1e-6)
    steps = np.linalg.norm(np.diff(reported[:, :3, 3], axis=0), axis=1)
    straight = steps[np.abs(steps - 0.5) < 0.01]
    assert len(straight) > 0.9 * len(steps)  # every step but the corners is exactly 0.5 mm
    np.testing.assert_allclose(reported[-1], path[-1], atol=1e-4)
    assert link.passed == len(path) and link.status_text == f"{len(path)} poses"
    moving = [text for name, text in link.statuses if name == "MOVING"]
    assert moving == [f"{number} of {len(path)}" for number in range(1, len(path) + 1)]  # each pose, once, in order
    assert link.statuses[0] == ("ACCEPTED", f"{len(path)} {path_id}") and link.statuses[-1][0] == "DONE"
    link.close()


def test_the_robot_reports_its_kinematics_while_the_real_tool_sits_where_its_true_tcp_is():
    true_tcp = TCP + (0.3, 0.0, -0.4)  # the TCP calibration is off by 0.5 mm
    simulator = RobotSimulator(tcp_in_flange=TCP, true_tcp_in_flange=true_tcp, speed_mm_s=100.0, realtime=False)
    simulator.start()
    try:
        link = RobotLink(*simulator.address[:2])
        link.send_path(zigzag(passes=1))
        assert link.wait_for(("DONE",), 20.0) == "DONE"
        reported, real = simulator.reported_pose(), simulator.tool_pose()
        np.testing.assert_allclose(reported, zigzag(passes=1)[-1], atol=1e-9)
        np.testing.assert_allclose(real[:3, 3] - reported[:3, 3], ORIENTATION @ (0.3, 0.0, -0.4), atol=1e-9)
        link.close()
    finally:
        simulator.stop()


@pytest.mark.parametrize(
    "change, reason",
    [
        (lambda poses: poses.__setitem__((3, slice(0, 3), slice(0, 3)), 1.1 * poses[3, :3, :3]), "pose 4 is not rigid"),
        (lambda poses: poses.__setitem__((5, slice(0, 3), 3), (2000.0, 0.0, 0.0)), "pose 6 puts the flange"),
    ],
)
def test_a_bad_path_is_refused_with_the_reason(robot, change, reason):
    path = zigzag(passes=1)
    change(path)
    link = RobotLink(*robot.address[:2])
    link.send_path(path)
    assert link.wait_for(("ACCEPTED", "REFUSED"), 5.0) == "REFUSED"
    assert reason.split(" is ")[0] in link.status_text and robot.paths == []
    link.close()


def test_a_broken_message_sequence_is_refused_and_a_good_path_then_accepted(robot):
    with socket.create_connection(robot.address[:2], timeout=5.0) as raw:
        raw.sendall(igtl.encode_transform(PATH_DEVICE, np.eye(4)))  # a pose without PATH_BEGIN
        reply = _read_status(raw)
        assert reply.error_name == "REFUSED" and "outside PATH_BEGIN" in reply.text
        first_poses = b"".join(igtl.encode_transform(PATH_DEVICE, pose) for pose in zigzag(passes=1)[:3])
        begin = igtl.encode_status(PATH_DEVICE, igtl.Status(1, 0, "PATH_BEGIN", "31 p1"))
        raw.sendall(begin + first_poses + encode_path(zigzag(passes=1), "p2"))  # p1 cut short, then p2 whole
        reply = _read_status(raw)
        assert reply.error_name == "REFUSED" and "PATH_BEGIN of a new path before PATH_END of path p1" in reply.text
    assert robot.paths == []


def _read_status(connection):
    buffer = b""
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        buffer += connection.recv(4096)
        messages, _ = igtl.decode_available(buffer)
        statuses = [message.content for message in messages if message.type == "STATUS"]
        if statuses:
            return statuses[0]
    raise AssertionError("no STATUS from the robot")


def test_the_path_assembler_checks_counts_and_ids():
    assembler = PathAssembler()
    messages, _ = igtl.decode_available(encode_path(zigzag(passes=1), "abc"))
    results = [assembler.add(message) for message in messages]
    assert results[-1].path_id == "abc" and len(results[-1].poses) == len(messages) - 2
    begin, *_ = igtl.decode_available(encode_path(np.tile(np.eye(4), (3, 1, 1)), "x"))[0]
    assembler.add(begin)
    end = igtl.decode_available(igtl.encode_status(PATH_DEVICE, igtl.Status(1, 0, "PATH_END", "3 x")))[0][0]
    with pytest.raises(PathError, match="PATH_BEGIN announced 3 poses, 0 arrived"):
        assembler.add(end)
    with pytest.raises(ValueError, match="path id 'two words'"):
        encode_path(np.eye(4)[None], "two words")


def test_stop_and_a_lost_connection_stop_the_robot():
    path = zigzag(passes=2)
    simulator = RobotSimulator(speed_mm_s=40.0, rate_hz=50.0, start_pose=path[0], realtime=True).start()
    try:
        link = RobotLink(*simulator.address[:2])
        link.send_path(path)
        assert link.wait_for(("MOVING",), 5.0) == "MOVING"
        link.stop()
        assert link.wait_for(("STOPPED",), 5.0) == "STOPPED" and simulator.state == "STOPPED"
        where = simulator.tool_pose()
        time.sleep(0.2)
        np.testing.assert_array_equal(simulator.tool_pose(), where)  # it stays where it stopped
        link.send_path(path)  # a new path after a stop is accepted
        assert link.wait_for(("MOVING",), 5.0) == "MOVING"
        link.close()  # the navigation goes away
        deadline = time.monotonic() + 5.0
        while simulator.state != "STOPPED" and time.monotonic() < deadline:
            time.sleep(0.02)
        assert simulator.state == "STOPPED"
    finally:
        simulator.stop()


def closed_port():
    """A loopback port bound but not listening: nothing answers there (a connection is refused at once)."""
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    return probe


def silent_server():
    """A loopback server that accepts connections (the system completes them in its backlog) and never answers:
    a robot controller that hangs."""
    return socket.create_server(("127.0.0.1", 0))


def timed(costs, call, *args):
    """``call(*args)``, its cost (s, ``time.perf_counter``) appended to ``costs``."""
    start = time.perf_counter()
    try:
        return call(*args)
    finally:
        costs.append(time.perf_counter() - start)


def test_an_unreachable_robot_is_one_clear_state_and_no_call_waits():
    """A refused connection and a robot that takes the path but never answers: each call returns at once (what
    is measured is how long the calls themselves take, which does not depend on the machine's load: nothing in
    them waits), and a refusal is one clear line."""
    costs = []
    with closed_port() as closed:
        port = closed.getsockname()[1]
        link = timed(costs, RobotLink, "127.0.0.1", port)
        for _ in range(5):
            timed(costs, link.poll)
        assert link.state == "DISCONNECTED" and not link.is_open
        assert link.status_text.startswith(f"the robot controller at 127.0.0.1:{port} cannot be reached")
        with pytest.raises(OSError, match="is closed"):
            link.send_path(zigzag(passes=1))
    with silent_server() as silent:
        link = timed(costs, RobotLink, *silent.getsockname()[:2], 0.3)
        timed(costs, link.send_path, zigzag(passes=8))
        deadline = time.monotonic() + 0.5
        while time.monotonic() < deadline:
            timed(costs, link.poll)
            time.sleep(0.01)
        assert link.connected and link.state == "SENT" and not link.outbox  # the path went out; no answer came
        timed(costs, link.stop)
        timed(costs, link.close)
    assert max(costs) < 0.05, f"slowest call {1000 * max(costs):.1f} ms"


@pytest.fixture
def hanging_listener():
    """A loopback listener whose backlog is full and which never accepts: a connection attempt to it hangs (the
    system drops its SYN), as to a robot controller behind a dead network link."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(0)
    fillers = []
    for _ in range(8):  # a few connections fill a backlog of 0 on loopback
        filler = socket.socket()
        filler.setblocking(False)
        filler.connect_ex(server.getsockname())
        fillers.append(filler)
    yield server.getsockname()[:2]
    for filler in fillers:
        filler.close()
    server.close()


def test_a_connection_that_never_completes_fails_after_the_timeout_without_waiting(hanging_listener):
    costs = []
    link = timed(costs, RobotLink, *hanging_listener, 0.3)
    while link.is_open and len(costs) < 200:
        timed(costs, link.poll)
        time.sleep(0.01)
    assert not link.connected and link.state == "DISCONNECTED"
    host, port = hanging_listener
    assert link.status_text == (
        f"the robot controller at {host}:{port} cannot be reached (no connection within 0.3 s); start its "
        "OpenIGTLink server or check the address"
    )
    assert max(costs) < 0.05, f"slowest call {1000 * max(costs):.1f} ms"


def test_a_stop_before_the_path_is_written_cancels_it(hanging_listener):
    """A path queued while the connection is still being made is dropped by a stop, never sent later."""
    link = RobotLink(*hanging_listener, 5.0)
    link.send_path(zigzag(passes=1))
    assert link.state == "SENT" and link.outbox  # queued: the connection is not made yet
    link.stop()
    assert link.state == "DISCONNECTED" and not link.outbox
    assert link.status_text == "stopped before the whole path was sent; the connection was closed"


def test_the_tracker_sees_the_tool_where_the_robot_moved_it(robot):
    """Robot simulator -> Vega simulator (NDI 8700449 on the tool) -> our NDI driver: ToolToTracker is
    RobotBaseToTracker @ the real flange @ MarkerToFlange, to the TX reply's resolution."""
    from OpenIGTLinkBridgeLib.live_scenario import cutting_simulator
    from OpenIGTLinkBridgeLib.ndi_driver import open_tracker
    from RAMSICPRegistrationLib.io.ndi_tools import tool_rom_path

    base_to_tracker = make_transform(rotation_about_axis((0, 1, 0), 1.2), (-300.0, 50.0, -1400.0))
    marker_to_flange = make_transform(rotation_about_axis((0, 0, 1), 0.5), (60.0, 0.0, 90.0))
    vega = cutting_simulator(robot, base_to_tracker, marker_to_flange).start()
    try:
        tracker = open_tracker(
            *vega.address[:2], roms={"Reference": tool_rom_path("8700339"), "Tool": tool_rom_path("8700449")}
        )
        link = RobotLink(*robot.address[:2])
        link.send_path(zigzag(passes=1))
        assert link.wait_for(("DONE",), 20.0) == "DONE"
        poses, _ = tracker.poses()
        expected = base_to_tracker @ robot.flange_pose() @ marker_to_flange
        np.testing.assert_allclose(poses["Tool"].matrix()[:3, 3], expected[:3, 3], atol=0.01)
        np.testing.assert_allclose(poses["Tool"].matrix()[:3, :3], expected[:3, :3], atol=2e-4)
        tracker.close()
        link.close()
    finally:
        vega.stop()
