"""Checkpoints (issue 26): a point on the bone stored after the registration, touched again later, tells whether the
reference body moved. Driven as a tracker drives the controller: the tracker streams ReferenceToTracker and
ProbeToReference (eq. 2 from the probe's pose in the tracker) into transform nodes of a real slicer-core scene, with
60 Hz frames, the tracker's noise and a probe tip calibrated 0.2 mm off. The bone stays where it is in the tracker;
a slip moves the reference body on it, so the checkpoint's true move is computable by hand."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.transforms import (
    apply_transform,
    invert_transform,
    make_transform,
    rotation_about_axis,
)

from conftest import headless_scene, random_transform

slicer = pytest.importorskip("slicer", reason="slicer-core (real MRML) needs Python >= 3.10")
from RAMSICPRegistrationLib.io.session_log import LOG_NAME, read_session_log  # noqa: E402
from RAMSICPRegistrationLib.navigation import mrml_nodes  # noqa: E402
from RAMSICPRegistrationLib.navigation.controller import NavigationController  # noqa: E402
from RAMSICPRegistrationLib.navigation.navigation import set_matrix  # noqa: E402
from RAMSICPRegistrationLib.navigation.parameters import CHECKPOINT_LIMIT_MM  # noqa: E402

TRUE_TIP = np.array([1.5, -2.0, 152.0])  # the probe's real tip in its marker frame (mm)
TIP_ERROR = np.array([0.12, -0.1, 0.13])  # the pivot calibration's error: 0.2 mm
NOISE_MM = 0.1  # the tracker's noise on the tip, per axis, per frame
RATE_HZ = 60.0


class Theatre:
    """The tracker's view of the operating room: the bone fixed in tracker coordinates, the reference body on it
    (``reference_to_tracker``), the probe in the surgeon's hand; every frame written into the controller's nodes."""

    def __init__(self, scene, tmp_path, patient, seed=0):
        self.rng = np.random.default_rng(seed)
        self.now = 0.0
        self.controller = NavigationController(
            scene, autosave_directory=tmp_path, clock=lambda: self.now, pose_time=lambda node: self.now
        )
        parameters = self.controller.parameters
        self.reference = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ReferenceToTracker")
        self.probe = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ProbeToReference")
        calibrated = scene.AddNewNodeByClass("vtkMRMLLinearTransformNode", "ProbeTipToProbe")
        set_matrix(calibrated, make_transform(translation=TRUE_TIP + TIP_ERROR))
        parameters.referenceToTracker, parameters.probeToReference = self.reference, self.probe
        parameters.probeTipToProbe = calibrated
        self.reference_to_tracker = random_transform(self.rng, 180.0, 1500.0)
        self.bone_to_tracker = self.reference_to_tracker.copy()  # the patient's frame at the CT: the bone stays
        self.patient = patient

    def frame(self, tip_tracker, tilt):
        """One tracker frame: the probe's real tip at ``tip_tracker`` (3,) with the tracker's noise, its shaft turned
        by ``tilt`` (3, 3)."""
        self.now += 1.0 / RATE_HZ
        tip = np.asarray(tip_tracker) + self.rng.normal(scale=NOISE_MM, size=3)
        probe_to_tracker = make_transform(tilt, tip - tilt @ TRUE_TIP)
        set_matrix(self.reference, self.reference_to_tracker)
        set_matrix(self.probe, invert_transform(self.reference_to_tracker) @ probe_to_tracker)  # eq. 2

    def hold(self, tip_tracker, tilt_deg=0.0, seconds=0.8):
        """The tip held on a point of the bone (tracker coordinates), the probe tilted ``tilt_deg`` about a random
        axis."""
        tilt = rotation_about_axis(self.rng.normal(size=3), np.radians(tilt_deg))
        for _ in range(int(seconds * RATE_HZ)):
            self.frame(tip_tracker, tilt)

    def bone_point(self, index):
        """An IPC point of the bone, in tracker coordinates (where it stays whatever the reference body does)."""
        in_reference = apply_transform(invert_transform(self.patient.reference_to_image), self.patient.ipc[index])
        return apply_transform(self.bone_to_tracker, in_reference[None])[0]

    def register(self):
        """A coarse registration from 40 touches on the bone (exact before any slip; the point of these tests is
        what comes after it)."""
        parameters = self.controller.parameters
        scene = self.controller.scene
        trial = self.patient.simulate_trial(np.random.default_rng(1), marker_fle_mm=0.0, probe_noise_mm=0.0)
        if parameters.ipcModel is None:
            parameters.ipcModel = mrml_nodes.model_node(scene, self.patient.ipc)
            parameters.markersImage = mrml_nodes.fiducial_node(scene, trial.markers_image)
            parameters.markersPatient = mrml_nodes.fiducial_node(scene, trial.markers_patient)
            parameters.method = "cr"
        for point in trial.ppc:
            self.hold(apply_transform(self.bone_to_tracker, point[None])[0], seconds=1.0 / RATE_HZ)
            assert self.controller.run("collect_point") is not None, self.controller.status().message
        return self.controller.run("register")


@pytest.fixture
def theatre(tmp_path, tibia_patient):
    theatre = Theatre(headless_scene(), tmp_path, tibia_patient)
    yield theatre
    theatre.controller.close()


def slip(move):
    """The reference body moved by ``move`` (4, 4) in tracker coordinates: its new ReferenceToTracker."""
    return lambda reference_to_tracker: move @ reference_to_tracker


def test_a_1_mm_slip_of_the_reference_body_raises_an_alarm_shown_logged_and_cleared_by_registering_again(
    theatre, tmp_path
):
    controller = theatre.controller
    theatre.hold(theatre.bone_point(0))
    assert controller.availability()["store_checkpoint"] == "register first (step 4)"
    assert controller.availability()["check_checkpoint"] == "store a checkpoint first (touch a divot or a landmark)"
    theatre.register()
    divot = theatre.bone_point(1234)
    theatre.hold(divot)
    assert controller.run("store_checkpoint") == "C1"
    assert controller.status().checkpoint_count == 1 and "checkpoint C1 stored" in controller.status().message
    theatre.hold(theatre.bone_point(4321))
    assert controller.run("store_checkpoint") == "C2"  # a second one, never checked after the slip
    node = controller.parameters.checkpoints
    assert node.GetTransformNodeID() == controller.parameters.referenceToImage.GetID()  # drawn on the bone in the CT
    stored = np.array(node.GetNthControlPointPosition(0))
    true_stored = apply_transform(invert_transform(theatre.reference_to_tracker), divot[None])[0]
    assert np.linalg.norm(stored - true_stored) < 0.25  # the tip's calibration error (0.2 mm) and the noise
    assert controller.status().tip_to_surface_mm is not None

    # The reference body slips 1 mm on its bracket, along a direction no axis favours; the bone stays.
    direction = np.array([0.48, -0.6, 0.64]) / np.linalg.norm([0.48, -0.6, 0.64])
    theatre.reference_to_tracker = make_transform(translation=direction) @ theatre.reference_to_tracker
    theatre.hold(divot, tilt_deg=25.0)  # touched again, the probe held another way
    result = controller.run("check_checkpoint")
    assert result.alarm and result.label == "C1" and result.distance_mm == pytest.approx(1.0, abs=0.1)
    status = controller.status()
    assert status.message_is_error and status.message.startswith("ALARM: checkpoint C1 moved 1.0")
    assert status.checkpoint_alarm == result.text and "register again" in status.checkpoint_alarm
    assert status.tip_to_surface_mm is None and status.predicted_error_at_tip_mm is None  # not navigated with
    assert node.GetNthControlPointLabel(0) == f"C1: {result.distance_mm:.2f} mm MOVED"

    events = read_session_log(tmp_path / LOG_NAME)  # the recorded session, read back as a later reader does
    assert [event["event"] for event in events] == [
        "registered",
        "checkpoint-stored",
        "checkpoint-stored",
        "checkpoint-checked",
    ]
    checked = events[-1]
    assert checked["alarm"] is True and checked["label"] == "C1"
    assert checked["distance_mm"] == pytest.approx(result.distance_mm) and checked["limit_mm"] == CHECKPOINT_LIMIT_MM
    np.testing.assert_allclose(checked["stored_reference_mm"], stored)
    assert (tmp_path / "Checkpoints.mrk.json").is_file()

    controller.run("register")  # on the probe points touched before the slip: they lie where the bone was
    status = controller.status()
    assert status.checkpoint_alarm and "the CHECKPOINT ALARM stands: 40 of the probe points used" in status.message
    assert status.tip_to_surface_mm is None
    controller.parameters.probePoints = None  # a new list, touched on the bone after the slip
    assert not theatre.register().alarms  # the markers' CR is 1 mm off the bone now: within what it allows
    status = controller.status()
    assert status.checkpoint_alarm == "" and status.checkpoint_count == 0 and status.tip_to_surface_mm is not None
    # C2 was stored before the slip too: it goes with C1, or checking it would raise the alarm again.
    assert "C1, C2 dropped" in status.checkpoint_text
    kinds = [event["event"] for event in read_session_log(tmp_path)]
    assert kinds[4:] == ["registered", "checkpoint-dropped", "registered"]
    assert read_session_log(tmp_path)[5]["labels"] == ["C1", "C2"]
    assert read_session_log(tmp_path)[4]["applied"] is True  # applied, but the alarm stood (stale points)
    theatre.hold(divot)
    assert controller.run("store_checkpoint") == "C1"


@pytest.mark.parametrize("seed", range(12))
def test_slips_of_1_mm_always_alarm_and_retouches_without_a_slip_never_do(theatre, seed):
    """A family of draws: each a new checkpoint on the bone, touched again at a tilt up to 35 degrees with new noise
    (the 0.2 mm tip error turns with the probe), with no slip (no alarm), then after a 1 mm slip of the reference
    body, a translation or a rotation about its bracket 60-150 mm away whose move at the checkpoint is computed by
    hand (an alarm, the distance read to 0.1 mm)."""
    controller = theatre.controller
    theatre.register()
    rng = np.random.default_rng(100 + seed)
    divot = theatre.bone_point(int(rng.integers(len(theatre.patient.ipc))))
    theatre.hold(divot, tilt_deg=rng.uniform(0.0, 35.0))
    controller.run("store_checkpoint")
    theatre.hold(divot, tilt_deg=rng.uniform(0.0, 35.0))
    quiet = controller.run("check_checkpoint")
    assert quiet is not None and not quiet.alarm and quiet.distance_mm < 0.35, controller.status().message
    if seed % 2:
        move = make_transform(translation=rng.normal(size=3))
        move[:3, 3] /= np.linalg.norm(move[:3, 3])  # 1 mm
    else:
        offset = rng.normal(size=3)
        bracket = divot + offset / np.linalg.norm(offset) * rng.uniform(60.0, 150.0)
        axis = np.cross(divot - bracket, rng.normal(size=3))  # across the arm: the divot turns on a circle of it
        turn = rotation_about_axis(axis, 2.0 * np.arcsin(0.5 / np.linalg.norm(divot - bracket)))  # a 1 mm chord
        move = make_transform(turn, bracket - turn @ bracket)
    # The checkpoint's true move in reference coordinates: where the bone point now lies in the moved frame.
    moved = invert_transform(move @ theatre.reference_to_tracker) @ np.append(divot, 1.0)
    expected = np.linalg.norm(
        moved[:3] - apply_transform(invert_transform(theatre.reference_to_tracker), divot[None])[0]
    )
    assert expected == pytest.approx(1.0, abs=0.01)
    theatre.reference_to_tracker = move @ theatre.reference_to_tracker
    theatre.hold(divot, tilt_deg=rng.uniform(0.0, 35.0))
    result = controller.run("check_checkpoint")
    print(f"re-touch {quiet.distance_mm:.2f} mm; after the slip {result.distance_mm:.2f} mm (true {expected:.2f})")
    assert result.alarm and abs(result.distance_mm - expected) < 0.2, (result.distance_mm, expected)


def test_a_check_refuses_a_moving_tip_a_point_far_from_every_checkpoint_and_a_touch_too_noisy_to_tell(theatre):
    controller = theatre.controller
    theatre.register()
    divot = theatre.bone_point(500)
    theatre.hold(divot)
    controller.run("store_checkpoint")
    for k in range(40):  # the tip slides 4 mm over the last 0.7 s
        theatre.frame(divot + (0.1 * k, 0.0, 0.0), np.eye(3))
    assert controller.run("check_checkpoint") is None
    assert "the tip moved" in controller.status().message and "hold it still" in controller.status().message
    theatre.hold(theatre.bone_point(150_000))
    assert controller.run("check_checkpoint") is None
    assert "mm from the nearest checkpoint, C1" in controller.status().message
    controller.parameters.checkpointLimitMm = 0.1  # below what 3 sigma of this touch can tell
    theatre.hold(divot)
    assert controller.run("check_checkpoint") is None
    assert "too noisy to tell a move of 0.10 mm" in controller.status().message
    assert controller.status().checkpoint_alarm == ""


def test_a_session_log_that_cannot_be_set_aside_stays_in_memory(tmp_path, monkeypatch):
    """An unreadable log in a folder where it cannot be renamed must not stop the controller from starting."""
    from pathlib import Path

    from RAMSICPRegistrationLib.io.session_log import LOG_NAME, SessionLog

    (tmp_path / LOG_NAME).write_text("{ not json", encoding="utf-8")

    def refuse(self, target):
        raise PermissionError("read-only folder")

    monkeypatch.setattr(Path, "replace", refuse)
    log = SessionLog(tmp_path)
    assert log.path is None
    assert log.record("checkpoint-stored", label="C1")["event"] == "checkpoint-stored"
    assert (tmp_path / LOG_NAME).read_text(encoding="utf-8") == "{ not json"  # what was there is left untouched
