"""Plan and cut through the controller, as the Slicer module and the browser view drive it: a markups plane on an
analytic cylinder (the answers by hand), the tracked cutting tool moved by writing matrices into transform nodes,
and the tool path sent over a real socket to the robot simulator."""

import json
import socket
import time

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.tool_path import tool_orientation
from RAMSICPRegistrationLib.core.transforms import apply_transform, invert_transform, make_transform
from RAMSICPRegistrationLib.core.transforms import rotation_about_axis as turn

from conftest import CYLINDER_RADIUS_MM as R
from conftest import cylinder_mesh, headless_scene, random_transform

slicer = pytest.importorskip("slicer", reason="slicer-core (real MRML) needs Python >= 3.10")
from OpenIGTLinkBridgeLib.robot_link import RobotLink  # noqa: E402
from OpenIGTLinkBridgeLib.robot_simulator import RobotSimulator  # noqa: E402
from RAMSICPRegistrationLib.navigation import mrml_nodes  # noqa: E402
from RAMSICPRegistrationLib.navigation.controller import NavigationController  # noqa: E402
from RAMSICPRegistrationLib.navigation.navigation import matrix_of, set_matrix  # noqa: E402

TOOL_TIP = make_transform(turn((0, 0, 1), 0.4), (20.0, -35.0, 160.0))  # the TCP in the tool's marker frame


@pytest.fixture
def clock():
    return {"s": 0.0}


@pytest.fixture
def planned(clock):
    """A controller with the cylinder as its IPC, a plane at z = 50 (y axis: the blade advances +y), the cut
    planned, and the tracker's nodes in place; ``tracker(tool_tip_to_image)`` streams one frame."""
    scene = headless_scene()
    controller = NavigationController(scene, clock=lambda: clock["s"], robot_link_factory=RobotLink)
    parameters = controller.parameters
    vertices, triangles = cylinder_mesh()
    parameters.ipcModel = mrml_nodes.model_node(scene, vertices, triangles)
    plane = scene.AddNewNodeByClass("vtkMRMLMarkupsPlaneNode", "OsteotomyPlane")
    plane.SetOriginWorld([0.0, 0.0, 50.0])
    plane.SetAxesWorld([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0])
    parameters.osteotomyPlane = plane
    assert controller.availability()["send_tool_path"] == "plan the cut first"
    cut = controller.run("plan_cut")
    rng = np.random.default_rng(7)
    reference_to_image, reference_to_tracker = random_transform(rng, 180, 300), random_transform(rng, 180, 1500)
    nodes = {}
    for name, matrix in (("ReferenceToImage", reference_to_image), ("ToolTipToTool", TOOL_TIP)):
        nodes[name] = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", name)
        set_matrix(nodes[name], matrix)
    for name in ("ReferenceToTracker", "ToolToTracker"):
        nodes[name] = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", name)
    parameters.referenceToImage, parameters.toolTipToTool = nodes["ReferenceToImage"], nodes["ToolTipToTool"]
    parameters.referenceToTracker, parameters.toolToTracker = nodes["ReferenceToTracker"], nodes["ToolToTracker"]

    def tracker(tool_tip_to_image):
        """One tracker frame: both tools, the tool placed so that its TCP is at ``tool_tip_to_image``."""
        tool_to_reference = invert_transform(reference_to_image) @ tool_tip_to_image @ invert_transform(TOOL_TIP)
        set_matrix(nodes["ReferenceToTracker"], reference_to_tracker)
        set_matrix(nodes["ToolToTracker"], reference_to_tracker @ tool_to_reference)

    yield controller, cut, tracker
    controller.close()


def test_planning_on_the_selected_plane_writes_the_endpoints_the_path_and_the_targets(planned):
    controller, cut, _ = planned
    parameters = controller.parameters
    expected = [(R, 0, 50), (-R, 0, 50), (0, R, 50), (0, -R, 50)]  # across +x, depth +y: the cylinder's ends
    np.testing.assert_allclose(cut.endpoints, expected, atol=1e-9)
    endpoints = parameters.cutEndpoints
    np.testing.assert_allclose(mrml_nodes.fiducial_positions(endpoints), expected, atol=1e-9)
    assert [endpoints.GetNthControlPointLabel(i) for i in range(4)] == ["E1", "E2", "E3", "E4"]
    assert parameters.targetsImage is endpoints  # the paper's targets for the verification TRE
    path_points = parameters.toolPath.GetPolyData().GetNumberOfPoints()
    assert path_points == len(cut.path.poses) and parameters.toolPath.GetPolyData().GetNumberOfLines() == 1
    assert parameters.osteotomyPlane.GetSize() == pytest.approx((2 * R, 2 * (R + 5.0)), abs=1e-6)
    status = controller.status()
    assert status.cut.startswith("plan: one cut, endpoints E1-E4; saw path") and f"{len(cut.path.poses)} poses" in (
        status.cut
    )
    parameters.osteotomyPlane.SetOriginWorld([0.0, 0.0, 52.0])  # the surgeon moves the plane
    assert controller.availability()["save_plan"].startswith("the plane or a setting of the cut changed")
    assert controller.status().cut.startswith("OUT OF DATE, plan again")
    controller.run("plan_cut")
    assert controller.availability()["save_plan"] is None
    np.testing.assert_allclose(mrml_nodes.fiducial_positions(endpoints)[:, 2], 52.0, atol=1e-9)


