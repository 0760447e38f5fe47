"""The Qt-free controller behind the Slicer widget and the browser view, driven as a tracker drives it.

Every test moves the probe only by writing matrices into transform nodes of a real slicer-core scene (what our
receiver and SlicerOpenIGTLink do) and presses only what the GUI offers (``controller.run``). Known answers: a tip
offset built by hand, points on a straight path at a set spacing, distances computable by hand.
"""

import json

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.transforms import (
    apply_transform,
    invert_transform,
    make_transform,
    rotation_about_axis,
)

from conftest import headless_scene

slicer = pytest.importorskip("slicer", reason="slicer-core (real MRML) needs Python >= 3.10")
from RAMSICPRegistrationLib.navigation import mrml_nodes  # noqa: E402
from RAMSICPRegistrationLib.navigation.controller import ACTIONS, NavigationController, WorkflowError  # noqa: E402
from RAMSICPRegistrationLib.navigation.navigation import matrix_of, set_matrix  # noqa: E402
from RAMSICPRegistrationLib.navigation.parameters import MODULE_NAME, PARAMETERS  # noqa: E402

TIP = np.array([1.5, -2.0, 152.0])  # the probe's tip in its own frame (mm), not on an axis on purpose


def observer_count(node):
    """Every observer on a VTK object, counted through its observer tags."""
    return sum(node.GetCommand(tag) is not None for tag in range(1, 2000))


@pytest.fixture
def scene():
    return headless_scene()


class ManualClock:
    """The controller's clock, advanced only by the test: tracking ages do not depend on how loaded the machine is
    (a registration that took 1.02 s on a loaded machine made the probe stale behind a real clock)."""

    def __init__(self):
        self.now_s = 1000.0

    def __call__(self):
        return self.now_s

    def advance(self, seconds):
        self.now_s += seconds


@pytest.fixture
def tracked(scene, tmp_path):
    """A controller with a tracked probe selected, a calibrated tip and autosave into ``tmp_path``; its clock is a
    ``ManualClock`` (``controller.clock``) that only the test advances."""
    controller = NavigationController(scene, autosave_directory=tmp_path, clock=ManualClock())
    probe = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ProbeToReference")
    tip = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ProbeTipToProbe")
    set_matrix(tip, make_transform(translation=TIP))
    controller.parameters.probeToReference = probe
    controller.parameters.probeTipToProbe = tip
    yield controller, probe
    controller.close()


def pose_with_tip_at(point, rotation=None):
    """A ProbeToReference pose that puts the tip (TIP in the probe frame) on ``point``."""
    rotation = np.eye(3) if rotation is None else rotation
    return make_transform(rotation, np.asarray(point, dtype=np.float64) - rotation @ TIP)


def test_parameter_node_is_the_modules_singleton_and_survives_nothing_else(scene):
    controller = NavigationController(scene)
    node = controller.parameters.node
    assert node.GetSingletonTag() == MODULE_NAME and node.GetAttribute("ModuleName") == MODULE_NAME
    assert scene.GetSingletonNode(MODULE_NAME, "vtkMRMLScriptedModuleNode") is node
    assert controller.parameters.thresholdHU == 200.0 and controller.parameters.autoCollectDistanceMm == 5.0
    with pytest.raises(ValueError, match="autoCollectDistanceMm = 0.1: must lie in"):
        controller.parameters.autoCollectDistanceMm = 0.1
    with pytest.raises(TypeError, match="expected a vtkMRMLLinearTransformNode"):
        controller.parameters.probeToReference = scene.AddNewNodeByClass("vtkMRMLModelNode")
    assert {parameter.name for parameter in PARAMETERS} >= {"probeToReference", "method", "referenceToImage"}
    controller.close()


