"""The next touch and 'enough' in the controller (issue 26, both shells): computed from cr-fused's own uncertainty at
the plan's targets, drawn on the bone, and followed by guided collection, played end to end: this test is the
surgeon, touching the bone where the drawn point is, with a hand's tremor, while the tracker streams 60 Hz poses
into a real slicer-core scene; the controller registers after each touch until it says enough."""

import re

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.surface_index import SurfaceIndex
from RAMSICPRegistrationLib.core.touch_guidance import touch_guidance
from RAMSICPRegistrationLib.core.transforms import apply_transform, invert_transform, make_transform

from conftest import headless_scene

slicer = pytest.importorskip("slicer", reason="slicer-core (real MRML) needs Python >= 3.10")
from RAMSICPRegistrationLib.navigation import mrml_nodes  # noqa: E402
from RAMSICPRegistrationLib.navigation.controller import NavigationController  # noqa: E402
from RAMSICPRegistrationLib.navigation.navigation import set_matrix  # noqa: E402

TIP = np.array([1.5, -2.0, 152.0])
RATE_HZ = 60.0


@pytest.fixture(scope="module")
def reachable(tibia_patient, tibia_index):
    """The IPC's points within 0.5 mm of the exposed bone (where a surgeon can touch it), image coordinates."""
    from RAMSICPRegistrationLib.experiments.guided import reachable_points

    class Subject:
        patient, index = tibia_patient, tibia_index

    return reachable_points(Subject)


class Surgeon:
    """A tracked probe in a hand: holds the tip on a point for 0.6 s with 0.05 mm of tremor, then lifts it."""

    def __init__(self, scene, seed):
        self.rng = np.random.default_rng(seed)
        self.now = 0.0
        self.controller = NavigationController(scene, clock=lambda: self.now, pose_time=lambda node: self.now)
        parameters = self.controller.parameters
        self.probe = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ProbeToReference")
        tip = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ProbeTipToProbe")
        set_matrix(tip, make_transform(translation=TIP))
        parameters.probeToReference, parameters.probeTipToProbe = self.probe, tip
        self.move_to((0.0, 0.0, 300.0))

    def move_to(self, point):
        self.now += 1.0 / RATE_HZ
        set_matrix(self.probe, make_transform(translation=np.asarray(point, dtype=np.float64) - TIP))

    def touch(self, point):
        """Come down on ``point`` (reference mm), hold it, lift the tip 24 mm."""
        point = np.asarray(point, dtype=np.float64)
        for k in range(6):
            self.move_to(point + (0.0, 0.0, 20.0 * (1 - k / 6)))
        for _ in range(36):
            self.move_to(point + self.rng.normal(scale=0.05, size=3))
        for k in range(1, 7):
            self.move_to(point + (0.0, 0.0, 4.0 * k))


def _patient_case(scene, parameters, patient, trial, reachable=None):
    parameters.ipcModel = mrml_nodes.model_node(scene, patient.ipc)
    parameters.markersImage = mrml_nodes.fiducial_node(scene, trial.markers_image)
    parameters.markersPatient = mrml_nodes.fiducial_node(scene, trial.markers_patient)
    parameters.targetsImage = mrml_nodes.fiducial_node(scene, patient.targets_image, name="TargetsImage")
    if reachable is not None:
        parameters.reachableSurface = mrml_nodes.model_node(scene, reachable, name="ExposedBone")


