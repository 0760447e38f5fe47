"""The surgeon's workflow as one Qt-free controller, for every shell (DESIGN.md, "Two shells, one controller").

The Slicer widget, the browser view, scripts and the tests all drive this class and show what it reports; none of
them holds workflow state or observers of its own. It works on the MRML scene it is given and listens to real
MRML events:

* the module's parameter node (``parameters.py``) says which nodes and settings the workflow uses; when a
  selection changes, the transform observers move with it;
* ``TransformModifiedEvent`` of the selected ``probeToReference`` and ``referenceToTracker`` nodes (a matrix update
  sends this event, not ``ModifiedEvent``). A new pose is a change of the node's own transform; a change of its
  parent, which the hierarchy reports with the same event, is not. From these the controller keeps each tool's
  tracking state (valid / stale / waiting), records pivot poses, auto-collects points every N mm, or collects a
  point each time the surgeon holds the tip still (``core.hold_still``: the mean tip over the whole hold);
* the scene's close events: pivot recording and auto-collect stop, every observer on a node is removed, the
  state is reset, and the controller attaches to the parameter node of the new scene.

Actions (``process_ct``, ``start_pivot``, ``collect_point``, ``register`` ...) raise ``WorkflowError`` saying what to
do when an input is missing, as a script expects. A shell calls them through ``run(action, ...)`` instead, which
turns what goes wrong into a message (``status().message`` and the 'message' event) and never raises;
``availability()`` tells beforehand which actions can run and why not (for enabling buttons); ``status()`` is a
snapshot for a shell's periodic refresh; ``add_listener`` reports events as they happen.

Plan and cut (``cutting``): ``plan_cut`` plans the osteotomy on the selected markups plane (endpoints, tool path,
the wedge's second cut), ``save_plan`` writes it as JSON, ``send_tool_path`` sends the path in robot-base
coordinates (``ImageToRobotBase``, eq. 4) to the robot controller over OpenIGTLink and ``stop_robot`` stops it.
While the tracked cutting tool (``toolToTracker`` with ``toolTipToTool``) moves, ``status().guidance`` gives its
distance and angle to the plan and its depth to the far cortex (``core.guidance``), green within the parameter
node's tolerances. A plane moved or a setting changed after planning makes the plan out of date: the path is not
sent until it is planned again. Nothing waits for the robot: ``service()``, which a shell calls from a timer that
runs for as long as the navigation lives (in Slicer the module's logic owns it, so it runs while other modules are
shown), connects, writes and reads the robot link and turns its answer into the status message.
"""

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.guidance import cut_guidance
from ..core.hold_still import HoldStillDetector
from ..core.plane_placement import PlanePlacement, bone_frame, placed_plane, placement_of, placement_through
from ..core.tool_path import plan_document
from ..core.transforms import apply_transform
from ..io.atomic_files import write_json_atomic
from ..io.ndi_tools import DEFAULT_REFERENCE_TOOL
from ..io.session_log import SessionLog
from . import checkpoints, cutting, next_touch
from .mrml_nodes import fiducial_positions
from .navigation import NavigationLogic, matrix_of, points_of
from .parameters import Parameters, get_parameter_node

logger = logging.getLogger(__name__)

#: Seconds without a new pose after which a tracked transform counts as stale (as SlicerIGT's Watchdog).
STALE_AFTER_S = 1.0
#: Seconds the robot controller has to accept (or refuse) a path before the navigation gives up on it.
ROBOT_ANSWER_TIMEOUT_S = 2.0

#: The transforms whose poses the controller follows: parameter name -> the name shown to the user.
WATCHED = {
    "probeToReference": "ProbeToReference",
    "referenceToTracker": "ReferenceToTracker",
    "toolToTracker": "ToolToTracker",
}

#: The controller's actions, by method name: what a shell may ``run``.
ACTIONS = (
    "process_ct",
    "start_pivot",
    "stop_pivot",
    "add_reference_body_markers",
    "collect_point",
    "collect_marker",
    "set_auto_collect",
    "set_hold_still_collect",
    "set_guided_collect",
    "register",
    "accept_registration",
    "set_included",
    "store_checkpoint",
    "check_checkpoint",
    "robot_calibration",
    "place_osteotomy_plane",
    "place_plane_at_tip",
    "plan_cut",
    "save_plan",
    "send_tool_path",
    "stop_robot",
    "save",
)


class WorkflowError(ValueError):
    """An action cannot run: the message says what is missing and what to do."""


class Cancelled(Exception):
    """Raised by a shell's progress callback to stop a long action (the CT processing)."""


@dataclass(frozen=True)
class ToolState:
    """Tracking state of one watched transform: ``valid``, ``stale``, ``waiting`` (no pose yet) or ``not selected``."""

    label: str
    state: str
    age_s: float = None

    @property
    def text(self):
        if self.state == "stale":
            return f"{self.label}: stale (last pose {self.age_s:.1f} s ago)"
        return f"{self.label}: {self.state}"


@dataclass(frozen=True)
class NavigationStatus:
    """What a shell shows, refreshed a few times a second."""

    tools: tuple  # ToolState for each of WATCHED
    pivot_recording: bool
    pivot_poses: int
    auto_collect: bool
    hold_still_collect: bool
    holding: bool  # the tip has been held still long enough: lifting it now collects the point
    probe_poses: int  # new ProbeToReference poses seen since the controller started (or the scene was closed)
    probe_points: int
    marker_points: int
    tip_to_surface_mm: float = None
    predicted_error_at_tip_mm: float = None  # cr-fused: the registration's predicted error where the tip is
    message: str = ""
    message_is_error: bool = False
    tip_reference_mm: tuple = None  # (x, y, z) of the calibrated tip in reference coordinates, while tracked
    guidance: object = None  # core.guidance.CutGuidance of the tracked cutting tool, when there is a plan
    cut: str = ""  # the plan in words ("" before planning)
    robot: str = ""  # the robot's state in words ("" before a path was sent)
    robot_progress: tuple = None  # (poses passed, poses in the path) while a path is out
    # The last registration's alarms while it waits for the user's acceptance (not applied to navigation until
    # then), distinct from its warnings, which inform; and its probe points far from the bone after the CR
    # (numbered from 1), left out of the fit until included by hand.
    alarms: tuple = ()
    warnings: tuple = ()
    far_points: tuple = ()
    # The next touch (issue 26): next_touch.NextTouch after a cr-fused registration with targets, and in words
    # (why there is none, too); guided collection takes only touches near it.
    next_touch: object = None
    next_touch_text: str = ""
    guided_collect: bool = False
    # Checkpoints: how many are stored, the last store or check in words, and the alarm of a checkpoint that moved
    # (the registration no longer holds: navigation readouts are withheld until a new registration).
    checkpoint_count: int = 0
    checkpoint_text: str = ""
    checkpoint_alarm: str = ""
    plane_placement: object = None  # core.plane_placement.PlanePlacement of the selected plane, if it has one

    def tool(self, label):
        return next(tool for tool in self.tools if tool.label == label)


class _PoseWatch:
    """Follows one transform node's own poses: the time of the last one, from its transform's modification time."""

    def __init__(self, node, clock):
        self.node, self.clock = node, clock
        self.mtime = self._mtime()
        self.last_pose_s = None

    def _mtime(self):
        transform = self.node.GetTransformToParent()
        return None if transform is None else transform.GetMTime()

    def new_pose(self):
        """True when the node's own transform changed since the last call (a tracker update, not a parent's)."""
        mtime = self._mtime()
        if mtime == self.mtime:
            return False
        self.mtime, self.last_pose_s = mtime, self.clock()
        return True

    def state(self, label, stale_after_s):
        if self.last_pose_s is None:
            return ToolState(label, "waiting")
        age = self.clock() - self.last_pose_s
        return ToolState(label, "stale" if age > stale_after_s else "valid", age)