def test_pivot_from_300_streamed_poses_recovers_the_tip(tracked):
    controller, probe = tracked
    controller.parameters.probeTipToProbe = None  # not calibrated yet: the pivot writes it
    rng = np.random.default_rng(3)
    divot = np.array([12.0, -40.0, 85.0])
    set_matrix(probe, pose_with_tip_at(divot))
    assert controller.run("start_pivot") is None and controller.status().pivot_recording
    for _ in range(300):
        rotation = rotation_about_axis(rng.normal(size=3), np.radians(rng.uniform(-30, 30)))
        pose = pose_with_tip_at(divot, rotation)
        pose[:3, 3] += rng.normal(scale=0.1, size=3)  # tracker noise, 0.1 mm per axis
        set_matrix(probe, pose)
    assert controller.status().pivot_poses == 300
    result = controller.run("stop_pivot")
    assert np.linalg.norm(result.tip_in_probe - TIP) < 0.05
    assert 0.1 < result.rms_mm < 0.25  # reported: the tip's scatter from the 0.1 mm per axis noise
    tip_node = controller.parameters.probeTipToProbe
    np.testing.assert_allclose(matrix_of(tip_node)[:3, 3], result.tip_in_probe)
    assert "RMS" in controller.status().message and not controller.status().pivot_recording


def test_pivot_without_a_probe_node_or_poses_is_a_message_not_an_exception(scene):
    controller = NavigationController(scene)
    assert controller.run("start_pivot") is None
    status = controller.status()
    assert status.message_is_error and "select ProbeToReference" in status.message
    assert controller.availability()["start_pivot"].startswith("select ProbeToReference")
    probe = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ProbeToReference")
    controller.parameters.probeToReference = probe
    set_matrix(probe, np.eye(4))
    controller.run("start_pivot")
    assert controller.run("stop_pivot") is None  # no pose arrived while recording
    assert "0 poses recorded, at least 10 needed" in controller.status().message
    with pytest.raises(WorkflowError, match="start pivot recording first"):
        controller.stop_pivot()  # a script calling the method directly gets the exception
    controller.close()