def test_the_next_touch_is_drawn_after_cr_fused_and_moves_to_the_planned_cuts_endpoints(tibia_patient, tibia_index):
    scene = headless_scene()
    surgeon = Surgeon(scene, seed=3)
    controller, parameters = surgeon.controller, surgeon.controller.parameters
    trial = tibia_patient.simulate_trial(np.random.default_rng(3), marker_fle_mm=1.0, points_per_area=1)
    _patient_case(scene, parameters, tibia_patient, trial)
    for point in trial.ppc:  # 8 points, one per sub-area
        surgeon.move_to(point)
        controller.run("collect_point")
    parameters.method = "cr-icp"
    controller.run("register")
    status = controller.status()
    assert status.next_touch is None and "choose cr-fused" in status.next_touch_text
    assert controller.availability()["set_guided_collect"].startswith("next touch: it needs cr-fused")
    parameters.method = "cr-fused"
    result = controller.run("register")
    expected = touch_guidance(result, tibia_index, targets_image=tibia_patient.targets_image)  # the library's answer
    touch = controller.status().next_touch
    np.testing.assert_allclose(touch.position_image, expected.next_touch.position_image, atol=1e-9)
    assert touch.predicted_tre_after_mm == pytest.approx(expected.next_touch.predicted_tre_rms_mm)
    assert touch.bound_95_mm == pytest.approx(expected.predicted_tre_95_mm.max()) and touch.targets == "the targets"
    drawn = parameters.nextTouch
    np.testing.assert_allclose(drawn.GetNthControlPointPosition(0), touch.position_image, atol=1e-9)
    assert drawn.GetNthControlPointLabel(0) == f"next: {touch.predicted_tre_after_mm:.2f} mm"
    tip_image = apply_transform(result.reference_to_image, trial.ppc[-1:])[0]  # the tip rests on the last point
    assert touch.tip_distance_mm == pytest.approx(np.linalg.norm(tip_image - touch.position_image))
    # 'enough' follows the limit at once, judged on the 95 % bound
    parameters.targetTreMm = round(touch.bound_95_mm + 0.01, 3)
    assert controller.status().next_touch.enough and controller.status().next_touch_text.startswith("ENOUGH")
    assert controller.availability()["set_guided_collect"].startswith("enough touches already")
    parameters.targetTreMm = round(touch.bound_95_mm - 0.01, 3)
    assert not controller.status().next_touch.enough and controller.availability()["set_guided_collect"] is None
    # a planned cut: its endpoints are the targets now
    controller.run("place_osteotomy_plane", level_mm=70.0)
    cut = controller.run("plan_cut")
    planned = touch_guidance(result, tibia_index, targets_image=cut.endpoints)
    touch = controller.status().next_touch
    assert touch.targets == "the planned cut's endpoints"
    np.testing.assert_allclose(touch.position_image, planned.next_touch.position_image, atol=1e-9)
    controller.close()


def test_guided_collection_touches_where_it_says_until_enough_and_keeps_its_promise(tibia_patient, reachable):
    """Eight patients (markers placed by hand in the CT, FLE 1 mm), each started with 3 free touches and one click
    on Register, then guided collection with a 0.4 mm limit: the surgeon touches the exposed bone nearest to the
    drawn point (the probe's 0.25 mm noise), 0.6 s still, lifted. Each registers and moves the suggestion on, until
    enough; the final registration's true error at the 4 targets is compared with what it predicted."""
    truth_errors, predicted, bounds, counts = [], [], [], []
    for seed in range(8):
        scene = headless_scene()
        surgeon = Surgeon(scene, seed)
        controller, parameters = surgeon.controller, surgeon.controller.parameters
        rng = np.random.default_rng(seed)
        trial = tibia_patient.simulate_trial(rng, marker_fle_mm=1.0)
        _patient_case(scene, parameters, tibia_patient, trial, reachable)
        parameters.targetTreMm = 0.4
        controller.run("set_hold_still_collect", True)
        for point in tibia_patient.random_touches(rng, 3):
            surgeon.touch(point)
        assert controller.run("register") is not None, controller.status().message
        assert controller.run("set_guided_collect", True) is None and controller.status().guided_collect
        suggestions = []
        while controller.status().guided_collect:
            assert len(suggestions) < 25, "guided collection did not reach enough in 25 touches"
            suggested = np.array(controller.status().next_touch.position_image)
            suggestions.append(suggested)
            surgeon.touch(tibia_patient.touch(rng, suggested)[0])
            assert len(controller.last_result.residuals_mm) == 3 + len(suggestions)  # collected and registered
        # the suggestion moves on (a spot may come back once others have been touched)
        assert len(np.unique(np.round(suggestions, 6), axis=0)) > len(suggestions) / 2
        status = controller.status()
        assert status.next_touch.enough and status.message.startswith("ENOUGH after"), status.message
        assert not status.hold_still_collect and status.probe_points == 3 + len(suggestions)
        result = controller.last_result
        targets_patient = apply_transform(
            invert_transform(tibia_patient.reference_to_image), tibia_patient.targets_image
        )
        registered = apply_transform(result.reference_to_image, targets_patient)
        truth_errors.append(np.linalg.norm(registered - tibia_patient.targets_image, axis=1))
        predicted.append(result.predicted_tre_mm)
        bounds.append(result.predicted_tre_95_mm)
        counts.append(len(suggestions))
        assert np.all(result.predicted_tre_95_mm < 0.4)
        controller.close()
    truth_errors, predicted, bounds = map(np.array, (truth_errors, predicted, bounds))
    ratio = np.sqrt(np.mean(truth_errors**2)) / np.sqrt(np.mean(predicted**2))
    within = np.mean(truth_errors < bounds)
    print(
        f"8 patients stopped at enough after guided touches {counts}: true / predicted RMS error at the targets "
        f"{ratio:.2f}, within their 95 % bound {within:.0%}"
    )
    # What is measured: the shell's guided loop (hold-still touches, register, next touch, stop at enough) on 8
    # patients, 32 targets. These 8 happen to be unlucky: 1.55 and 78 %, and already 1.35-1.44 at fixed counts of 5-15
    # touches. benchmarks/guided_stopping_calibration.py runs the same loop on the core (it stops where this test
    # does on these 8): over 120 patients, stopped at enough, 1.06 (bootstrap 95 % interval 0.96-1.18) and 96 %;
    # fixed counts 1.00-1.03. Samples of 8 of those 120 patients span 0.74-1.64 (1st-99th percentile) with coverage
    # of at least 78 % in 99 %: the bounds below, just outside those, fail about 2 % of calibrated samples.
    assert 0.7 <= ratio <= 1.7, f"true / predicted RMS error {ratio:.2f} over 8 patients: beyond 0.74-1.64"
    assert within >= 0.75, f"{within:.0%} of the targets within their 95 % bound over 8 patients: below 78 %"