def test_a_wedge_angle_adds_the_second_cut_and_removing_it_removes_it(planned):
    controller, _, _ = planned
    parameters = controller.parameters
    parameters.wedgeAngleDeg = 10.0
    cut = controller.run("plan_cut")
    wedge = parameters.wedgePlane
    normal = [0.0] * 3
    wedge.GetNormalWorld(normal)
    assert np.degrees(np.arccos(np.dot(normal, (0.0, 0.0, 1.0)))) == pytest.approx(10.0)
    labels = [parameters.cutEndpoints.GetNthControlPointLabel(i) for i in range(8)]
    assert labels == ["E1", "E2", "E3", "E4", "W1", "W2", "W3", "W4"] and set(cut.path.cut_index) == {0, 1}
    assert "a 10 degree wedge of two cuts" in controller.status().cut
    parameters.wedgeAngleDeg = 0.0
    controller.run("plan_cut")
    assert parameters.wedgePlane is None and parameters.cutEndpoints.GetNumberOfControlPoints() == 4


def test_live_guidance_for_known_tool_poses_from_the_tracker_nodes(planned, clock):
    controller, cut, tracker = planned
    plan = cut.plans[0]
    on_plan = make_transform(tool_orientation(plan), (0.0, -5.0, 50.0))
    assert controller.status().guidance is None  # the tool has not been seen yet
    tracker(on_plan)
    guidance = controller.status().guidance
    assert guidance.on_plan and abs(guidance.distance_mm) < 1e-9 and guidance.angle_deg < 1e-5
    assert guidance.depth_to_far_cortex_mm == pytest.approx(np.sqrt(R**2 - 25.0) + 5.0, abs=2e-4)
    tracker(make_transform(tool_orientation(plan), (0.0, -5.0, 51.0)))  # 1 mm off, on the normal's side
    assert controller.status().guidance.distance_mm == pytest.approx(1.0, abs=1e-9)
    tilted = make_transform(turn((1, 0, 0), np.radians(5.0)) @ tool_orientation(plan), (0.0, -5.0, 50.0))
    tracker(tilted)  # 5 degrees about the blade's width
    guidance = controller.status().guidance
    assert guidance.angle_deg == pytest.approx(5.0, abs=1e-6) and not guidance.on_plan and "OFF PLAN" in guidance.text
    controller.parameters.guidanceAngleDeg = 6.0  # the surgeon's tolerance
    assert controller.status().guidance.on_plan
    clock["s"] += 1.5  # the tracker falls silent: no guidance from a stale pose
    assert controller.status().guidance is None


def _calibrate_robot(controller, image_to_base):
    """Eq. 3 through the controller: three calibrator positions seen by the robot and the tracker."""
    parameters = controller.parameters
    scene = controller.scene
    reference_to_tracker = matrix_of(parameters.referenceToTracker)
    reference_to_image = matrix_of(parameters.referenceToImage)
    base_to_tracker = reference_to_tracker @ invert_transform(reference_to_image) @ invert_transform(image_to_base)
    robot_points = np.array([[300.0, 0.0, 200.0], [380.0, 30.0, 200.0], [320.0, 90.0, 240.0]])
    parameters.robotPositions = mrml_nodes.fiducial_node(scene, robot_points, name="RobotPositions")
    tracker_points = apply_transform(base_to_tracker, robot_points)
    parameters.trackerPositions = mrml_nodes.fiducial_node(scene, tracker_points, name="TrackerPositions")
    controller.run("robot_calibration")
    np.testing.assert_allclose(matrix_of(parameters.imageToRobotBase), image_to_base, atol=1e-9)