def test_auto_collect_along_a_60_mm_path_collects_at_the_set_spacing_and_saves_each_at_once(tracked, tmp_path):
    controller, probe = tracked
    start, direction = np.array([10.0, 20.0, 30.0]), np.array([2.0, -1.0, 2.0]) / 3.0
    set_matrix(probe, pose_with_tip_at(start))
    # 4.75 mm in 0.5 mm steps: 9 steps (4.5 mm) are too few, 10 steps (5 mm) enough, with no tie to round
    controller.parameters.autoCollectDistanceMm = 4.75
    controller.run("set_auto_collect", True)
    assert controller.status().auto_collect
    saved_counts = []
    for step in range(121):  # 0, 0.5, ..., 60 mm
        set_matrix(probe, pose_with_tip_at(start + direction * 0.5 * step))
        saved = tmp_path / "ProbePoints.mrk.json"
        saved_counts.append(len(json.loads(saved.read_text())["markups"][0]["controlPoints"]))
    points = mrml_nodes.fiducial_positions(controller.parameters.probePoints)
    assert len(points) == 13  # at 0, 5, 10, ..., 60 mm
    np.testing.assert_allclose(points, start + direction * 5.0 * np.arange(13)[:, None], atol=1e-9)
    assert saved_counts == [1 + step // 10 for step in range(121)]  # on disk the moment it is taken
    controller.run("set_auto_collect", False)
    set_matrix(probe, pose_with_tip_at(start + direction * 80.0))
    assert controller.parameters.probePoints.GetNumberOfControlPoints() == 13


def test_stale_after_a_silent_second_then_valid_again_and_collection_needs_no_other_call(tracked, scene):
    controller, probe = tracked
    assert controller.tool_state("probeToReference").state == "waiting"
    assert controller.run("collect_point") is None
    assert "ProbeToReference is not updating (last pose: never)" in controller.status().message
    set_matrix(probe, pose_with_tip_at([1.0, 2.0, 3.0]))
    assert controller.tool_state("probeToReference").state == "valid"
    assert controller.run("collect_point") == 0
    controller.clock.advance(1.2)  # the tracker stops sending
    state = controller.tool_state("probeToReference")
    assert state.state == "stale" and state.age_s >= 1.2
    assert controller.run("collect_point") is None and "last pose: 1." in controller.status().message
    set_matrix(probe, pose_with_tip_at([4.0, 5.0, 6.0]))
    assert controller.tool_state("probeToReference").state == "valid"
    controller.run("add_reference_body_markers")  # 4 marker centres in reference coordinates...
    controller.parameters.markersPatient.RemoveNthControlPoint(3)  # ...the surgeon touches the 4th instead
    controller.parameters.markersImage = mrml_nodes.fiducial_node(scene, np.eye(4, 3) * 30.0)
    assert controller.run("collect_marker") == 3
    np.testing.assert_allclose(mrml_nodes.fiducial_positions(controller.parameters.markersPatient)[3], [4, 5, 6])
    assert controller.run("collect_marker") is None and "already holds 4 centres" in controller.status().message
    np.testing.assert_allclose(mrml_nodes.fiducial_positions(controller.parameters.probePoints), [[1.0, 2.0, 3.0]])


def test_a_parent_transform_change_is_not_a_pose(tracked, scene):
    controller, probe = tracked
    set_matrix(probe, np.eye(4))
    controller.clock.advance(1.2)
    parent = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ReferenceToImage")
    probe.SetAndObserveTransformNodeID(parent.GetID())
    set_matrix(parent, make_transform(translation=(5.0, 0.0, 0.0)))  # TransformModifiedEvent on the probe too
    assert controller.tool_state("probeToReference").state == "stale"


def test_tip_to_surface_readout_follows_matrix_updates(tracked, scene, tibia_patient):
    controller, probe = tracked
    parameters = controller.parameters
    parameters.ipcModel = mrml_nodes.model_node(scene, tibia_patient.ipc)
    reference_to_image = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ReferenceToImage")
    set_matrix(reference_to_image, tibia_patient.reference_to_image)
    parameters.referenceToImage = reference_to_image
    on_bone = apply_transform(invert_transform(tibia_patient.reference_to_image), tibia_patient.ipc[:1])[0]
    set_matrix(probe, pose_with_tip_at(on_bone))
    assert controller.status().tip_to_surface_mm == pytest.approx(0.0, abs=1e-9)
    normal = tibia_patient.ipc[0] - tibia_patient.ipc.mean(axis=0)  # roughly outwards from the bone
    lifted = on_bone + 200.0 * normal / np.linalg.norm(normal)
    set_matrix(probe, pose_with_tip_at(lifted))
    expected = np.linalg.norm(tibia_patient.ipc - apply_transform(tibia_patient.reference_to_image, lifted), axis=1)
    assert controller.status().tip_to_surface_mm == pytest.approx(expected.min(), abs=1e-9)
    controller.clock.advance(1.2)
    assert controller.status().tip_to_surface_mm is None  # no readout from a stale probe


def test_observers_follow_the_selection(tracked, scene):
    controller, first = tracked
    second = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ProbeToReference (2)")
    before_first, before_second = observer_count(first), observer_count(second)
    controller.parameters.probeToReference = second
    assert observer_count(first) == before_first - 1 and observer_count(second) == before_second + 1
    set_matrix(first, np.eye(4))
    assert controller.tool_state("probeToReference").state == "waiting"  # the old node is not followed
    set_matrix(second, np.eye(4))
    assert controller.tool_state("probeToReference").state == "valid"
    controller.parameters.probeToReference = None
    assert observer_count(second) == before_second
    assert controller.tool_state("probeToReference").state == "not selected"


@pytest.mark.parametrize("running", ["pivot", "auto-collect"])
def test_scene_close_while_recording_removes_every_observer(scene, tmp_path, running):
    probe = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ProbeToReference")
    reference = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ReferenceToTracker")
    counts = {node: observer_count(node) for node in (probe, reference)}
    controller = NavigationController(scene, autosave_directory=tmp_path)
    parameter_node = controller.parameters.node
    parameter_observers = observer_count(parameter_node) - len(controller._parameter_observation[1])
    scene_observers = observer_count(scene)
    controller.parameters.probeToReference = probe
    controller.parameters.referenceToTracker = reference
    controller.parameters.probeTipToProbe = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ProbeTipToProbe")
    set_matrix(probe, np.eye(4))
    set_matrix(reference, np.eye(4))
    if running == "pivot":
        controller.run("start_pivot")
    else:
        controller.run("set_auto_collect", True)
    set_matrix(probe, make_transform(translation=(10.0, 0.0, 0.0)))
    assert all(observer_count(node) == counts[node] + 1 for node in counts)
    scene.Clear(0)  # what File > Close scene does
    assert all(observer_count(node) == counts[node] for node in counts)  # our observers are gone
    status = controller.status()
    assert not status.pivot_recording and not status.auto_collect
    assert status.tools[0].state == "not selected"
    set_matrix(probe, make_transform(translation=(20.0, 0.0, 0.0)))  # a late pose on a removed node: ignored
    controller.close()
    assert observer_count(parameter_node) == parameter_observers
    assert observer_count(scene) == scene_observers - 2


def test_register_through_the_controller_moves_the_probe_over_the_ct(tracked, scene, tibia_patient):
    controller, probe = tracked
    parameters = controller.parameters
    trial = tibia_patient.simulate_trial(np.random.default_rng(1), marker_fle_mm=0.0, probe_noise_mm=0.0)
    parameters.ipcModel = mrml_nodes.model_node(scene, tibia_patient.ipc)
    parameters.markersImage = mrml_nodes.fiducial_node(scene, trial.markers_image)
    parameters.markersPatient = mrml_nodes.fiducial_node(scene, trial.markers_patient)
    parameters.method = "cr"  # exact marker centres: the coarse registration alone is exact
    assert controller.availability()["register"] == "collect probe points on the bone (step 3)"
    for point in trial.ppc:
        set_matrix(probe, pose_with_tip_at(point))
        controller.run("collect_point")
    result = controller.run("register")
    assert result.method == "cr" and len(result.residuals_mm) == 40
    np.testing.assert_allclose(result.reference_to_image, tibia_patient.reference_to_image, atol=1e-6)
    np.testing.assert_allclose(matrix_of(parameters.referenceToImage), result.reference_to_image)
    assert probe.GetParentTransformNode() is parameters.referenceToImage
    assert parameters.probeTipToProbe.GetParentTransformNode() is probe
    assert controller.status().message.startswith(result.method.upper())
    assert controller.run("set_included", 99, False) is None and "the table has points 1 to 40" in (
        controller.status().message
    )
    parameters.method = "cr-fused"  # the default: markers and surface in one fit, with a pose covariance
    fused = controller.run("register")
    assert controller.status().message.startswith("CR-FUSED") and "weights: markers: FLE" in controller.status().message
    tip_image = apply_transform(fused.reference_to_image, trial.ppc[-1:])  # the tip rests on the last point
    assert controller.status().predicted_error_at_tip_mm == pytest.approx(fused.predicted_error_mm(tip_image)[0])


def test_process_ct_cancel_writes_nothing(scene, tibia_phantom):
    from RAMSICPRegistrationLib.navigation.controller import Cancelled

    controller = NavigationController(scene)
    controller.parameters.ctVolume = mrml_nodes.volume_node(scene, tibia_phantom[0], "CT")
    steps = []

    def cancel_after_segmentation(step, done, total):
        steps.append(step)
        if done == 1:
            raise Cancelled

    before = scene.GetNumberOfNodes()
    assert controller.run("process_ct", progress=cancel_after_segmentation) is None
    assert steps == ["segmentation", "marker spheres"] and scene.GetNumberOfNodes() == before
    assert controller.status().message == "CT processing cancelled; nothing was changed"
    controller.close()


def test_a_ct_without_a_bone_gives_its_marker_centres_in_a_node_of_their_own(scene):
    """No object in the CT is plausibly bone (the reference-body phantom without its shaft): no IPC, the message
    says why, and the 4 marker spheres found are put in a markups node apart, the workflow's nodes left alone."""
    from RAMSICPRegistrationLib.image.volume_io import CTVolume
    from RAMSICPRegistrationLib.navigation.navigation import REFUSED_CT_MARKERS
    from RAMSICPRegistrationLib.simulation.ct_painting import ReferenceBodyModel
    from RAMSICPRegistrationLib.simulation.reference_body_phantom import (
        SHAFT_RADIUS_MM,
        SOFT_TISSUE_MM,
        make_reference_body_phantom,
    )

    volume, truth = make_reference_body_phantom(ReferenceBodyModel("aluminium", "aluminium"))
    ras = volume.ijk_to_ras_points(np.argwhere(np.ones(volume.voxels.shape, dtype=bool)))
    voxels = volume.voxels.copy().reshape(-1)
    voxels[np.hypot(ras[:, 0], ras[:, 1]) < SHAFT_RADIUS_MM + SOFT_TISSUE_MM + 2.0] = -1000
    controller = NavigationController(scene)
    ct = CTVolume(voxels.reshape(volume.voxels.shape), volume.ijk_to_ras)
    controller.parameters.ctVolume = mrml_nodes.volume_node(scene, ct, "CT")
    assert controller.run("process_ct") is None
    message = controller.status().message
    assert "plausibly bone" in message and f"(4 of 4 usable) are in the markups node '{REFUSED_CT_MARKERS}'" in message
    node = scene.GetFirstNodeByName(REFUSED_CT_MARKERS)
    labels = [node.GetNthControlPointLabel(i) for i in range(node.GetNumberOfControlPoints())]
    assert sorted(labels) == ["M1 ok", "M2 ok", "M3 ok", "M4 ok"]
    for i, label in enumerate(labels):
        centre = np.array(node.GetNthControlPointPosition(i))
        assert np.linalg.norm(centre - truth.marker_centres[int(label[1]) - 1]) < 0.05
    parameters = controller.parameters
    assert parameters.markersImage is None and parameters.ipcModel is None and parameters.segmentation is None
    controller.close()


def test_process_ct_refuses_a_second_run_while_one_is_going(scene, tibia_phantom):
    """The Slicer widget's progress callback processes events, so a second click on 'Process CT' can arrive
    while the first run goes on: it is refused with a message, and the button is disabled meanwhile."""
    from RAMSICPRegistrationLib.navigation.controller import Cancelled

    controller = NavigationController(scene)
    controller.parameters.ctVolume = mrml_nodes.volume_node(scene, tibia_phantom[0], "CT")
    seen = []

    def click_again_then_cancel(step, done, total):
        seen.append((controller.availability()["process_ct"], controller.run("process_ct")))
        seen.append(controller.status().message)
        raise Cancelled

    assert controller.availability()["process_ct"] is None
    assert controller.run("process_ct", progress=click_again_then_cancel) is None
    busy = "the CT is being processed; wait for it to finish or cancel it"
    assert seen == [(busy, None), busy]
    assert controller.availability()["process_ct"] is None  # available again once the run has ended
    controller.close()


def test_a_ct_under_a_linear_transform_gives_its_ipc_and_marker_centres_where_slicer_shows_it(scene, tibia_phantom):
    """The CT sits under a parent transform (a registration done earlier, a manual alignment): Slicer shows it
    moved, so the IPC and the marker centres must come out moved too, in world RAS."""
    from conftest import random_transform

    volume, truth = tibia_phantom
    controller = NavigationController(scene)
    moved = random_transform(np.random.default_rng(24), 40.0, 80.0)
    parent = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "CTToWorld")
    set_matrix(parent, moved)
    ct = mrml_nodes.volume_node(scene, volume, "CT")
    ct.SetAndObserveTransformNodeID(parent.GetID())
    controller.parameters.ctVolume = ct
    image = controller.run("process_ct")
    assert image is not None and image.warnings == (), controller.status().message
    centres = mrml_nodes.fiducial_positions(image.markers_image)
    np.testing.assert_allclose(centres, apply_transform(moved, truth.marker_centres), atol=0.1)
    plain = NavigationController(headless_scene())  # the same CT, not moved: its IPC, moved by hand, is the answer
    plain.parameters.ctVolume = mrml_nodes.volume_node(plain.scene, volume, "CT")
    expected = apply_transform(moved, _model_points(plain.run("process_ct").ipc_model))
    np.testing.assert_allclose(_model_points(image.ipc_model), expected, rtol=0, atol=1e-6)
    controller.close()
    plain.close()