class NavigationController:
    """The surgeon's workflow on one MRML scene.

    Args:
        scene: the vtkMRMLScene (``slicer.mrmlScene`` inside Slicer, a ``slicer-core`` scene elsewhere).
        autosave_directory: every collected point list is written there at once, atomically.
        clock: monotonic clock in seconds (for tracking ages).
        stale_after_s: a watched transform without a new pose for longer than this is stale.
        pose_time: optional callable(node) -> the time (s) the node's new pose was measured, for hold-still
            collection; by default the clock when the pose arrives. Our receiver knows each frame's time stamp.
        robot_link_factory: callable(host, port) -> a link to the robot controller that never blocks, with
            ``send_path``, ``poll``, ``stop``, ``close``, ``is_open``, ``state``, ``states_seen``, ``status_text``:
            ``OpenIGTLinkBridgeLib.robot_link.RobotLink``, handed in by
            the shell (the navigation layer sits below the tracker and robot feed and never imports it). Without
            one, planning works and sending the path says that this session has no robot link.
    """

    def __init__(
        self,
        scene,
        autosave_directory=None,
        clock=time.monotonic,
        stale_after_s=STALE_AFTER_S,
        pose_time=None,
        robot_link_factory=None,
    ):
        self.scene = scene
        self.robot_link_factory = robot_link_factory
        self.robot = None  # the link to the robot controller, once a path was sent
        self._robot_answer = None  # (perf_counter when sent, timeout s, ToolPath) while the answer is awaited
        self._processing_ct = False
        self.steps = NavigationLogic(scene, autosave_directory)
        self.session_log = SessionLog(autosave_directory)
        self._tip_frames = checkpoints.TipFrames()
        self.clock, self.stale_after_s = clock, stale_after_s
        self.pose_time = pose_time
        self.last_result = None
        self._listeners = []
        self._scene_tags = []
        self._parameter_observation = None
        self._watches = {}  # parameter name -> _PoseWatch
        self._pose_tags = {}  # parameter name -> (node, tag)
        self._registrations = 0  # registrations run: what the next touch was computed for
        self._reset_state()
        for event, callback in (
            (scene.StartCloseEvent, self._on_scene_start_close),
            (scene.EndCloseEvent, self._on_scene_end_close),
        ):
            self._scene_tags.append(scene.AddObserver(event, callback))
        self._attach_parameter_node()

    # -- wiring --------------------------------------------------------------------------------------------
    @property
    def parameters(self):
        """The workflow's inputs and outputs (``parameters.Parameters`` on the module's parameter node)."""
        return Parameters(get_parameter_node(self.scene))

    def run(self, action, *args, **kwargs):
        """Run an action (a name from ``ACTIONS``) as a shell does: returns its result, or None when it could not
        run, and then says why in ``status().message`` and a 'message' event (with ``is_error`` True)."""
        if action not in ACTIONS:
            raise ValueError(f"unknown action {action!r}; actions are {', '.join(ACTIONS)}")
        try:
            return getattr(self, action)(*args, **kwargs)
        except (ValueError, RuntimeError) as error:  # WorkflowError, bad input, a failed step: all in words
            self._say(str(error), is_error=True)
            return None

    def add_listener(self, callback):
        """Call ``callback(event, data)`` on every event: 'image', 'pivot', 'collected' (data: (points node, index,
        the hold-still Touch or None)), 'auto-collect', 'hold-still', 'registered', 'message' (data: (text,
        is_error)), 'reset', 'planned' (data: the cutting.PlannedCut), 'path-sent' (data: the ToolPath sent, robot
        base), and 'pose' (data: the tool's label, e.g. 'ProbeToReference') for each new pose of a watched tool, at
        the tracker's rate: keep that one cheap. Returns the callback, for ``remove_listener``."""
        self._listeners.append(callback)
        return callback

    def remove_listener(self, callback):
        self._listeners.remove(callback)

    def close(self):
        """Remove every observer this controller added and stop the robot (the shell is going away)."""
        self._drop_robot("the navigation closed")
        self._detach_all()
        for tag in self._scene_tags:
            self.scene.RemoveObserver(tag)
        self._scene_tags = []

    def _notify(self, event, data=None):
        for callback in list(self._listeners):
            try:
                callback(event, data)
            except Exception:  # a shell's display error must not break the workflow
                logger.exception("listener failed on %s", event)

    def _reset_state(self):
        self._pivot_poses = None
        self._auto_collect = False
        self._hold_still = None  # the HoldStillDetector while hold-still collection is on
        self._probe_frames = 0
        self._message = ("", False)
        self._cut = None  # cutting.PlannedCut
        self._pending = None  # a registration with alarms, not applied until accepted
        self._guided = False  # hold-still collection takes only touches near the next touch, then registers
        self._touch = (None, None, "")  # (inputs it was computed from, TouchGuidance or None, targets' name or why not)
        self._checkpoint_errors = {}  # label -> standard error (mm) of the stored position
        self._checkpoint_alarms = {}  # label -> the CheckResult of its last check, while it alarms
        self._points_at_alarm = (None, 0)  # (probe points node ID, points in it) when the first alarm came
        self._stale_points = 0  # probe points touched before the alarm that the last registration used
        self._checkpoint_text = ""
        self._bone_frame = (None, None)  # (IPC key, BoneFrame)
        self._tip_frames.clear()

    def _attach_parameter_node(self):
        node = get_parameter_node(self.scene)
        tags = [node.AddObserver(event, self._on_parameters_modified) for event in _parameter_events(node)]
        self._parameter_observation = (node, tags)
        self._sync_pose_observers()

    def _detach_all(self):
        for name in list(self._pose_tags):
            self._unwatch(name)
        if self._parameter_observation is not None:
            node, tags = self._parameter_observation
            for tag in tags:
                node.RemoveObserver(tag)
            self._parameter_observation = None

    def _on_parameters_modified(self, caller=None, event=None):
        self._sync_pose_observers()

    def _sync_pose_observers(self):
        """Observe the transform nodes selected now; move the observers when a selection changed."""
        node = self._parameter_observation[0] if self._parameter_observation else None
        for name in WATCHED:
            selected = None if node is None else node.GetNodeReference(name)
            current = self._pose_tags.get(name, (None, None))[0]
            if selected is current:
                continue
            self._unwatch(name)
            if selected is not None:
                tag = selected.AddObserver(selected.TransformModifiedEvent, self._on_transform_modified)
                self._pose_tags[name] = (selected, tag)
                self._watches[name] = _PoseWatch(selected, self.clock)
        if self._pivot_poses is not None and "probeToReference" not in self._pose_tags:
            self._pivot_poses = None
            self._say("pivot recording stopped: no ProbeToReference is selected", is_error=True)
        if self._auto_collect and "probeToReference" not in self._pose_tags:
            self.set_auto_collect(False)
        if self._hold_still is not None and "probeToReference" not in self._pose_tags:
            self.set_hold_still_collect(False)

    def _unwatch(self, name):
        observed, tag = self._pose_tags.pop(name, (None, None))
        if observed is not None:
            observed.RemoveObserver(tag)
        self._watches.pop(name, None)

    def _on_scene_start_close(self, caller=None, event=None):
        if self._pivot_poses is not None or self._auto_collect or self._hold_still is not None:
            logger.info("scene closing: pivot recording and point collection stopped")
        self._drop_robot("the scene closed")
        self._detach_all()
        self._reset_state()
        self.last_result = None

    def _on_scene_end_close(self, caller=None, event=None):
        self._attach_parameter_node()
        self._notify("reset")

    # -- tracker events ------------------------------------------------------------------------------------
    def _on_transform_modified(self, caller, event=None):
        name = next((name for name, (node, _) in self._pose_tags.items() if node is caller), None)
        if name is None or not self._watches[name].new_pose():
            return
        self._notify("pose", WATCHED[name])
        if name != "probeToReference":
            return
        self._probe_frames += 1
        tip_node = self.parameters.probeTipToProbe
        if tip_node is not None:
            when = self.clock() if self.pose_time is None else self.pose_time(caller)
            pose = matrix_of(caller, "ProbeToReference") @ matrix_of(tip_node, "ProbeTipToProbe")
            self._tip_frames.add(when, pose[:3, 3])
        if self._pivot_poses is not None:
            self._pivot_poses.append(matrix_of(caller, "ProbeToReference"))
        if self._auto_collect:
            try:
                self._collect(self.parameters.probePoints, "ProbePoints", self.parameters.autoCollectDistanceMm)
            except (ValueError, TypeError, RuntimeError) as error:  # never raise out of an MRML observer
                self.set_auto_collect(False)
                self._say(f"auto-collect stopped: {error}", is_error=True)
        if self._hold_still is not None:
            try:
                pose = matrix_of(caller, "ProbeToReference")  # the pose, not only the tip: a swivel is one touch
                tip = matrix_of(self.parameters.probeTipToProbe, "ProbeTipToProbe")[:3, 3]
                when = self.clock() if self.pose_time is None else self.pose_time(caller)
                touch = self._hold_still.add_pose(pose, tip, when, self._probe_frames)
                if touch is not None:
                    self._add_touch(touch)
            except (ValueError, TypeError, RuntimeError) as error:
                self._hold_still = None
                self._notify("hold-still", False)
                if self._guided:  # guided collection runs through the hold-still detector: it stops with it
                    self._guided = False
                    self._notify("guided-collect", False)
                self._say(f"hold-still collection stopped: {error}", is_error=True)

    def _say(self, message, is_error=False):
        self._message = (message, is_error)
        (logger.warning if is_error else logger.info)(message)
        self._notify("message", self._message)

    # -- what a shell shows --------------------------------------------------------------------------------
    def tool_state(self, name):
        """ToolState of a watched transform (a key of ``WATCHED``)."""
        watch = self._watches.get(name)
        if watch is None:
            return ToolState(WATCHED[name], "not selected")
        return watch.state(WATCHED[name], self.stale_after_s)

    def status(self):
        """A NavigationStatus snapshot, with the tip-to-surface distance when the registration allows it."""
        parameters = self.parameters
        return NavigationStatus(
            tools=tuple(self.tool_state(name) for name in WATCHED),
            pivot_recording=self._pivot_poses is not None,
            pivot_poses=0 if self._pivot_poses is None else len(self._pivot_poses),
            auto_collect=self._auto_collect,
            hold_still_collect=self._hold_still is not None,
            holding=self._hold_still is not None and self._hold_still.holding,
            probe_poses=self._probe_frames,
            probe_points=_count(parameters.probePoints),
            marker_points=_count(parameters.markersPatient),
            tip_to_surface_mm=self._tip_to_surface_mm(parameters),
            predicted_error_at_tip_mm=self._predicted_error_at_tip_mm(parameters),
            message=self._message[0],
            message_is_error=self._message[1],
            tip_reference_mm=self._tip_reference_mm(parameters),
            guidance=self._guidance(parameters),
            cut=self._cut_text(parameters),
            **self._robot_report(),
            **self._registration_report(),
            **self._next_touch_report(parameters),
            guided_collect=self._guided,
            checkpoint_count=_count(parameters.checkpoints),
            checkpoint_text=self._checkpoint_text,
            checkpoint_alarm="\n".join(result.text for result in self._checkpoint_alarms.values()),
            plane_placement=self._plane_placement(parameters),
        )

    def _withheld(self):
        """Why the registration is not to be navigated with now, or None: it waits for the user's acceptance, or a
        checkpoint moved since it was stored (the reference body slipped)."""
        if self._pending is not None:
            return "the registration has alarms and waits for acceptance"
        if self._checkpoint_alarms:
            labels = ", ".join(self._checkpoint_alarms)
            return f"checkpoint {labels} moved since it was stored: the reference body may have slipped"
        return None

    def _tip_reference_mm(self, parameters):
        if parameters.probeTipToProbe is None or self.tool_state("probeToReference").state != "valid":
            return None
        tip = self.steps.tip_in_reference(parameters.probeToReference, parameters.probeTipToProbe)
        return tuple(float(value) for value in tip)

    def tip_position(self):
        """The calibrated probe tip (3,) in world coordinates, mm: image RAS once registered (the transform
        hierarchy ProbeTipToProbe -> ProbeToReference -> ReferenceToImage), the reference frame before; None
        before the pivot calibration. What a view follows with its slices."""
        tip_node = self.parameters.probeTipToProbe
        if tip_node is None:
            return None
        from vtkmodules.vtkCommonMath import vtkMatrix4x4

        matrix = vtkMatrix4x4()
        tip_node.GetMatrixTransformToWorld(matrix)
        return np.array([matrix.GetElement(row, 3) for row in range(3)])

    def _tip_to_surface_mm(self, parameters):
        nodes = (parameters.ipcModel, parameters.probeToReference, parameters.probeTipToProbe)
        if any(node is None for node in nodes) or parameters.referenceToImage is None or self._withheld() is not None:
            return None
        if self.tool_state("probeToReference").state != "valid":
            return None
        try:
            return self.steps.tip_to_surface_mm(*nodes, parameters.referenceToImage)
        except (ValueError, TypeError):
            return None

    def _predicted_error_at_tip_mm(self, parameters):
        result = self.last_result
        if (
            result is None
            or self._withheld() is not None
            or result.pose_covariance is None
            or parameters.probeTipToProbe is None
        ):
            return None
        if parameters.probeToReference is None or self.tool_state("probeToReference").state != "valid":
            return None
        tip = self.steps.tip_in_reference(parameters.probeToReference, parameters.probeTipToProbe)
        tip_image = result.reference_to_image[:3, :3] @ tip + result.reference_to_image[:3, 3]
        return float(result.predicted_error_mm(tip_image[None])[0])

    def _refresh_next_touch(self, parameters):
        """(TouchGuidance or None, the targets' name or why there is none) for the last registration, computed
        again, and drawn (``NextTouch``), only when the registration, its acceptance, the targets, the reachable
        surface or the IPC changed."""
        result = self.last_result
        targets, problem = None, ""
        if result is None:
            problem = ""
        elif self._pending is not None:
            problem = "next touch: accept the registration or register again first"
        else:
            try:
                targets, name = next_touch.guidance_targets(self._cut, parameters.targetsImage)
            except ValueError as error:
                problem = f"next touch: {error}"
        reachable, ipc = parameters.reachableSurface, parameters.ipcModel
        key = (
            self._registrations,
            problem,
            None if targets is None else targets.tobytes(),
            _node_state(reachable),
            _node_state(ipc),
        )
        if self._touch[0] != key:
            guidance, why = None, problem
            if targets is not None:
                try:
                    guidance = next_touch.compute(result, self.steps.surface_index(ipc), targets, reachable)
                    why = name
                except (ValueError, TypeError) as error:
                    why = f"next touch: {error}"
            self._touch = (key, guidance, why)
            next_touch.draw(self.scene, parameters, guidance)
        return self._touch[1], self._touch[2]

    def _next_touch_report(self, parameters):
        """``next_touch`` (next_touch.NextTouch or None) and ``next_touch_text`` for ``status()``."""
        guidance, why = self._refresh_next_touch(parameters)
        if guidance is None:
            return {"next_touch": None, "next_touch_text": why}
        tip = self._tip_reference_mm(parameters)
        tip_image = None
        if tip is not None and parameters.referenceToImage is not None:
            tip_image = apply_transform(matrix_of(parameters.referenceToImage), np.array([tip]))[0]
        touch = next_touch.status_of(guidance, why, parameters.targetTreMm, tip_image)
        return {"next_touch": touch, "next_touch_text": touch.text}

    def _frame(self, parameters):
        """The IPC's BoneFrame (``core.plane_placement``), computed once per IPC."""
        key = _node_state(parameters.ipcModel)
        if self._bone_frame[0] != key:
            self._bone_frame = (key, bone_frame(points_of(parameters.ipcModel, "IPC model")))
        return self._bone_frame[1]

    def _plane_placement(self, parameters):
        """The PlanePlacement of the selected osteotomy plane in the bone's frame, or None (no plane, no IPC, a plane
        along the bone)."""
        plane = parameters.osteotomyPlane
        if plane is None or parameters.ipcModel is None:
            return None
        try:
            return placement_of(self._frame(parameters), *cutting.plane_geometry(plane))
        except (ValueError, TypeError):
            return None

    def availability(self):
        """{action: None when it can run now, else the reason in words} for every action of ``ACTIONS``."""
        parameters = self.parameters
        tracking = self._tracking_problem(parameters)
        calibrated = None if parameters.probeTipToProbe is not None else "calibrate the probe tip (pivot) first"
        collecting = tracking or calibrated
        reasons = {
            "process_ct": self._ct_problem(parameters),
            "start_pivot": tracking if self._pivot_poses is None else "pivot recording is already running",
            "stop_pivot": None if self._pivot_poses is not None else "start pivot recording first",
            "add_reference_body_markers": None,
            "collect_point": collecting,
            "collect_marker": collecting,
            "set_auto_collect": collecting if not self._auto_collect else None,
            "set_hold_still_collect": collecting if self._hold_still is None else None,
            "set_guided_collect": None if self._guided else collecting or self._guided_problem(parameters),
            "register": _first_missing(
                (parameters.ipcModel, "build the IPC from the CT (step 1) or select an IPC model"),
                (parameters.markersImage, "find or place the marker centres in the image (step 1)"),
                (parameters.markersPatient, "add the reference body's marker centres (step 3)"),
                (parameters.probePoints, "collect probe points on the bone (step 3)"),
            ),
            "robot_calibration": _first_missing(
                (parameters.robotPositions, "select the calibrator positions in robot coordinates"),
                (parameters.trackerPositions, "select the calibrator positions in tracker coordinates"),
                (parameters.referenceToTracker, "select ReferenceToTracker"),
                (parameters.referenceToImage, "register first (step 4)"),
            ),
            "accept_registration": None if self._pending is not None else "no registration is waiting for acceptance",
            "set_included": None if parameters.residualTable is not None else "register once first",
            "store_checkpoint": collecting or self._registered_problem(parameters),
            "check_checkpoint": collecting
            or (None if _count(parameters.checkpoints) else "store a checkpoint first (touch a divot or a landmark)"),
            "place_osteotomy_plane": self._ipc_problem(parameters),
            "place_plane_at_tip": self._ipc_problem(parameters) or collecting or self._registered_problem(parameters),
            "plan_cut": _first_missing(
                (
                    parameters.osteotomyPlane,
                    "place the osteotomy plane on the bone first: give its level and angles, or place a plane with "
                    "Slicer's Markups toolbar and select it",
                ),
                (parameters.ipcModel, "build the IPC from the CT (step 1) or select an IPC model"),
            ),
            "save_plan": self._plan_problem(parameters),
            "send_tool_path": self._plan_problem(parameters)
            or (None if not self._checkpoint_alarms else self._withheld())
            or self._robot_problem(parameters),
            "stop_robot": None if self.robot is not None and self.robot.is_open else "no path was sent to the robot",
            "save": None,
        }
        return reasons

    def _ipc_problem(self, parameters):
        return None if parameters.ipcModel is not None else "build the IPC from the CT (step 1) or select an IPC model"

    def _registered_problem(self, parameters):
        """Why the registration cannot be used now (none applied, or withheld), or None."""
        if parameters.referenceToImage is None or self.last_result is None:
            return "register first (step 4)"
        return self._withheld()

    def _guided_problem(self, parameters):
        guidance, why = self._refresh_next_touch(parameters)
        if guidance is None:
            return why or "register with cr-fused first (step 4)"
        bound = float(np.max(guidance.predicted_tre_95_mm))
        if bound < parameters.targetTreMm:
            return (
                f"enough touches already: every target within {bound:.2f} mm with 95 % confidence (limit "
                f"{parameters.targetTreMm:g} mm); lower the limit to collect more"
            )
        return None

    def _ct_problem(self, parameters):
        if self._processing_ct:
            return "the CT is being processed; wait for it to finish or cancel it"
        return None if parameters.ctVolume is not None else "select the CT volume"

    def _plan_problem(self, parameters):
        if self._cut is None:
            return "plan the cut first"
        if cutting.cut_inputs(parameters) != self._cut.inputs:
            return "the plane or a setting of the cut changed since it was planned; plan the cut again"
        return None

    def _robot_problem(self, parameters):
        if self.robot_link_factory is None:
            return "this session has no link to a robot (start navigation from the Slicer module or ramsicp web)"
        if parameters.imageToRobotBase is None:
            return "calibrate the robot first (step 6): the path goes to the robot through ImageToRobotBase"
        if self.robot is not None and self.robot.is_open and self.robot.state in ("SENT", "ACCEPTED", "MOVING"):
            return "the robot is still on the last path; wait for it or stop it"
        return None

    def _tracking_problem(self, parameters):
        if parameters.probeToReference is None:
            return "select ProbeToReference (the tracked probe) in step 2"
        state = self.tool_state("probeToReference")
        if state.state == "valid":
            return None
        age = "never" if state.age_s is None else f"{state.age_s:.1f} s ago"
        return (
            f"ProbeToReference is not updating (last pose: {age}); check that the tracker sees the probe and the "
            "reference body"
        )

    def _require(self, action):
        reason = self.availability()[action]
        if reason is not None:
            raise WorkflowError(reason)

    # -- 1. image ------------------------------------------------------------------------------------------
    def process_ct(self, progress=None):
        """Segment the selected CT, build the IPC and find the marker spheres; returns ImageSideNodes.

        ``progress(step, done, total)`` may raise ``Cancelled``: the run then stops, nothing is written and None is
        returned. While it runs, ``process_ct`` is unavailable: a shell whose progress callback processes events (a
        click may arrive) cannot start a second run.
        """
        self._require("process_ct")
        parameters = self.parameters
        self._processing_ct = True  # a shell's progress callback processes events: a second click must not start again
        try:
            image = self.steps.process_ct(parameters.ctVolume, parameters.thresholdHU, progress=progress)
        except Cancelled:
            self._say("CT processing cancelled; nothing was changed", is_error=True)
            return None
        finally:
            self._processing_ct = False
        self._say("; ".join(image.warnings) or "IPC and marker centres ready", is_error=bool(image.warnings))
        self._notify("image", image)
        return image

    # -- 2. tracker ----------------------------------------------------------------------------------------
    def start_pivot(self):
        """Record every new ProbeToReference pose until ``stop_pivot``; the tip rests in a divot meanwhile."""
        self._require("start_pivot")
        self._pivot_poses = []
        self._say("pivot recording: swivel the probe about its tip")
        self._notify("pivot", None)

    def stop_pivot(self):
        """Stop recording and calibrate ``ProbeTipToProbe`` from the poses (created when not selected)."""
        self._require("stop_pivot")
        poses, self._pivot_poses = self._pivot_poses, None
        parameters = self.parameters
        tip_node = parameters.probeTipToProbe or self.steps.transform_node("ProbeTipToProbe")
        try:
            result = self.steps.pivot_calibrate(np.array(poses).reshape(-1, 4, 4), tip_node)
        except ValueError as error:
            self._notify("pivot", None)
            raise WorkflowError(f"pivot calibration failed: {error}") from None
        parameters.probeTipToProbe = tip_node
        if parameters.probeToReference is not None and tip_node.GetParentTransformNode() is None:
            tip_node.SetAndObserveTransformNodeID(parameters.probeToReference.GetID())
        self._say(pivot_summary(result))
        self._notify("pivot", result)
        return result

    # -- 3. patient points ---------------------------------------------------------------------------------
    def add_reference_body_markers(self, tool_id=DEFAULT_REFERENCE_TOOL):
        """``markersPatient`` from the reference body's NDI geometry (its marker centres in its own frame)."""
        node = self.steps.markers_patient_node(tool_id)
        self._say(f"marker centres of NDI {tool_id} added")
        self._notify("collected", (node, None, None))
        return node

    def collect_point(self):
        """Add the probe tip to ``probePoints`` (created when not selected); returns the point's index."""
        self._require("collect_point")
        return self._collect(self.parameters.probePoints, "ProbePoints")

    def collect_marker(self):
        """Touch a marker sphere's centre (a calibrated divot) into ``markersPatient``; returns its index."""
        self._require("collect_marker")
        parameters = self.parameters
        image_count = _count(parameters.markersImage)
        if image_count and _count(parameters.markersPatient) >= image_count:
            raise WorkflowError(
                f"{parameters.markersPatient.GetName()} already holds {image_count} centres, as many as the image; "
                "delete one to touch it again"
            )
        return self._collect(parameters.markersPatient, "MarkersPatient")

    def _collect(self, node, default_name, min_distance_mm=None):
        parameters = self.parameters
        role = "markersPatient" if default_name == "MarkersPatient" else "probePoints"
        if node is None:
            node = self.scene.AddNewNodeByClass("vtkMRMLMarkupsFiducialNode", default_name)
            setattr(parameters, role, node)
        index = self.steps.collect_point(
            node, parameters.probeToReference, parameters.probeTipToProbe, min_distance_mm=min_distance_mm
        )
        if index is not None:
            self._notify("collected", (node, index, None))
        return index

    def set_auto_collect(self, enabled):
        """Collect a probe point whenever the tip has moved ``autoCollectDistanceMm`` from the last one. Turns
        hold-still collection off: one collection mode at a time."""
        if enabled:
            self._require("set_auto_collect")
        if bool(enabled) == self._auto_collect:
            return
        if enabled:
            self.set_hold_still_collect(False)
        self._auto_collect = bool(enabled)
        if enabled:
            spacing = self.parameters.autoCollectDistanceMm
            self._say(f"auto-collect on: a point every {spacing:g} mm")
        self._notify("auto-collect", self._auto_collect)

    def set_hold_still_collect(self, enabled):
        """Collect a probe point each time the tip is held still (within ``holdStillMm`` for ``holdStillS``): the
        point is the mean tip over the whole hold, taken when the tip moves away (or when this is turned off).
        Turns auto-collect off: one collection mode at a time."""
        if not enabled:
            if self._hold_still is not None:
                touch, self._hold_still = self._hold_still.finish(end_of_recording=False), None
                if touch is not None:
                    self._add_touch(touch)
                self._notify("hold-still", False)
            if self._guided:
                self._guided = False
                self._notify("guided-collect", False)
            return
        self._require("set_hold_still_collect")
        if self._hold_still is not None:
            return
        self.set_auto_collect(False)
        parameters = self.parameters
        self._hold_still = HoldStillDetector(parameters.holdStillMm, parameters.holdStillS)
        probe = parameters.probeToReference  # its pose now comes first: a probe lying still since then is a rest
        when = self.clock() if self.pose_time is None else self.pose_time(probe)
        tip = matrix_of(parameters.probeTipToProbe, "ProbeTipToProbe")[:3, 3]
        self._hold_still.add_pose(matrix_of(probe, "ProbeToReference"), tip, when, self._probe_frames)
        self._say(
            f"hold-still collection on: hold the tip still for {parameters.holdStillS:g} s "
            f"(within {parameters.holdStillMm:g} mm), then lift it"
        )
        self._notify("hold-still", True)

    def set_guided_collect(self, enabled):
        """Hold-still collection that follows the next touch (issue 26): a touch within ``GUIDED_RADIUS_MM`` of the
        point drawn on the bone is collected, the patient registered again at once and the next touch moved on; a
        touch elsewhere is not collected. It stops by itself when the touches are enough (every target's 95 % bound
        below ``targetTreMm``), when a registration raises an alarm, or when hold-still collection is turned off."""
        if not enabled:  # and the hold-still collection it turned on
            if self._guided:
                self._stop_guided("guided collection off")
            return
        self._require("set_guided_collect")
        self.set_hold_still_collect(True)
        self._guided = True
        self._say(
            f"guided collection on: touch the point drawn on the bone (within {next_touch.GUIDED_RADIUS_MM:g} mm), "
            "hold still, then lift; the registration follows each touch"
        )
        self._notify("guided-collect", True)

    def _add_touch(self, touch):
        if touch.rest:  # the probe lay still since collection began: not a touch of anything
            self._say(
                f"not collected: the probe lay still for {touch.duration_s:.1f} s since collection began (a rest)"
            )
            return
        if self._guided and not self._near_next_touch(touch.position):
            return
        parameters = self.parameters
        node = parameters.probePoints
        if node is None:
            node = self.scene.AddNewNodeByClass("vtkMRMLMarkupsFiducialNode", "ProbePoints")
            parameters.probePoints = node
        index = self.steps.add_point(node, touch.position)
        self._say(
            f"point {index + 1} collected: {touch.kind} of {touch.duration_s:.2f} s over {touch.frames} frames, "
            f"spread {touch.spread_mm:.2f} mm"
        )
        self._notify("collected", (node, index, touch))
        if self._guided:
            self._register_guided(index)

    def _near_next_touch(self, position):
        """Guided collection: True when a touch at ``position`` (reference coordinates) lies near the next touch;
        otherwise says why it is not collected (and stops guided collection when there is no next touch)."""
        guidance, why = self._refresh_next_touch(self.parameters)
        if guidance is None:
            self._stop_guided(f"guided collection stopped: {why or 'no next touch'}", is_error=True)
            return False
        touched = apply_transform(self.last_result.reference_to_image, np.asarray(position)[None])[0]
        distance = float(np.linalg.norm(touched - guidance.next_touch.position_image))
        if distance > next_touch.GUIDED_RADIUS_MM:
            self._say(
                f"not collected: that touch was {distance:.1f} mm from the point drawn on the bone (within "
                f"{next_touch.GUIDED_RADIUS_MM:g} mm is taken); touch the drawn point",
                is_error=True,
            )
            return False
        return True

    def _stop_guided(self, message=None, is_error=False):
        """End guided collection and the hold-still collection under it; say ``message`` (after the last touch's). A
        hold under way is dropped, not collected: it was meant as a guided touch, and unguided it would be taken
        wherever it is."""
        self._guided = False
        if self._hold_still is not None:
            self._hold_still = None
            self._notify("hold-still", False)
        self._notify("guided-collect", False)
        if message:
            self._say(message, is_error=is_error)

    def _register_guided(self, index):
        """After a guided touch: register again; stop when it alarms or the touches are enough."""
        try:
            result = self.register()
        except (ValueError, RuntimeError) as error:
            self._stop_guided(f"guided collection stopped: the registration failed: {error}", is_error=True)
            return
        if result.alarms:
            self._stop_guided()  # register() said the alarm
            return
        parameters = self.parameters
        report = self._next_touch_report(parameters)
        touch = report["next_touch"]
        if touch is None:
            self._stop_guided(f"guided collection stopped: {report['next_touch_text']}", is_error=True)
        elif touch.enough:
            self._stop_guided(
                f"ENOUGH after {index + 1} probe points: every target within {touch.bound_95_mm:.2f} mm with 95 % "
                f"confidence (limit {touch.target_tre_mm:g} mm), predicted error {touch.predicted_tre_mm:.2f} mm; "
                "guided collection stopped"
            )
        else:
            self._say(
                f"point {index + 1} collected and registered: predicted error {touch.predicted_tre_mm:.2f} mm (95 % "
                f"bound {touch.bound_95_mm:.2f} mm, limit {touch.target_tre_mm:g} mm); the next touch is drawn, it "
                f"brings {touch.predicted_tre_after_mm:.2f} mm"
            )

    # -- 4. register ---------------------------------------------------------------------------------------
    def register(self):
        """Register with the selected method and policy; the probe then moves over the CT. Returns the result."""
        self._require("register")
        parameters = self.parameters
        method = parameters.method
        result = self.steps.register(
            parameters.ipcModel,
            parameters.probePoints,
            parameters.markersImage,
            parameters.markersPatient,
            parameters.targetsImage,
            parameters.targetsPatient,
            method=method,
            sweep=True,
            policy=parameters.policy if method == "cr-ramsicp" else None,
        )
        self.last_result = result
        self._registrations += 1
        self._pending = result if result.alarms else None
        if result.alarms:  # an alarm stops: not applied to navigation until the user accepts it
            self._say(
                f"ALARM, registration not applied: {result.alarms[0]} ({len(result.alarms)} alarm(s); accept the "
                "registration to navigate with it anyway)",
                is_error=True,
            )
        else:
            self._apply(result)
            self._say(registration_summary(result) + self._checkpoint_note())
        self.session_log.record(
            "registered",
            applied=not result.alarms,
            points=len(result.residuals_mm),
            **_result_figures(result),
        )
        self._notify("registered", result)
        return result

    def accept_registration(self):
        """Apply the registration whose alarms the user has read (``status().alarms``) to navigation."""
        self._require("accept_registration")
        result, self._pending = self._pending, None
        self._apply(result)
        self.session_log.record("accepted", **_result_figures(result))
        self._say(
            f"registration accepted despite {len(result.alarms)} alarm(s): {registration_summary(result)}"
            + self._checkpoint_note()
        )
        self._notify("accepted", result)
        return result

    def _apply(self, result):
        """ReferenceToImage from ``result``, and the probe under it: the probe then moves over the CT. After a
        checkpoint alarm, a registration on probe points all touched since then clears it (``_after_slip``)."""
        parameters = self.parameters
        self.steps.apply_registration(result)
        self._after_slip(parameters)
        if parameters.probeTipToProbe is not None and parameters.probeToReference is not None:
            self.steps.build_hierarchy(
                parameters.probeTipToProbe, parameters.probeToReference, parameters.referenceToImage
            )

    def _registration_report(self):
        """The last registration's alarms (while unaccepted), warnings and far probe points, for ``status()``."""
        result = self.last_result
        if result is None:
            return {}
        alarms = () if self._pending is None else tuple(result.alarms)
        warnings = tuple(warning for warning in result.warnings if warning not in result.alarms)
        return {"alarms": alarms, "warnings": warnings, "far_points": tuple(self.steps.far_points())}

    def set_included(self, point_index, included):
        """Include or exclude probe point ``point_index`` (0-based) from the next registration."""
        self.steps.set_included(point_index, included)

    # -- 5. verify: checkpoints ----------------------------------------------------------------------------
    def store_checkpoint(self):
        """Store the tip held still on the bone (a divot, a landmark) as checkpoint ``C<n>``, in reference
        coordinates (``checkpoints``): the mean tip over the last ``checkpoints.HOLD_S`` seconds. Touch it again
        later with ``check_checkpoint``. Returns its label."""
        self._require("store_checkpoint")
        parameters = self.parameters
        held = self._held_tip(parameters)
        node = checkpoints.checkpoint_node(self.scene, parameters, parameters.referenceToImage)
        _, labels = checkpoints.stored(node)
        label = f"C{max([int(name[1:]) for name in labels if name[1:].isdigit()], default=0) + 1}"
        node.AddControlPoint(held.position.tolist(), label)
        self._checkpoint_errors[label] = held.standard_error_mm
        self.steps.autosave(node)
        self.session_log.record(
            "checkpoint-stored",
            label=label,
            position_reference_mm=held.position.tolist(),
            standard_error_mm=held.standard_error_mm,
            frames=held.frames,
        )
        self._checkpoint_text = (
            f"checkpoint {label} stored (mean of {held.frames} frames, spread {held.spread_mm:.2f} mm): touch it again "
            "later and press Check to find out whether the reference body moved"
        )
        self._say(self._checkpoint_text)
        self._notify("checkpoint", (label, None))
        return label

    def check_checkpoint(self):
        """Touch a stored checkpoint again: how far (mm, reference coordinates) the held tip lies from where it was
        stored; beyond ``checkpointLimitMm`` an alarm (the reference body slipped), shown in every shell and
        written into the session log. Returns the ``checkpoints.CheckResult``."""
        self._require("check_checkpoint")
        parameters = self.parameters
        held = self._held_tip(parameters)
        node = parameters.checkpoints
        positions, labels = checkpoints.stored(node)
        errors = [self._checkpoint_errors.get(label, 0.0) for label in labels]
        try:
            result = checkpoints.check(positions, errors, labels, held, parameters.checkpointLimitMm)
        except ValueError as error:
            raise WorkflowError(str(error)) from None
        if result.alarm:
            if not self._checkpoint_alarms:  # the probe points touched before this lie in the frame that moved
                points = parameters.probePoints
                self._points_at_alarm = (None, 0) if points is None else (points.GetID(), _count(points))
            self._checkpoint_alarms[result.label] = result
        else:
            self._checkpoint_alarms.pop(result.label, None)
        checkpoints.show_check(node, result, alarming=bool(self._checkpoint_alarms))
        self.session_log.record(
            "checkpoint-checked",
            label=result.label,
            distance_mm=result.distance_mm,
            sigma_mm=result.sigma_mm,
            limit_mm=result.limit_mm,
            alarm=result.alarm,
            position_reference_mm=held.position.tolist(),
            stored_reference_mm=positions[labels.index(result.label)].tolist(),
            frames=held.frames,
        )
        self._checkpoint_text = result.text
        self._say(result.text, is_error=result.alarm)
        self._notify("checkpoint", (result.label, result))
        return result

    def _held_tip(self, parameters):
        try:
            return self._tip_frames.held(self._tip_frames.latest_s, parameters.holdStillMm)
        except ValueError as error:
            raise WorkflowError(str(error)) from None

    def _checkpoint_note(self):
        """What a registration's message adds while a checkpoint alarm stands."""
        if not self._checkpoint_alarms:
            return ""
        return (
            f"; the CHECKPOINT ALARM stands: {self._stale_points} of the probe points used were touched before the "
            "reference body moved; untick them ('include') or collect a new list, then register again"
        )

    def _after_slip(self, parameters):
        """A registration applied after a checkpoint alarm: when none of the probe points it used was touched
        before the alarm (they lie in the frame the reference body left), the checkpoints that moved are dropped
        (stored where the reference body sat before) and the alarm cleared; otherwise the alarm stands."""
        self._stale_points = 0
        if not self._checkpoint_alarms:
            return
        node_id, count = self._points_at_alarm
        points = parameters.probePoints
        table = parameters.residualTable
        if points is not None and points.GetID() == node_id and table is not None and count:
            include = table.GetTable().GetColumnByName("include")
            self._stale_points = sum(bool(include.GetValue(row)) for row in range(min(count, table.GetNumberOfRows())))
        if self._stale_points:
            return
        node = parameters.checkpoints
        dropped = list(self._checkpoint_alarms)
        self._checkpoint_alarms = {}
        if node is not None:
            # Every checkpoint was stored where the reference body sat before it slipped, the ones not checked yet
            # too: all of them are dropped, or the next check of one would raise the alarm again.
            _, labels = checkpoints.stored(node)
            dropped = list(dict.fromkeys([*dropped, *labels]))
            node.RemoveAllControlPoints()
            checkpoints.show_check(node, None, alarming=False)
            self.steps.autosave(node)
        for label in dropped:
            self._checkpoint_errors.pop(label, None)
        self.session_log.record(
            "checkpoint-dropped", labels=dropped, reason="the reference body moved; registered again"
        )
        self._checkpoint_text = (
            f"checkpoint {', '.join(dropped)} dropped after the new registration (the reference body had moved): "
            "store them again"
        )

    # -- 6. robot ------------------------------------------------------------------------------------------
    def robot_calibration(self):
        """Eqs. 3-4 from the selected calibrator positions: writes RobotBaseToTracker and ImageToRobotBase."""
        self._require("robot_calibration")
        parameters = self.parameters
        nodes = self.steps.robot_calibration(
            points_of(parameters.robotPositions, "robot positions"),
            points_of(parameters.trackerPositions, "tracker positions"),
            parameters.referenceToTracker,
            parameters.referenceToImage,
        )
        self._say("robot calibrated: ImageToRobotBase written")
        return nodes

    # -- 7. plan and cut -----------------------------------------------------------------------------------
    def place_osteotomy_plane(self, level_mm=None, tilt_anterior_deg=None, tilt_side_deg=None, entry_deg=None):
        """Place the osteotomy plane by numbers in the bone's frame (``core.plane_placement``): ``level_mm`` below the
        bone's top, its tilts from square to the bone's axis towards anterior and towards the side (degrees), and
        the side the blade enters from (degrees around the bone, 0 anterior). A value left None keeps the selected
        plane's (a new plane: the bone's middle, square to it, entered from anterior). Creates ``OsteotomyPlane``
        when no plane is selected. Returns the PlanePlacement."""
        self._require("place_osteotomy_plane")
        parameters = self.parameters
        frame = self._frame(parameters)
        current = self._plane_placement(parameters) or PlanePlacement(level_mm=frame.length_mm / 2.0)
        given = (level_mm, tilt_anterior_deg, tilt_side_deg, entry_deg)
        kept = (current.level_mm, current.tilt_anterior_deg, current.tilt_side_deg, current.entry_deg)
        values = [float(kept[i]) if value is None or value == "" else float(value) for i, value in enumerate(given)]
        return self._put_plane(parameters, frame, PlanePlacement(*values))

    def place_plane_at_tip(self):
        """Place the osteotomy plane through the tracked probe tip on the bone (registered into the image), with the
        selected plane's tilts: the blade enters from the side the tip touches. Returns the PlanePlacement."""
        self._require("place_plane_at_tip")
        parameters = self.parameters
        frame = self._frame(parameters)
        tip = self.steps.tip_in_reference(parameters.probeToReference, parameters.probeTipToProbe)
        tip_image = apply_transform(matrix_of(parameters.referenceToImage), tip[None])[0]
        current = self._plane_placement(parameters) or PlanePlacement(level_mm=0.0)
        try:
            placement = placement_through(frame, tip_image, current.tilt_anterior_deg, current.tilt_side_deg)
        except ValueError as error:
            raise WorkflowError(str(error)) from None
        return self._put_plane(parameters, frame, placement)

    def _put_plane(self, parameters, frame, placement):
        """Write a PlanePlacement into the selected plane (``OsteotomyPlane``, created when none is selected)."""
        try:
            origin, normal, depth = placed_plane(frame, placement)
        except ValueError as error:
            raise WorkflowError(str(error)) from None
        plane = parameters.osteotomyPlane
        if plane is None:
            plane = self.scene.AddNewNodeByClass("vtkMRMLMarkupsPlaneNode", "OsteotomyPlane")
            plane.CreateDefaultDisplayNodes()
            plane.SetSizeMode(plane.SizeModeAbsolute)
            plane.SetSize(60.0, 60.0)
            parameters.osteotomyPlane = plane
        plane.SetOriginWorld(origin.tolist())
        plane.SetAxesWorld(np.cross(depth, normal).tolist(), depth.tolist(), normal.tolist())
        self._say(
            f"osteotomy plane placed {placement.level_mm:.1f} mm below the bone's top, tilted "
            f"{placement.tilt_anterior_deg:.1f} degrees anterior and {placement.tilt_side_deg:.1f} degrees to the "
            f"side, the blade entering at {placement.entry_deg:.0f} degrees; plan the cut on it"
        )
        self._notify("plane", placement)
        return placement

    def plan_cut(self):
        """Plan the osteotomy on the selected plane (``cutting``): each cut's endpoints, the tool path and, for a
        wedge, the second cut, written into the scene. With no verification targets selected yet the endpoints
        become them (the paper's targets). Returns the ``cutting.PlannedCut``."""
        self._require("plan_cut")
        parameters = self.parameters
        planned = cutting.plan_from_nodes(parameters)
        cutting.write_plan_nodes(self.scene, parameters, planned)
        self._cut = cutting.PlannedCut(planned.plans, planned.path, cutting.cut_inputs(parameters))
        if parameters.targetsImage is None:
            parameters.targetsImage = parameters.cutEndpoints
        self._say(self._cut_text(parameters))
        self._notify("planned", self._cut)
        return self._cut

    def save_plan(self, path):
        """Write the plan as JSON (``core.tool_path.plan_document``; in robot-base coordinates too once the robot is
        calibrated); returns the path."""
        self._require("save_plan")
        parameters = self.parameters
        image_to_base = None if parameters.imageToRobotBase is None else matrix_of(parameters.imageToRobotBase)
        document = plan_document(self._cut.plans, self._cut.path, image_to_base)
        path = Path(path)
        if path.is_dir():
            raise WorkflowError(f"{path} is a folder; give a file name ending in .json")
        try:
            write_json_atomic(path, document)
        except OSError as error:
            raise WorkflowError(f"cannot write the plan to {path} ({error.strerror or error})") from None
        self._say(f"plan written to {path}")
        return path

    def send_tool_path(self, timeout_s=ROBOT_ANSWER_TIMEOUT_S):
        """Send the tool path in robot-base coordinates (``ImageToRobotBase`` @ each pose, eq. 4) to the robot
        controller at ``robotHost``:``robotPort``; returns the ToolPath sent, at once.

        Nothing here waits for the network (this runs on Slicer's GUI thread): the link connects and writes without
        blocking, and ``service()`` (a timer's work) reads the robot's answer. No answer within ``timeout_s`` (s),
        a refusal or an unreachable robot become an error message then, and the link is closed.
        """
        self._require("send_tool_path")
        parameters = self.parameters
        path = self._cut.path.in_robot_base(matrix_of(parameters.imageToRobotBase, "ImageToRobotBase"))
        host, port = parameters.robotHost.strip(), parameters.robotPort
        if not host:
            raise WorkflowError("the robot controller's address is empty; give its host, e.g. 127.0.0.1")
        if self.robot is None or not self.robot.is_open or (self.robot.host, self.robot.port) != (host, port):
            self._drop_robot("another robot address")
            self.robot = self._connect_robot(host, port)
        if not self.robot.is_open:  # refused at once (nothing listens on that port)
            raise WorkflowError(self.robot.status_text)
        try:
            self.robot.send_path(path.poses)
        except OSError as error:
            raise WorkflowError(str(error)) from None
        self._robot_answer = (time.perf_counter(), timeout_s, path)
        self._say(
            f"path sent to the robot at {host}:{port}: {len(path.poses)} poses, {path.passes} passes, "
            f"{path.length_mm:.0f} mm; waiting for its answer"
        )
        self._notify("path-sent", path)
        self.service()
        return path

    def service(self):
        """Advance the robot link: connect, write, read its reports, and judge the answer to the path sent. Never
        waits. A shell calls it from a timer for as long as the navigation lives, whichever module or page is
        shown (Slicer: the module's logic owns that timer), because a robot controller drops a client that stops
        reading, and the robot then stops mid-cut."""
        link = self.robot
        if link is None:
            return
        try:
            link.poll()
        except OSError as error:
            logger.warning("robot link: %s", error)
        if self._robot_answer is None:
            return
        sent_at, timeout_s, path = self._robot_answer
        seen = link.states_seen
        if "REFUSED" in seen:
            self._robot_answer = None
            self._say(f"the robot refused the path: {link.status_text}", is_error=True)
        elif seen & {"ACCEPTED", "MOVING", "DONE"}:
            self._robot_answer = None
            self._say(
                f"the robot at {link.host}:{link.port} accepted the path ({len(path.poses)} poses) "
                f"{1000 * (time.perf_counter() - sent_at):.0f} ms after sending began"
            )
        elif not link.is_open:
            self._robot_answer = None
            self._say(link.status_text, is_error=True)
        elif time.perf_counter() - sent_at > timeout_s:
            self._robot_answer = None
            self._say(
                f"the robot at {link.host}:{link.port} did not accept the path within {timeout_s:g} s "
                f"({link.status_text}); the connection was closed",
                is_error=True,
            )
            self._drop_robot("no answer to the path")

    def stop_robot(self):
        """Tell the robot to stop where it is (a path not wholly sent yet is cancelled)."""
        self._require("stop_robot")
        try:
            self.robot.stop()
        except OSError as error:
            raise WorkflowError(str(error)) from None
        self._robot_answer = None
        self._say("STOP sent to the robot")

    def _connect_robot(self, host, port):
        return self.robot_link_factory(host, port)

    def _drop_robot(self, why):
        """Stop the robot and close the link (a navigation that goes away must not leave the robot moving)."""
        self._robot_answer = None
        if self.robot is None:
            return
        try:
            if self.robot.is_open and self.robot.state in ("SENT", "ACCEPTED", "MOVING"):
                self.robot.stop()
                logger.warning("robot stopped: %s", why)
        except OSError:
            pass
        self.robot.close()
        self.robot = None

    def _guidance(self, parameters):
        """CutGuidance of the tracked tool while it and the reference body are tracked and a plan exists (not while a
        registration with alarms waits for acceptance)."""
        if (
            self._cut is None
            or self._withheld() is not None
            or any(self.tool_state(name).state != "valid" for name in ("toolToTracker", "referenceToTracker"))
        ):
            return None
        try:
            pose = cutting.tool_tip_to_image(parameters)
            if pose is None:
                return None
            return cut_guidance(
                self._cut.plans,
                pose,
                tool=parameters.cuttingTool,
                width_mm=parameters.toolWidthMm,
                distance_tolerance_mm=parameters.guidanceDistanceMm,
                angle_tolerance_deg=parameters.guidanceAngleDeg,
            )
        except (ValueError, TypeError):
            return None

    def _cut_text(self, parameters):
        if self._cut is None:
            return ""
        path, plans = self._cut.path, self._cut.plans
        cuts = "one cut" if len(plans) == 1 else f"a {parameters.wedgeAngleDeg:g} degree wedge of two cuts"
        text = (
            f"plan: {cuts}, endpoints {'E1-E4' if len(plans) == 1 else 'E1-E4 and W1-W4'}; {path.tool} path "
            f"{len(path.poses)} poses in {path.passes} passes, {path.length_mm:.0f} mm"
        )
        predicted = self._predicted_endpoint_errors()
        if predicted is not None:
            text += f"; predicted registration error at the endpoints {predicted.min():.2f}-{predicted.max():.2f} mm"
        if self._plan_problem(parameters) is not None:
            text = "OUT OF DATE, plan again: " + text
        return text

    def _predicted_endpoint_errors(self):
        """The registration's predicted error (mm) at each endpoint (cr-fused), else None."""
        result = self.last_result
        if result is None or result.pose_covariance is None:
            return None
        return np.asarray(result.predicted_error_mm(self._cut.endpoints))

    def _robot_report(self):
        link = self.robot
        if link is None:
            return {"robot": "", "robot_progress": None}
        words = {
            "CONNECTING": "connecting",
            "CONNECTED": "connected",
            "SENT": "path sent, waiting for its answer",
            "ACCEPTED": "path accepted",
            "MOVING": f"moving: pose {link.passed} of {link.path_size}",
            "DONE": "done: the whole path was run",
            "REFUSED": f"refused the path: {link.status_text}",
            "STOPPED": f"stopped: {link.status_text}",
            "DISCONNECTED": f"disconnected: {link.status_text}",
        }.get(link.state, link.state.lower())
        return {"robot": f"robot at {link.host}:{link.port}: {words}", "robot_progress": (link.passed, link.path_size)}

    # -- 8. save -------------------------------------------------------------------------------------------
    def save(self, path):
        """Save the scene and every node's data as ``path``: a ``.mrb`` bundle, or a ``.mrml`` scene with its data
        files beside it (``NavigationLogic.save``); returns the files written (the scene first). Every shell saves
        through here, the Slicer module included."""
        try:
            written = self.steps.save(path)
        except ValueError as error:
            raise WorkflowError(str(error)) from None
        if len(written) == 1:
            self._say(f"scene saved with all its data: {path}")
        else:
            self._say(f"scene saved: {path} and {len(written) - 1} data files")
        return written


