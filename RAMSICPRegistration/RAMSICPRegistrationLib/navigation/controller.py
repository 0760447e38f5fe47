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
"""

import logging
import time
from dataclasses import dataclass

import numpy as np

from ..core.hold_still import HoldStillDetector
from ..io.ndi_tools import DEFAULT_REFERENCE_TOOL
from .navigation import NavigationLogic, matrix_of, points_of
from .parameters import Parameters, get_parameter_node

logger = logging.getLogger(__name__)

#: Seconds without a new pose after which a tracked transform counts as stale (as SlicerIGT's Watchdog).
STALE_AFTER_S = 1.0

#: The transforms whose poses the controller follows: parameter name -> the name shown to the user.
WATCHED = {"probeToReference": "ProbeToReference", "referenceToTracker": "ReferenceToTracker"}

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
    "register",
    "set_included",
    "robot_calibration",
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
    """

    def __init__(
        self, scene, autosave_directory=None, clock=time.monotonic, stale_after_s=STALE_AFTER_S, pose_time=None
    ):
        self.scene = scene
        self.steps = NavigationLogic(scene, autosave_directory)
        self.clock, self.stale_after_s = clock, stale_after_s
        self.pose_time = pose_time
        self.last_result = None
        self._listeners = []
        self._scene_tags = []
        self._parameter_observation = None
        self._watches = {}  # parameter name -> _PoseWatch
        self._pose_tags = {}  # parameter name -> (node, tag)
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
        is_error)), 'reset', and 'pose' (data: the tool's label, e.g. 'ProbeToReference') for each new pose of a
        watched tool, at the tracker's rate: keep that one cheap. Returns the callback, for ``remove_listener``."""
        self._listeners.append(callback)
        return callback

    def remove_listener(self, callback):
        self._listeners.remove(callback)

    def close(self):
        """Remove every observer this controller added (the shell is going away)."""
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
                parameters = self.parameters
                tip = self.steps.tip_in_reference(caller, parameters.probeTipToProbe)
                when = self.clock() if self.pose_time is None else self.pose_time(caller)
                touch = self._hold_still.add(tip, when, self._probe_frames)
                if touch is not None:
                    self._add_touch(touch)
            except (ValueError, TypeError, RuntimeError) as error:
                self._hold_still = None
                self._notify("hold-still", False)
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
            holding=self._hold_still is not None and self._hold_still.pending() is not None,
            probe_poses=self._probe_frames,
            probe_points=_count(parameters.probePoints),
            marker_points=_count(parameters.markersPatient),
            tip_to_surface_mm=self._tip_to_surface_mm(parameters),
            predicted_error_at_tip_mm=self._predicted_error_at_tip_mm(parameters),
            message=self._message[0],
            message_is_error=self._message[1],
            tip_reference_mm=self._tip_reference_mm(parameters),
        )

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
        if any(node is None for node in nodes) or parameters.referenceToImage is None:
            return None
        if self.tool_state("probeToReference").state != "valid":
            return None
        try:
            return self.steps.tip_to_surface_mm(*nodes, parameters.referenceToImage)
        except (ValueError, TypeError):
            return None

    def _predicted_error_at_tip_mm(self, parameters):
        result = self.last_result
        if result is None or result.pose_covariance is None or parameters.probeTipToProbe is None:
            return None
        if parameters.probeToReference is None or self.tool_state("probeToReference").state != "valid":
            return None
        tip = self.steps.tip_in_reference(parameters.probeToReference, parameters.probeTipToProbe)
        tip_image = result.reference_to_image[:3, :3] @ tip + result.reference_to_image[:3, 3]
        return float(result.predicted_error_mm(tip_image[None])[0])

    def availability(self):
        """{action: None when it can run now, else the reason in words} for every action of ``ACTIONS``."""
        parameters = self.parameters
        tracking = self._tracking_problem(parameters)
        calibrated = None if parameters.probeTipToProbe is not None else "calibrate the probe tip (pivot) first"
        collecting = tracking or calibrated
        reasons = {
            "process_ct": None if parameters.ctVolume is not None else "select the CT volume",
            "start_pivot": tracking if self._pivot_poses is None else "pivot recording is already running",
            "stop_pivot": None if self._pivot_poses is not None else "start pivot recording first",
            "add_reference_body_markers": None,
            "collect_point": collecting,
            "collect_marker": collecting,
            "set_auto_collect": collecting if not self._auto_collect else None,
            "set_hold_still_collect": collecting if self._hold_still is None else None,
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
            "set_included": None if parameters.residualTable is not None else "register once first",
            "save": None,
        }
        return reasons

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
        returned.
        """
        self._require("process_ct")
        parameters = self.parameters
        try:
            image = self.steps.process_ct(parameters.ctVolume, parameters.thresholdHU, progress=progress)
        except Cancelled:
            self._say("CT processing cancelled; nothing was changed", is_error=True)
            return None
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
                touch, self._hold_still = self._hold_still.finish(), None
                if touch is not None:
                    self._add_touch(touch)
                self._notify("hold-still", False)
            return
        self._require("set_hold_still_collect")
        if self._hold_still is not None:
            return
        self.set_auto_collect(False)
        parameters = self.parameters
        self._hold_still = HoldStillDetector(parameters.holdStillMm, parameters.holdStillS)
        self._say(
            f"hold-still collection on: hold the tip still for {parameters.holdStillS:g} s "
            f"(within {parameters.holdStillMm:g} mm), then lift it"
        )
        self._notify("hold-still", True)

    def _add_touch(self, touch):
        parameters = self.parameters
        node = parameters.probePoints
        if node is None:
            node = self.scene.AddNewNodeByClass("vtkMRMLMarkupsFiducialNode", "ProbePoints")
            parameters.probePoints = node
        index = self.steps.add_point(node, touch.position)
        self._say(
            f"point {index + 1} collected: held {touch.duration_s:.2f} s over {touch.frames} frames, "
            f"spread {touch.spread_mm:.2f} mm"
        )
        self._notify("collected", (node, index, touch))

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
        if parameters.probeTipToProbe is not None and parameters.probeToReference is not None:
            self.steps.build_hierarchy(
                parameters.probeTipToProbe, parameters.probeToReference, parameters.referenceToImage
            )
        self.last_result = result
        self._say(registration_summary(result))
        self._notify("registered", result)
        return result

    def set_included(self, point_index, included):
        """Include or exclude probe point ``point_index`` (0-based) from the next registration."""
        self.steps.set_included(point_index, included)

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

    # -- 7. save -------------------------------------------------------------------------------------------
    def save(self, path):
        """Save the scene and its data as ``path`` (.mrml), for plain Python and the browser view; returns the files
        written (the scene first)."""
        written = self.steps.save(path)
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


def _count(node):
    return 0 if node is None else node.GetNumberOfControlPoints()


def _first_missing(*pairs):
    return next((reason for node, reason in pairs if node is None), None)


def _parameter_events(node):
    """The parameter node's events that can change a selection: any modification, and reference changes."""
    from vtkmodules.vtkCommonCore import vtkCommand

    return (vtkCommand.ModifiedEvent, node.ReferenceAddedEvent, node.ReferenceModifiedEvent, node.ReferenceRemovedEvent)