def _model_points(model_node):
    from vtkmodules.util.numpy_support import vtk_to_numpy

    return vtk_to_numpy(model_node.GetPolyData().GetPoints().GetData()).astype(np.float64)


def test_a_ct_under_a_non_linear_transform_is_refused_with_what_to_do(scene, tibia_phantom):
    from vtkmodules.vtkCommonCore import vtkPoints
    from vtkmodules.vtkCommonTransforms import vtkThinPlateSplineTransform

    controller = NavigationController(scene)
    warp = vtkThinPlateSplineTransform()
    source, target = vtkPoints(), vtkPoints()
    for point, shift in (
        ((0, 0, 0), (0, 0, 0)),
        ((100, 0, 0), (3, 0, 0)),
        ((0, 100, 0), (0, 0, 0)),
        ((0, 0, 100), (0, 2, 0)),
    ):
        source.InsertNextPoint(point)
        target.InsertNextPoint(np.add(point, shift))
    warp.SetSourceLandmarks(source)
    warp.SetTargetLandmarks(target)
    warp.SetBasisToR()
    parent = scene.AddNewNodeByClass("vtkMRMLTransformNode", "Warp")
    parent.SetAndObserveTransformToParent(warp)
    assert not parent.IsTransformToWorldLinear()
    ct = mrml_nodes.volume_node(scene, tibia_phantom[0], "CT")
    ct.SetAndObserveTransformNodeID(parent.GetID())
    controller.parameters.ctVolume = ct
    before = scene.GetNumberOfNodes()
    assert controller.run("process_ct") is None and scene.GetNumberOfNodes() == before
    assert controller.status().message == (
        "volume node 'CT' is under the non-linear transform 'Warp'; harden the transform on the CT (Data module: "
        "right-click the CT, 'Harden transform') or take the CT out of it, so that one matrix places its voxels"
    )
    controller.close()