def pivot_summary(result):
    """One line for the surgeon about a pivot calibration."""
    kept = int(result.inliers.sum())
    return (
        f"pivot: tip at {np.linalg.norm(result.tip_in_probe):.1f} mm from the probe origin, RMS {result.rms_mm:.2f} mm "
        f"from {kept} of {len(result.inliers)} poses, swivel {result.rotation_range_deg:.0f} degrees"
    )


def registration_summary(result):
    """What both shells show about a registration: method, FRE, probe points, TRE with its prediction, and for
    cr-fused the weights it used."""
    tre = "" if result.tre_mm is None else f", TRE {result.tre_mm:.2f} mm"
    if result.predicted_tre_rms_mm is not None:
        tre += f" (predicted {result.predicted_tre_rms_mm:.2f} mm)"
    elif result.predicted_cr_tre_mm is not None:
        tre += f", CR TRE predicted {np.max(result.predicted_cr_tre_mm):.2f} mm (FLE {result.fle_mm:.2f} mm)"
    scale = "" if result.scale is None else f", L = {result.scale:g} ({result.scale_policy})"
    text = (
        f"{result.method.upper()}{scale}: FRE {result.fre_mm:.2f} mm, probe points {result.ppc_rms_mm:.2f} mm RMS "
        f"from the bone{tre}"
    )
    if result.fused_weights is not None:
        text += f"; weights: {result.fused_weights.describe()}"
    return text