def test_guided_collection_leaves_out_a_touch_away_from_the_drawn_point(tibia_patient, reachable):
    scene = headless_scene()
    surgeon = Surgeon(scene, seed=5)
    controller, parameters = surgeon.controller, surgeon.controller.parameters
    rng = np.random.default_rng(5)
    trial = tibia_patient.simulate_trial(rng, marker_fle_mm=1.0)
    _patient_case(scene, parameters, tibia_patient, trial, reachable)
    parameters.targetTreMm = 0.2
    for point in tibia_patient.random_touches(rng, 4):
        surgeon.move_to(point)
        controller.run("collect_point")
    controller.run("register")
    controller.run("set_guided_collect", True)
    suggested = np.array(controller.status().next_touch.position_image)
    far = tibia_patient.touch(rng, suggested + (0.0, 0.0, 30.0), probe_noise_mm=0.0)[0]  # up the bone, on it
    away = np.linalg.norm(apply_transform(controller.last_result.reference_to_image, far[None])[0] - suggested)
    assert away > 6.0  # beyond the 5 mm a guided touch may lie from the drawn point
    surgeon.touch(far)
    status = controller.status()
    assert status.probe_points == 4 and status.guided_collect and status.message_is_error
    said = re.match(r"not collected: that touch was (\d+\.\d) mm from the point drawn", status.message)
    assert said and float(said.group(1)) == pytest.approx(away, abs=0.1) and "touch the drawn point" in status.message
    surgeon.touch(tibia_patient.touch(rng, suggested)[0])
    assert controller.status().probe_points == 5 and controller.last_result.residuals_mm.shape == (5,)
    controller.run("set_guided_collect", False)
    status = controller.status()
    assert not status.guided_collect and not status.hold_still_collect
    controller.close()


def test_no_next_touch_while_a_registration_waits_for_acceptance_or_without_targets(tibia_patient):
    scene = headless_scene()
    surgeon = Surgeon(scene, seed=1)
    controller, parameters = surgeon.controller, surgeon.controller.parameters
    trial = tibia_patient.simulate_trial(np.random.default_rng(1), marker_fle_mm=0.5, points_per_area=1)
    parameters.ipcModel = mrml_nodes.model_node(scene, tibia_patient.ipc)
    parameters.markersImage = mrml_nodes.fiducial_node(scene, trial.markers_image)
    parameters.markersPatient = mrml_nodes.fiducial_node(scene, trial.markers_patient)
    for point in trial.ppc:
        surgeon.move_to(point)
        controller.run("collect_point")
    controller.run("register")
    status = controller.status()
    assert status.next_touch is None and status.next_touch_text == (
        "next touch: the next touch needs the plan's targets: plan the cut, or select targets in the image"
    )
    parameters.targetsImage = mrml_nodes.fiducial_node(scene, tibia_patient.targets_image)
    assert controller.status().next_touch is not None
    assert parameters.nextTouch.GetNumberOfControlPoints() == 1
    index = SurfaceIndex(tibia_patient.ipc)
    assert index.nearest(np.array([controller.status().next_touch.position_image]))[0][0] < 1e-9  # on the IPC
    controller.close()