def test_every_action_has_an_availability_and_run_refuses_unknown_ones(scene):
    controller = NavigationController(scene)
    assert set(controller.availability()) == set(ACTIONS)
    assert all(callable(getattr(controller, action)) for action in ACTIONS)
    with pytest.raises(ValueError, match="unknown action 'explode'"):
        controller.run("explode")
    controller.close()


def test_hold_still_collection_takes_the_mean_of_each_hold(tracked):
    """Three holds of 0.6 s at 60 Hz with 0.1 mm tremor, the tip moving 20 mm between them: three points, each
    the mean of its own hold's frames (computed here by hand), taken when the tip moves away or when turned off."""
    controller, probe = tracked
    rng = np.random.default_rng(11)
    now = {"s": 0.0}
    controller.pose_time = lambda node: now["s"]  # the frames' own time stamps, as our receiver provides
    holds = np.array([[0.0, 0.0, 0.0], [20.0, 0.0, 0.0], [20.0, 20.0, 0.0]])
    frames, expected = [], []
    for number, point in enumerate(holds):
        held = point + rng.normal(scale=0.1, size=(36, 3))  # 0.6 s at 60 Hz
        expected.append(held.mean(axis=0))
        frames += list(held)
        if number + 1 < len(holds):
            frames += list(np.linspace(point, holds[number + 1], 12)[1:-1] + [0.0, 0.0, 8.0])  # lifted between
    now["s"] = -0.5
    set_matrix(probe, pose_with_tip_at([0.0, 0.0, 30.0]))  # tracked, in the air above the first point
    controller.parameters.holdStillMm, controller.parameters.holdStillS = 1.0, 0.5
    controller.run("set_hold_still_collect", True)
    collected_at = []
    controller.add_listener(lambda event, data: collected_at.append(now["s"]) if event == "collected" else None)
    for index, tip in enumerate(frames):
        now["s"] = index / 60.0
        set_matrix(probe, pose_with_tip_at(tip))
        if index == 20:
            assert not controller.status().holding  # 1/3 s held: not yet long enough
        if index == 35:
            assert controller.status().holding  # 35/60 s: lifting the tip now would collect the point
    assert len(collected_at) == 2  # the first two holds ended when the tip moved away
    controller.run("set_hold_still_collect", False)  # the last hold ends when collection is turned off
    points = mrml_nodes.fiducial_positions(controller.parameters.probePoints)
    np.testing.assert_allclose(points, expected, atol=1e-9)
    assert controller.run("set_auto_collect", True) is None and controller.status().auto_collect
    controller.run("set_hold_still_collect", True)  # one mode at a time
    assert controller.status().hold_still_collect and not controller.status().auto_collect