def _result_figures(result):
    """A registration's figures for the session log (mm)."""
    return {
        "method": result.method,
        "fre_mm": result.fre_mm,
        "ppc_rms_mm": result.ppc_rms_mm,
        "tre_mm": result.tre_mm,
        "predicted_tre_rms_mm": result.predicted_tre_rms_mm,
        "alarms": list(result.alarms),
        "reference_to_image": np.asarray(result.reference_to_image).tolist(),
    }


def _count(node):
    return 0 if node is None else node.GetNumberOfControlPoints()


def _node_state(node):
    """What identifies a node's data now (its ID and modification times; a markups node's points themselves, whose
    edits leave its MTime alone), or None: a key of what was computed."""
    if node is None:
        return None
    if node.IsA("vtkMRMLMarkupsNode"):
        return (node.GetID(), fiducial_positions(node).tobytes())
    data = node.GetPolyData() if node.IsA("vtkMRMLModelNode") else None
    return (node.GetID(), node.GetMTime(), None if data is None else data.GetMTime())


def _first_missing(*pairs):
    return next((reason for node, reason in pairs if node is None), None)


def _parameter_events(node):
    """The parameter node's events that can change a selection: any modification, and reference changes."""
    from vtkmodules.vtkCommonCore import vtkCommand

    return (vtkCommand.ModifiedEvent, node.ReferenceAddedEvent, node.ReferenceModifiedEvent, node.ReferenceRemovedEvent)