def service_until(controller, condition, seconds=10.0, interval_s=0.02):
    """Call ``controller.service()`` as a shell's timer does until ``condition()``; True when it came true."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        controller.service()
        if condition():
            return True
        time.sleep(interval_s)
    return False


def test_the_path_goes_to_the_robot_in_robot_base_coordinates_and_the_robot_reports_back(planned):
    controller, cut, tracker = planned
    tracker(make_transform(tool_orientation(cut.plans[0]), (0.0, -30.0, 50.0)))
    image_to_base = make_transform(turn((0.3, 1.0, 0.2), 2.5), (450.0, -80.0, 120.0))
    assert controller.availability()["send_tool_path"].startswith("calibrate the robot first")
    _calibrate_robot(controller, image_to_base)
    robot = RobotSimulator(speed_mm_s=4000.0, rate_hz=200.0, realtime=False).start()
    try:
        controller.parameters.robotPort = robot.address[1]
        messages = []
        controller.add_listener(lambda event, data: messages.append(data[0]) if event == "message" else None)
        sent = controller.run("send_tool_path")
        assert sent is not None, controller.status().message
        assert messages[0].startswith(
            f"path sent to the robot at 127.0.0.1:{robot.address[1]}: {len(cut.path.poses)} poses"
        )
        assert service_until(controller, lambda: "accepted the path" in controller.status().message)
        assert messages[-1].startswith(
            f"the robot at 127.0.0.1:{robot.address[1]} accepted the path ({len(cut.path.poses)} poses)"
        )
        np.testing.assert_allclose(robot.paths[-1].poses, image_to_base @ cut.path.poses, atol=2e-4)
        assert service_until(controller, lambda: controller.status().robot.endswith("done: the whole path was run"))
        status = controller.status()
        assert status.robot_progress == (len(cut.path.poses), len(cut.path.poses)), status.robot
        np.testing.assert_allclose(robot.reported_pose(), image_to_base @ cut.path.poses[-1], atol=1e-9)
    finally:
        controller.close()
        robot.stop()


def test_a_refusal_an_unreachable_robot_and_a_closed_scene_are_handled(planned):
    controller, _, _ = planned
    _calibrate_robot(controller, make_transform(np.eye(3), (400.0, 0.0, 0.0)))
    small = RobotSimulator(reach_mm=100.0, realtime=False).start()
    try:
        controller.parameters.robotPort = small.address[1]
        assert controller.run("send_tool_path") is not None  # sent; the answer comes later
        assert service_until(controller, lambda: controller.status().message_is_error)
        assert controller.status().message.startswith("the robot refused the path: path ")
        assert "out of its 100 mm reach" in controller.status().message
    finally:
        small.stop()
    controller.robot.close()
    assert controller.run("send_tool_path") is None  # nothing listens there now: refused at once
    assert "cannot be reached (Connection refused)" in controller.status().message
    slow = RobotSimulator(speed_mm_s=5.0, reach_mm=2000.0).start()
    try:
        controller.parameters.robotPort = slow.address[1]
        controller.run("send_tool_path")
        assert service_until(controller, lambda: slow.state == "MOVING")
        assert (
            controller.availability()["send_tool_path"] == "the robot is still on the last path; wait for it or stop it"
        )
        controller.scene.Clear(0)  # the scene closes: the navigation must not leave the robot moving
        for _ in range(100):
            if slow.state == "STOPPED":
                break
            time.sleep(0.02)
        assert slow.state == "STOPPED" and controller.robot is None
    finally:
        slow.stop()


#: How often the Slicer module's logic services the robot link (``RAMSICPRegistration.ROBOT_SERVICE_INTERVAL_MS``).
LOGIC_TIMER_S = 0.05


def test_the_robot_keeps_cutting_while_the_module_is_hidden(planned):
    """The surgeon sends the path and switches module: the widget's refresh timer (``status()``) stops, only the
    logic's timer runs ``service()``. The robot, which drops a client that stops reading, runs the whole path, and
    the navigation knows it."""
    controller, cut, _ = planned
    _calibrate_robot(controller, make_transform(np.eye(3), (400.0, 0.0, 0.0)))
    robot = RobotSimulator(speed_mm_s=200.0, rate_hz=125.0, reach_mm=2000.0, realtime=True).start()
    try:
        controller.parameters.robotPort = robot.address[1]
        assert controller.run("send_tool_path") is not None
        length = cut.path.length_mm
        started = time.monotonic()
        assert service_until(controller, lambda: robot.state == "DONE", seconds=10 + length / 200.0, interval_s=0.05)
        assert time.monotonic() - started > length / 200.0 * 0.9  # it really ran in real time, over several seconds
        controller.service()
        assert controller.robot.state == "DONE" and controller.robot.passed == len(cut.path.poses)
        assert controller.status().robot.endswith("done: the whole path was run")
        assert controller.robot.reports >= 0.9 * 125.0 * length / 200.0  # every report was read while hidden
    finally:
        controller.close()
        robot.stop()


def _silent_robot():
    return socket.create_server(("127.0.0.1", 0))  # accepts (in its backlog), never answers


def _refusing_port():
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))  # bound, not listening: a connection is refused
    return probe


@pytest.mark.parametrize("robot", [_silent_robot, _refusing_port], ids=["silent", "closed"])
def test_a_robot_that_does_not_answer_costs_the_caller_under_50_ms(planned, robot):
    """Every call the GUI thread makes (sending the path, servicing the link until the answer's timeout, the
    status) returns in under 50 ms: measured with ``time.perf_counter`` around each call, which nothing in them
    waits for, so the figure does not depend on the machine's load. The old link waited up to 2 s to connect and
    another 2 s for the answer, in the click."""
    controller, _, _ = planned
    _calibrate_robot(controller, make_transform(np.eye(3), (400.0, 0.0, 0.0)))
    costs = []

    def timed(call, *args):
        start = time.perf_counter()
        result = call(*args)
        costs.append(time.perf_counter() - start)
        return result

    with robot() as server:
        controller.parameters.robotPort = server.getsockname()[1]
        sent = timed(controller.run, "send_tool_path", 0.5)
        assert (sent is None) == (robot is _refusing_port)  # a refusal is known at once, silence only later
        deadline = time.monotonic() + 2.0
        while not controller.status().message_is_error and time.monotonic() < deadline:
            timed(controller.service)
            timed(controller.status)
            time.sleep(0.02)
        for _ in range(10):  # and after the answer, as the timer goes on
            timed(controller.service)
            timed(controller.status)
    message = controller.status().message
    if robot is _silent_robot:
        assert message.startswith("the robot at 127.0.0.1:") and "did not accept the path within 0.5 s" in message
        assert controller.robot is None  # the link was closed
    else:
        assert "cannot be reached (Connection refused)" in message
    assert len(costs) > 10 and max(costs) < 0.05, f"slowest call {1000 * max(costs):.1f} ms"


def test_the_plan_is_saved_as_json_with_the_robot_base_coordinates(planned, tmp_path):
    controller, cut, _ = planned
    path = controller.run("save_plan", tmp_path / "plan.json")
    document = json.loads(path.read_text())
    assert {"plane", "endpoints", "tool_path"} <= set(document) and "robot_base" not in document
    np.testing.assert_allclose(document["endpoints"], cut.endpoints)
    image_to_base = make_transform(np.eye(3), (400.0, 0.0, 0.0))
    _calibrate_robot(controller, image_to_base)
    document = json.loads(controller.run("save_plan", tmp_path / "plan.json").read_text())
    np.testing.assert_allclose(document["robot_base"]["tool_path"], image_to_base @ cut.path.poses, atol=1e-9)
    assert controller.run("save_plan", tmp_path) is None and "is a folder" in controller.status().message


def test_the_predicted_registration_error_is_shown_at_the_endpoints(tibia_patient):
    """On the demo tibia: a plane at the cut height (across medial, the blade advancing anterior) has the demo's
    targets as its endpoints, and after a cr-fused registration the plan shows its predicted error there."""
    scene = headless_scene()
    controller = NavigationController(scene)
    parameters = controller.parameters
    trial = tibia_patient.simulate_trial(np.random.default_rng(4), marker_fle_mm=0.3, probe_noise_mm=0.2)
    parameters.ipcModel = mrml_nodes.model_node(scene, tibia_patient.ipc)
    parameters.markersImage = mrml_nodes.fiducial_node(scene, trial.markers_image)
    parameters.markersPatient = mrml_nodes.fiducial_node(scene, trial.markers_patient)
    parameters.probePoints = mrml_nodes.fiducial_node(scene, trial.ppc, name="ProbePoints")
    result = controller.run("register")
    plane = scene.AddNewNodeByClass("vtkMRMLMarkupsPlaneNode", "OsteotomyPlane")
    plane.SetOriginWorld([0.0, 0.0, tibia_patient.cut_height_mm])
    plane.SetAxesWorld([-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0])
    parameters.osteotomyPlane = plane
    cut = controller.run("plan_cut")
    np.testing.assert_array_equal(cut.endpoints, tibia_patient.targets_image)
    predicted = result.predicted_error_mm(tibia_patient.targets_image)
    assert f"predicted registration error at the endpoints {predicted.min():.2f}-{predicted.max():.2f} mm" in (
        controller.status().cut
    )
    controller.close()


def test_a_plane_not_placed_yet_is_a_message(planned):
    controller, _, _ = planned
    empty = controller.scene.AddNewNodeByClass("vtkMRMLMarkupsPlaneNode", "NotPlaced")
    controller.parameters.osteotomyPlane = empty
    assert controller.run("plan_cut") is None
    message = "osteotomy plane 'NotPlaced' is not placed yet; place it on the bone in the CT"
    assert controller.status().message == message
    assert controller.availability()["send_tool_path"].startswith("the plane or a setting of the cut changed")