def test_hold_still_collection_takes_a_swivel_as_one_point_at_its_fixed_point_and_skips_a_rest(tracked):
    """Live, as in ``ramsicp collect``: the probe lying still when collection is turned on is a rest (said, not
    collected); a swivel of 40 degrees about a landmark, with ProbeTipToProbe 2.5 mm off, is one point exactly on the
    landmark (the swivel's fixed point), where the mean tip would lie up to 2.5 mm away."""
    from RAMSICPRegistrationLib.core.transforms import rotation_about_axis

    controller, probe = tracked
    set_matrix(controller.parameters.probeTipToProbe, make_transform(translation=TIP + (2.5, 0.0, 0.0)))
    now = {"s": 0.0}
    controller.pose_time = lambda node: now["s"]
    messages = []
    controller.add_listener(lambda event, data: messages.append(data[0]) if event == "message" else None)
    lying = pose_with_tip_at([300.0, 0.0, 0.0])
    set_matrix(probe, lying)
    controller.run("set_hold_still_collect", True)
    landmark = np.array([10.0, 20.0, 30.0])
    frames = [lying] * 20 + [pose_with_tip_at(landmark + (0, 0, 40.0 - 10 * k)) for k in range(4)]
    for k in range(60):  # the swivel: two tilts of up to 20 degrees each
        angle = 2 * np.pi * k / 60
        rotation = rotation_about_axis((1, 0, 0), np.radians(20) * np.sin(angle)) @ rotation_about_axis(
            (0, 1, 0), np.radians(20) * np.sin(2 * angle)
        )
        frames.append(pose_with_tip_at(landmark, rotation))
    frames += [pose_with_tip_at(landmark + (0, 0, 10.0 * (k + 1))) for k in range(4)]
    for index, pose in enumerate(frames):
        now["s"] = index / 20.0
        set_matrix(probe, pose)
    assert any("not collected: the probe lay still for" in message and "(a rest)" in message for message in messages)
    (point,) = mrml_nodes.fiducial_positions(controller.parameters.probePoints)
    np.testing.assert_allclose(point, landmark, atol=1e-6)
    assert "point 1 collected: swivel of 2.95 s over 60 frames" in controller.status().message