def test_guided_collection_over_a_real_openigtlink_tracker_follows_the_suggestions(tibia_patient, reachable):
    """End to end through the tracker chain the shells use: a simulated Vega (NDI protocol) -> our NDI driver ->
    our PLUS-compatible OpenIGTLink server -> the bridge's receiver -> transform nodes -> the controller. The test's
    hand holds the probe on the bone where the orange point is drawn, then lifts it; the controller collects only
    such touches, registers after each, and stops at 'enough'; the predicted error at the targets falls."""
    import time

    from OpenIGTLinkBridgeLib.bridge_controller import BridgeController
    from OpenIGTLinkBridgeLib.live_scenario import PROBE_TIP_MM, HandHeldProbe, serve_hand_held_probe

    rng = np.random.default_rng(11)
    scene = headless_scene()
    probe = HandHeldProbe()
    simulator, server = serve_hand_held_probe(probe)
    bridge = BridgeController(scene)
    controller = NavigationController(scene)
    try:
        parameters = controller.parameters
        parameters.probeToReference = controller.steps.transform_node("ProbeToReference")  # the receiver's names
        parameters.referenceToTracker = controller.steps.transform_node("ReferenceToTracker")
        tip = controller.steps.transform_node("ProbeTipToProbe")
        set_matrix(tip, make_transform(translation=PROBE_TIP_MM))  # the pivot's result
        parameters.probeTipToProbe = tip
        trial = tibia_patient.simulate_trial(rng, marker_fle_mm=1.0)
        _patient_case(scene, parameters, tibia_patient, trial, reachable)
        parameters.targetTreMm = 0.5
        bridge.connect("127.0.0.1", server.address[1])

        def run_tracker(seconds):
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                bridge.poll()
                time.sleep(0.002)

        def touch(point):
            """Hold the tip on ``point`` (reference mm) for 0.6 s, then lift it away, moving (no hold in the air)."""
            probe.touch(point)
            run_tracker(0.6)
            lifted = np.asarray(point) + (0.0, 20.0, 20.0)
            probe.slide(lifted, lifted + (0.0, 30.0, 30.0), period_s=0.8)
            run_tracker(0.3)

        run_tracker(1.0)
        assert controller.tool_state("probeToReference").state == "valid", bridge.status().connection
        controller.run("set_hold_still_collect", True)
        for point in tibia_patient.random_touches(rng, 3):
            touch(point)
        assert controller.status().probe_points == 3, controller.status().message
        controller.run("register")
        run_tracker(0.3)  # the shell reads the tracker on: the probe is current again after the registration
        assert controller.run("set_guided_collect", True) is None, controller.status().message
        assert controller.status().guided_collect
        predicted = [controller.status().next_touch.predicted_tre_mm]
        promised = []
        while controller.status().guided_collect:
            assert len(promised) < 20, "guided collection did not reach enough in 20 touches"
            shown = controller.status().next_touch
            promised.append(shown.predicted_tre_after_mm)
            touch(tibia_patient.touch(rng, np.array(shown.position_image))[0])
            assert len(controller.last_result.residuals_mm) == 3 + len(promised), controller.status().message
            touched = np.array(parameters.probePoints.GetNthControlPointPosition(2 + len(promised)))
            registered = apply_transform(controller.last_result.reference_to_image, touched[None])[0]
            assert np.linalg.norm(registered - shown.position_image) < 5.0  # where it was drawn
            predicted.append(controller.last_result.predicted_tre_rms_mm)
        status = controller.status()
        print(f"predicted error at the targets after each registration (mm): {np.round(predicted, 3).tolist()}")
        print(f"promised by each suggestion (mm): {np.round(promised, 3).tolist()}")
        assert status.message.startswith("ENOUGH after") and status.next_touch.enough, status.message
        assert not status.hold_still_collect and status.probe_points == 3 + len(promised)
        assert predicted[-1] < 0.6 * predicted[0]
        # each registration predicts what its suggestion promised (the rank-one update is the full model's answer)
        np.testing.assert_allclose(predicted[1:], promised, rtol=0.15)
        assert np.all(np.diff(predicted) < 0.05)  # each guided touch lowers it, or keeps it within noise
    finally:
        controller.close()
        bridge.close()
        server.stop()
        simulator.stop()


def test_a_reachable_point_list_edited_in_place_changes_the_next_touchs_key():
    """A markups node's MTime stays when a control point is moved: the suggestion is keyed by the points
    themselves, so moving the only reachable point moves the next touch with it (review finding)."""
    from RAMSICPRegistrationLib.navigation.controller import _node_state

    scene = slicer.vtkMRMLScene()
    node = scene.AddNewNodeByClass("vtkMRMLMarkupsFiducialNode", "Reachable")
    node.AddControlPoint([1.0, 2.0, 3.0])
    before = _node_state(node)
    node.SetNthControlPointPosition(0, 4.0, 5.0, 6.0)
    assert _node_state(node) != before