def test_flagged_markers_are_refused_and_numbered_markers_pair_by_number(tracked, scene, tibia_patient):
    """As ``ramsicp register``: a marker the CT flagged is not used silently; deleting it leaves the others paired
    by their numbers, so the coarse registration is still exact."""
    controller, probe = tracked
    parameters = controller.parameters
    trial = tibia_patient.simulate_trial(np.random.default_rng(2), marker_fle_mm=0.0, probe_noise_mm=0.0)
    parameters.ipcModel = mrml_nodes.model_node(scene, tibia_patient.ipc)
    labels = ["M1 ok", "M2 partial", "M3 ok", "M4 ok"]
    parameters.markersImage = mrml_nodes.fiducial_node(scene, trial.markers_image, labels)
    parameters.markersPatient = mrml_nodes.fiducial_node(scene, trial.markers_patient)  # the tool: M1..M4
    parameters.method = "cr"
    for point in trial.ppc[:10]:
        set_matrix(probe, pose_with_tip_at(point))
        controller.run("collect_point")
    assert controller.run("register") is None
    assert controller.status().message.startswith("marker 2 is partial in the CT, so its centre may be off")
    parameters.markersImage.RemoveNthControlPoint(1)  # the surgeon deletes marker 2
    result = controller.run("register")
    np.testing.assert_allclose(result.reference_to_image, tibia_patient.reference_to_image, atol=1e-6)
    assert len(result.marker_residuals_mm) == 3


def _collect(controller, probe, points):
    for point in points:
        set_matrix(probe, pose_with_tip_at(point))
        controller.run("collect_point")


def _exact_inputs(scene, controller, tibia_patient, ipc_shift=(0.0, 0.0, 0.0), marker_order=None):
    """An exact trial's markers and IPC (shifted in the image by ``ipc_shift`` mm) selected; returns the trial."""
    parameters = controller.parameters
    trial = tibia_patient.simulate_trial(np.random.default_rng(1), marker_fle_mm=0.0, probe_noise_mm=0.0)
    parameters.ipcModel = mrml_nodes.model_node(scene, tibia_patient.ipc + np.asarray(ipc_shift))
    parameters.markersImage = mrml_nodes.fiducial_node(scene, trial.markers_image)
    order = np.arange(len(trial.markers_patient)) if marker_order is None else marker_order
    parameters.markersPatient = mrml_nodes.fiducial_node(scene, trial.markers_patient[order])
    return trial


def test_a_registration_with_an_alarm_is_not_navigated_until_accepted(tracked, scene, tibia_patient):
    """Issue 23: an IPC 2 mm off where the exact markers put the bone (under the 3 mm far-touch floor): CR-ICP
    slides 2 mm, beyond the 1 mm the markers allow, an alarm. The result is shown, not applied: no ReferenceToImage,
    no tip distance, until the user accepts it; then it is navigated with, and the alarm is no longer shown."""
    controller, probe = tracked
    parameters = controller.parameters
    trial = _exact_inputs(scene, controller, tibia_patient, ipc_shift=(2.0, 0.0, 0.0))
    _collect(controller, probe, trial.ppc)
    parameters.method = "cr-icp"
    assert controller.availability()["accept_registration"] == "no registration is waiting for acceptance"
    result = controller.run("register")
    assert result.alarms and "cr-icp moved probe point" in result.alarms[0]
    status = controller.status()
    assert status.alarms == result.alarms and not set(status.warnings) & set(result.alarms)
    assert status.message.startswith("ALARM, registration not applied") and status.message_is_error
    assert parameters.referenceToImage is None and probe.GetParentTransformNode() is None
    assert status.tip_to_surface_mm is None
    assert controller.run("accept_registration") is result
    np.testing.assert_allclose(matrix_of(parameters.referenceToImage), result.reference_to_image)
    assert probe.GetParentTransformNode() is parameters.referenceToImage
    status = controller.status()
    assert status.alarms == () and status.message.startswith("registration accepted despite 1 alarm(s)")
    assert status.tip_to_surface_mm is not None
    assert controller.availability()["accept_registration"] is not None


def _lifted_off(patient, point, distance_mm):
    """``point`` (reference mm) moved ``distance_mm`` along the axis direction that takes it farthest from the IPC."""
    image_to_reference = invert_transform(patient.reference_to_image)
    ipc = apply_transform(image_to_reference, patient.ipc)
    moves = np.vstack((np.eye(3), -np.eye(3))) * distance_mm
    gaps = [np.linalg.norm(ipc - (point + move), axis=1).min() for move in moves]
    assert max(gaps) > 6.0, "the test needs a point that can be lifted off the bone"
    return point + moves[int(np.argmax(gaps))]


def test_touches_far_from_the_bone_are_left_out_until_included_by_hand(tracked, scene, tibia_patient):
    """Two touches 10 mm off the bone (in the air between touches): flagged in the residual table's note, their
    'include' turned off, the CR exact on the other 40; ticked again by hand, the next registration uses one."""
    controller, probe = tracked
    parameters = controller.parameters
    trial = _exact_inputs(scene, controller, tibia_patient)
    lifted = np.array([_lifted_off(tibia_patient, point, 10.0) for point in trial.ppc[:2]])
    _collect(controller, probe, np.vstack((trial.ppc, lifted)))
    parameters.method = "cr"
    result = controller.run("register")
    assert result.left_out == result.far_points == (40, 41) and not result.alarms
    np.testing.assert_allclose(result.reference_to_image, tibia_patient.reference_to_image, atol=1e-6)
    status = controller.status()
    assert status.far_points == (41, 42) and any("left out of the fit: 41 (" in w for w in status.warnings)
    table = parameters.residualTable.GetTable()
    include, note = table.GetColumnByName("include"), table.GetColumnByName("note")
    assert [include.GetValue(row) for row in (39, 40, 41)] == [1, 0, 0]
    assert note.GetValue(40).startswith("far from the bone after the CR: ") and note.GetValue(39) == ""
    controller.run("set_included", 40, True)  # the surgeon says point 41 was on the bone after all
    again = controller.run("register")  # point 42 stays out (its include is off): point 41 is far, and used
    assert again.far_points == (40,) and again.left_out == () and len(again.residuals_mm) == 41
    table = parameters.residualTable.GetTable()
    assert [table.GetColumnByName("include").GetValue(row) for row in (40, 41)] == [1, 0]
    assert all(table.GetColumnByName("note").GetValue(row).startswith("far") for row in (40, 41))
    assert controller.status().far_points == (41, 42)


def test_patient_markers_in_another_order_are_paired_by_their_distances(tracked, scene, tibia_patient):
    """The patient's marker centres listed in another order: paired by the tool's distances, said, and exact."""
    controller, probe = tracked
    trial = _exact_inputs(scene, controller, tibia_patient, marker_order=[2, 0, 3, 1])
    _collect(controller, probe, trial.ppc)
    controller.parameters.method = "cr"
    result = controller.run("register")
    np.testing.assert_allclose(result.reference_to_image, tibia_patient.reference_to_image, atol=1e-6)
    assert any("paired by the markers' distances instead" in w for w in controller.status().warnings)
