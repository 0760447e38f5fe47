"""RAMSICPRegistration: the surgeon's workflow from CT to a verified patient-to-image registration (CR-RAMSICP).

A thin Slicer shell over ``RAMSICPRegistrationLib.navigation.controller.NavigationController``, which holds every
piece of behaviour (MRML event observers, tracking state, pivot recording, auto-collect, registration, scene-close
clean-up) and is tested on slicer-core. The widget only binds the GUI to the parameter node, forwards clicks with
``controller.run(...)`` and shows what the controller reports, the live guidance of the cut included. The logic
owns the one parameter-node wrapper (Slicer's parameterNodeWrapper adds an observer at every ``connectGui`` that it
never removes, so the GUI is bound once per parameter node, not at every ``enter()``) and a timer that services the
robot link for as long as the module lives, whichever module is shown. Saving goes through the controller (a .mrb,
or a .mrml with its data files). Supported: Slicer 5.6, 5.8 and 5.10 (every Slicer API used here is checked
against their sources by ``Testing/test_module_files.py``).
"""

import os
from typing import Annotated, Union

import qt
import slicer
from slicer import (
    vtkMRMLLinearTransformNode,
    vtkMRMLMarkupsFiducialNode,
    vtkMRMLMarkupsPlaneNode,
    vtkMRMLModelNode,
    vtkMRMLPlotChartNode,
    vtkMRMLScalarVolumeNode,
    vtkMRMLSegmentationNode,
    vtkMRMLTableNode,
)
from slicer.i18n import tr as _
from slicer.i18n import translate
from slicer.parameterNodeWrapper import Choice, WithinRange, parameterNodeWrapper
from slicer.ScriptedLoadableModule import (
    ScriptedLoadableModule,
    ScriptedLoadableModuleLogic,
    ScriptedLoadableModuleTest,
    ScriptedLoadableModuleWidget,
)
from slicer.util import VTKObservationMixin

from OpenIGTLinkBridgeLib.robot_link import RobotLink
from RAMSICPRegistrationLib.core.hold_still import DEFAULT_STILL_MM, DEFAULT_STILL_S
from RAMSICPRegistrationLib.core.registration import DEFAULT_METHOD, METHODS, POLICIES
from RAMSICPRegistrationLib.core.tool_path import TOOLS
from RAMSICPRegistrationLib.navigation.controller import Cancelled, NavigationController

#: PLACEHOLDER until publication: the same address as EXTENSION_HOMEPAGE in the top-level CMakeLists.txt.
DOCUMENTATION_URL = "https://example.invalid/SlicerRAMSICPNavigator#in-3d-slicer"

#: Push button -> controller action it runs (buttons that need more than a click have their own slot).
BUTTON_ACTIONS = {
    "markersPatientButton": "add_reference_body_markers",
    "collectMarkerButton": "collect_marker",
    "collectButton": "collect_point",
    "registerButton": "register",
    "acceptRegistrationButton": "accept_registration",
    "robotButton": "robot_calibration",
    "storeCheckpointButton": "store_checkpoint",
    "checkCheckpointButton": "check_checkpoint",
    "placePlaneAtTipButton": "place_plane_at_tip",
    "planCutButton": "plan_cut",
    "sendPathButton": "send_tool_path",
    "stopRobotButton": "stop_robot",
}
#: Widget -> controller action whose availability enables it.
ENABLED_BY = {
    "processCTButton": "process_ct",
    "markersPatientButton": "add_reference_body_markers",
    "collectMarkerButton": "collect_marker",
    "collectButton": "collect_point",
    "registerButton": "register",
    "acceptRegistrationButton": "accept_registration",
    "storeCheckpointButton": "store_checkpoint",
    "checkCheckpointButton": "check_checkpoint",
    "robotButton": "robot_calibration",
    "placePlaneButton": "place_osteotomy_plane",
    "placePlaneAtTipButton": "place_plane_at_tip",
    "planCutButton": "plan_cut",
    "savePlanButton": "save_plan",
    "sendPathButton": "send_tool_path",
    "stopRobotButton": "stop_robot",
}
REFRESH_INTERVAL_MS = 200
#: The logic's timer: how often the robot link is serviced (its reports read), whether or not the module is shown.
ROBOT_SERVICE_INTERVAL_MS = 50
#: Collects a point while the module is shown. Qt reads Ctrl as Cmd on macOS: Cmd+Shift+C there. Free in Slicer
#: 5.6-5.10 and in Windows', macOS' and GNOME's/KDE's own shortcuts (Ctrl+Space, the earlier choice, is Spotlight on
#: macOS and switches the input method on Linux and Windows); checked by Testing/test_module_files.py.
COLLECT_SHORTCUT = "Ctrl+Shift+C"
ENOUGH_STYLE = "color: #ffffff; background-color: #2e7d32; font-weight: bold; padding: 4px"
NEXT_TOUCH_STYLE = "color: #e65100; font-weight: bold"
ON_PLAN_STYLE = "color: #ffffff; background-color: #2e7d32; font-size: 15px; font-weight: bold; padding: 4px"
ALARM_STYLE = "color: #ffffff; background-color: #c62828; font-weight: bold; padding: 4px"
OFF_PLAN_STYLE = "color: #ffffff; background-color: #c62828; font-size: 15px; font-weight: bold; padding: 4px"


class RAMSICPRegistration(ScriptedLoadableModule):
    def __init__(self, parent):
        ScriptedLoadableModule.__init__(self, parent)
        self.parent.title = _("RAMSICP Registration")
        self.parent.categories = [translate("qSlicerAbstractCoreModule", "IGT")]
        self.parent.dependencies = []
        self.parent.contributors = ["RAMSICP Navigator developers"]
        self.parent.helpText = (
            _(
                "Patient-to-image registration for robot-assisted long-bone osteotomy: coarse registration on the "
                "reference body's marker spheres, then range-adaptive ICP (CR-RAMSICP) on probe points. Steps: image, "
                "tracker, patient points, register, verify, robot, plan and cut (the tool path to the robot, live "
                "guidance), save. Feed the tracker with the OpenIGTLink Bridge module."
            )
            + f' <a href="{DOCUMENTATION_URL}">{_("Documentation")}</a>'
        )
        self.parent.acknowledgementText = _(
            "Method after Zhang et al., CR-RAMSICP. Bone geometry: Visible Human Female, University of Denver, "
            "CC BY 4.0. NDI tool geometries: PLUS Toolkit, BSD-3-Clause."
        )


@parameterNodeWrapper
class RAMSICPRegistrationParameterNode:
    """The fields of ``RAMSICPRegistrationLib.navigation.parameters.PARAMETERS``, which the controller reads."""

    ctVolume: vtkMRMLScalarVolumeNode
    thresholdHU: Annotated[float, WithinRange(-1000.0, 3000.0)] = 200.0
    segmentation: vtkMRMLSegmentationNode
    ipcModel: vtkMRMLModelNode
    markersImage: vtkMRMLMarkupsFiducialNode
    probeTipToProbe: vtkMRMLLinearTransformNode
    probeToReference: vtkMRMLLinearTransformNode
    referenceToTracker: vtkMRMLLinearTransformNode
    markersPatient: vtkMRMLMarkupsFiducialNode
    probePoints: vtkMRMLMarkupsFiducialNode
    autoCollectDistanceMm: Annotated[float, WithinRange(0.5, 50.0)] = 5.0
    holdStillMm: Annotated[float, WithinRange(0.2, 10.0)] = DEFAULT_STILL_MM
    holdStillS: Annotated[float, WithinRange(0.05, 5.0)] = DEFAULT_STILL_S
    reachableSurface: Union[vtkMRMLModelNode, vtkMRMLMarkupsFiducialNode]
    targetTreMm: Annotated[float, WithinRange(0.05, 10.0)] = 1.0
    nextTouch: vtkMRMLMarkupsFiducialNode
    method: Annotated[str, Choice(list(METHODS))] = DEFAULT_METHOD
    policy: Annotated[str, Choice(list(POLICIES))] = "rms-plateau"
    referenceToImage: vtkMRMLLinearTransformNode
    residualTable: vtkMRMLTableNode
    sweepChart: vtkMRMLPlotChartNode
    targetsImage: vtkMRMLMarkupsFiducialNode
    targetsPatient: vtkMRMLMarkupsFiducialNode
    checkpoints: vtkMRMLMarkupsFiducialNode
    checkpointLimitMm: Annotated[float, WithinRange(0.1, 5.0)] = 0.6
    robotPositions: vtkMRMLMarkupsFiducialNode
    trackerPositions: vtkMRMLMarkupsFiducialNode
    robotBaseToTracker: vtkMRMLLinearTransformNode
    imageToRobotBase: vtkMRMLLinearTransformNode
    osteotomyPlane: vtkMRMLMarkupsPlaneNode
    cutExtentMm: Annotated[float, WithinRange(0.0, 300.0)] = 0.0
    wedgeAngleDeg: Annotated[float, WithinRange(0.0, 30.0)] = 0.0
    wedgePlane: vtkMRMLMarkupsPlaneNode
    cuttingTool: Annotated[str, Choice(list(TOOLS))] = "saw"
    toolWidthMm: Annotated[float, WithinRange(0.5, 50.0)] = 10.0
    farMarginMm: Annotated[float, WithinRange(0.0, 30.0)] = 2.0
    cutEndpoints: vtkMRMLMarkupsFiducialNode
    toolPath: vtkMRMLModelNode
    toolToTracker: vtkMRMLLinearTransformNode
    toolTipToTool: vtkMRMLLinearTransformNode
    guidanceDistanceMm: Annotated[float, WithinRange(0.1, 10.0)] = 1.0
    guidanceAngleDeg: Annotated[float, WithinRange(0.1, 20.0)] = 2.0
    robotHost: str = "127.0.0.1"
    robotPort: Annotated[int, WithinRange(1, 65535)] = 18945


class RAMSICPRegistrationWidget(ScriptedLoadableModuleWidget, VTKObservationMixin):
    def __init__(self, parent=None):
        ScriptedLoadableModuleWidget.__init__(self, parent)
        VTKObservationMixin.__init__(self)
        self.logic = None
        self._parameterNode = None
        self._parameterNodeGuiTag = None
        self._shortcut = None
        self._timer = None

    def setup(self):
        ScriptedLoadableModuleWidget.setup(self)
        uiWidget = slicer.util.loadUI(self.resourcePath("UI/RAMSICPRegistration.ui"))
        self.layout.addWidget(uiWidget)
        self.ui = slicer.util.childWidgetVariables(uiWidget)
        uiWidget.setMRMLScene(slicer.mrmlScene)
        self.logic = RAMSICPRegistrationLogic()
        self.logic.controller.add_listener(self.onControllerEvent)
        self.addObserver(slicer.mrmlScene, slicer.mrmlScene.StartCloseEvent, self.onSceneStartClose)
        self.addObserver(slicer.mrmlScene, slicer.mrmlScene.EndCloseEvent, self.onSceneEndClose)
        for button, action in BUTTON_ACTIONS.items():
            getattr(self.ui, button).connect("clicked(bool)", lambda checked, action=action: self.run(action))
        self.ui.processCTButton.connect("clicked(bool)", self.onProcessCT)
        self.ui.pivotButton.connect("toggled(bool)", self.onPivotToggled)
        self.ui.autoCollectCheckBox.connect("toggled(bool)", self.onAutoCollectToggled)
        self.ui.holdStillCheckBox.connect("toggled(bool)", self.onHoldStillToggled)
        self.ui.guidedCollectCheckBox.connect("toggled(bool)", self.onGuidedCollectToggled)
        self.ui.placePlaneButton.connect("clicked(bool)", self.onPlacePlane)
        self.ui.saveButton.connect("clicked(bool)", self.onSave)
        self.ui.savePlanButton.connect("clicked(bool)", self.onSavePlan)
        self._timer = qt.QTimer(self.parent)
        self._timer.setInterval(REFRESH_INTERVAL_MS)
        self._timer.connect("timeout()", self.refresh)
        self.initializeParameterNode()

    def cleanup(self):
        if self._timer is not None:
            self._timer.stop()
        self.uninstallShortcut()
        self.removeObservers()
        self.setParameterNode(None)
        if self.logic is not None:
            self.logic.close()

    def enter(self):
        self.initializeParameterNode()
        self.installShortcut()
        self._timer.start()
        self.refresh()

    def exit(self):
        # The GUI stays bound to the parameter node (binding again at each enter() would add an observer each
        # time), and the logic's timer keeps servicing the robot link: only the display refresh stops.
        self._timer.stop()
        self.uninstallShortcut()

    def installShortcut(self):
        """COLLECT_SHORTCUT collects a point while this module is shown (removed on exit, as Segment Editor does)."""
        mainWindow = slicer.util.mainWindow()
        if self._shortcut is not None or mainWindow is None:  # no main window with --no-main-window
            return
        self._shortcut = qt.QShortcut(qt.QKeySequence(COLLECT_SHORTCUT), mainWindow)
        self._shortcut.connect("activated()", self.onCollectShortcut)

    def uninstallShortcut(self):
        if self._shortcut is not None:
            self._shortcut.disconnect("activated()", self.onCollectShortcut)
            self._shortcut.setParent(None)
            self._shortcut = None

    def onCollectShortcut(self):
        self.run("collect_point")

    def onSceneStartClose(self, caller, event):
        self.setParameterNode(None)

    def onSceneEndClose(self, caller, event):
        if self.parent.isEntered:
            self.initializeParameterNode()

    def initializeParameterNode(self):
        """Bind the GUI to the logic's parameter-node wrapper, once per parameter node (a new one after a scene
        close): the same wrapper comes back on every enter(), and is not bound again."""
        parameterNode = self.logic.getParameterNode()
        if parameterNode is not self._parameterNode:
            self.setParameterNode(parameterNode)

    def setParameterNode(self, inputParameterNode):
        if self._parameterNode:
            self._parameterNode.disconnectGui(self._parameterNodeGuiTag)
            self._parameterNodeGuiTag = None
        self._parameterNode = inputParameterNode
        if self._parameterNode:
            self._parameterNodeGuiTag = self._parameterNode.connectGui(self.ui)
            self.refresh()

    # -- clicks: forwarded to the controller ---------------------------------------------------------------
    def run(self, action, *args, **kwargs):
        with slicer.util.tryWithErrorDisplay(_("Unexpected error; the details are in the log."), waitCursor=True):
            self.logic.controller.run(action, *args, **kwargs)
        self.refresh()

    def onProcessCT(self):
        dialog = slicer.util.createProgressDialog(
            parent=slicer.util.mainWindow(), maximum=3, windowTitle=_("RAMSICP: image side")
        )
        # createProgressDialog leaves the dialog modeless (Slicer 5.6-5.10), and the callback below processes
        # events: without this a second click could start a second run (the controller refuses it anyway).
        dialog.setWindowModality(qt.Qt.WindowModal)

        def progress(step, done, total):
            dialog.labelText = step
            dialog.value = done
            slicer.app.processEvents()
            if dialog.wasCanceled:
                raise Cancelled()

        try:
            self.run("process_ct", progress=progress)
        finally:
            dialog.close()

    def onPivotToggled(self, recording):
        self.run("start_pivot" if recording else "stop_pivot")

    def onAutoCollectToggled(self, enabled):
        self.run("set_auto_collect", enabled)

    def onHoldStillToggled(self, enabled):
        self.run("set_hold_still_collect", enabled)

    def onGuidedCollectToggled(self, enabled):
        self.run("set_guided_collect", enabled)

    def onPlacePlane(self):
        self.run(
            "place_osteotomy_plane",
            self.ui.planeLevelSpinBox.value,
            self.ui.planeTiltAnteriorSpinBox.value,
            self.ui.planeTiltSideSpinBox.value,
            self.ui.planeEntrySpinBox.value,
        )

    def onSave(self):
        """Save through the controller: Slicer's own writer for .mrml writes only the scene's XML (the points, the
        IPC, the segmentation and the residual table would be lost)."""
        path = qt.QFileDialog.getSaveFileName(
            None,
            _("Save the navigation scene"),
            "",
            _("Medical Reality Bundle (*.mrb);;MRML scene and its data files (*.mrml)"),
        )
        if path:
            self.run("save", path)

    def onSavePlan(self):
        path = qt.QFileDialog.getSaveFileName(None, _("Save the osteotomy plan"), "plan.json", _("JSON (*.json)"))
        if path:
            self.run("save_plan", path)

    # -- what the controller reports -----------------------------------------------------------------------
    def onControllerEvent(self, event, data):
        if event == "registered":
            self.ui.resultsLabel.text = self.logic.controller.status().message
            self.ui.warningsTextEdit.plainText = "\n".join(data.warnings) if data.warnings else _("No warnings.")
        elif event == "reset":
            self.ui.resultsLabel.text = ""
            self.ui.warningsTextEdit.plainText = ""

    def refresh(self):
        """Show the controller's status; enable each action only when its inputs exist (tooltips say why)."""
        if self.logic is None or self._parameterNode is None:
            return
        controller = self.logic.controller
        status = controller.status()
        self.ui.trackingStatusLabel.text = "\n".join(tool.text for tool in status.tools)
        self.ui.tipDistanceLabel.text = (
            _("tip to bone surface: -")
            if status.tip_to_surface_mm is None
            else _("tip to bone surface: {distance:.1f} mm").format(distance=status.tip_to_surface_mm)
        )
        if status.predicted_error_at_tip_mm is not None:
            self.ui.tipDistanceLabel.text += _("; predicted registration error at the tip: {error:.2f} mm").format(
                error=status.predicted_error_at_tip_mm
            )
        self.ui.pointCountLabel.text = _("{count} probe points, {markers} marker centres").format(
            count=status.probe_points, markers=status.marker_points
        )
        self.ui.statusLabel.text = status.message
        self.ui.statusLabel.styleSheet = "color: #c62828" if status.message_is_error else ""
        reasons = controller.availability()
        for widget, action in ENABLED_BY.items():
            button = getattr(self.ui, widget)
            button.enabled = reasons[action] is None
            button.toolTip = reasons[action] or ""
        self.ui.pivotButton.enabled = status.pivot_recording or reasons["start_pivot"] is None
        self.ui.pivotButton.text = _("Stop pivoting and calibrate") if status.pivot_recording else _("Start pivoting")
        self.ui.pivotButton.toolTip = "" if status.pivot_recording else (reasons["start_pivot"] or "")
        self._setCheckedQuietly(self.ui.pivotButton, status.pivot_recording)
        self.ui.autoCollectCheckBox.enabled = status.auto_collect or reasons["set_auto_collect"] is None
        self._setCheckedQuietly(self.ui.autoCollectCheckBox, status.auto_collect)
        self.ui.holdStillCheckBox.enabled = status.hold_still_collect or reasons["set_hold_still_collect"] is None
        self._setCheckedQuietly(self.ui.holdStillCheckBox, status.hold_still_collect)
        self.ui.holdStillCheckBox.styleSheet = "color: #2e7d32; font-weight: bold" if status.holding else ""
        self.ui.pivotResultLabel.text = (
            _("recording: {count} poses").format(count=status.pivot_poses) if status.pivot_recording else ""
        )
        self.ui.cutLabel.text = status.cut
        guidance = status.guidance
        self.ui.guidanceLabel.text = _("guidance: -") if guidance is None else guidance.text
        self.ui.guidanceLabel.styleSheet = (
            "" if guidance is None else (ON_PLAN_STYLE if guidance.on_plan else OFF_PLAN_STYLE)
        )
        self.ui.robotStatusLabel.text = status.robot
        self.ui.alarmLabel.text = "\n".join(
            _("ALARM, not used for navigation until accepted: {alarm}").format(alarm=alarm) for alarm in status.alarms
        )
        self.ui.alarmLabel.styleSheet = ALARM_STYLE if status.alarms else ""
        self.ui.acceptRegistrationButton.visible = bool(status.alarms)
        self.showNextTouch(status, reasons)
        self.showCheckpoints(status)
        self.showPlanePlacement(status)
        table = self._parameterNode.residualTable
        if self.ui.residualTableView.mrmlTableNode() is not table:
            self.ui.residualTableView.setMRMLTableNode(table)

    def showNextTouch(self, status, reasons):
        """The next touch (drawn on the bone as the orange NextTouch point) in words, green once enough."""
        touch = status.next_touch
        self.ui.nextTouchLabel.text = status.next_touch_text
        self.ui.nextTouchLabel.styleSheet = (
            "" if touch is None else (ENOUGH_STYLE if touch.enough else NEXT_TOUCH_STYLE)
        )
        self.ui.guidedCollectCheckBox.enabled = status.guided_collect or reasons["set_guided_collect"] is None
        self.ui.guidedCollectCheckBox.toolTip = "" if status.guided_collect else (reasons["set_guided_collect"] or "")
        self._setCheckedQuietly(self.ui.guidedCollectCheckBox, status.guided_collect)

    def showCheckpoints(self, status):
        self.ui.checkpointLabel.text = _("{count} checkpoint(s) stored. {text}").format(
            count=status.checkpoint_count, text=status.checkpoint_text
        )
        self.ui.checkpointAlarmLabel.text = status.checkpoint_alarm
        self.ui.checkpointAlarmLabel.styleSheet = ALARM_STYLE if status.checkpoint_alarm else ""

    def showPlanePlacement(self, status):
        """The selected plane's placement in the bone's frame, in the spin boxes the user is not editing."""
        placement = status.plane_placement
        if placement is None:
            return
        for spinBox, value in (
            (self.ui.planeLevelSpinBox, placement.level_mm),
            (self.ui.planeTiltAnteriorSpinBox, placement.tilt_anterior_deg),
            (self.ui.planeTiltSideSpinBox, placement.tilt_side_deg),
            (self.ui.planeEntrySpinBox, round(placement.entry_deg) % 360),
        ):
            if not spinBox.hasFocus():
                wasBlocked = spinBox.blockSignals(True)
                spinBox.value = value
                spinBox.blockSignals(wasBlocked)

    @staticmethod
    def _setCheckedQuietly(button, checked):
        if button.checked != checked:
            wasBlocked = button.blockSignals(True)
            button.checked = checked
            button.blockSignals(wasBlocked)


class RAMSICPRegistrationLogic(ScriptedLoadableModuleLogic):
    """Facade: the module's parameter node and the Qt-free controller on Slicer's scene, and the timer that
    services the robot link (reads its reports, judges its answer) for as long as the module lives: a widget's
    timer stops when the surgeon switches module, and a robot controller drops a client that stops reading."""

    def __init__(self):
        ScriptedLoadableModuleLogic.__init__(self)
        autosave = os.path.join(slicer.app.temporaryPath, "RAMSICPNavigator-autosave")
        self.controller = NavigationController(
            slicer.mrmlScene, autosave_directory=autosave, robot_link_factory=RobotLink
        )
        self._parameterNode = None
        self._serviceTimer = qt.QTimer()
        self._serviceTimer.setInterval(ROBOT_SERVICE_INTERVAL_MS)
        self._serviceTimer.connect("timeout()", self.controller.service)
        self._serviceTimer.start()

    def getParameterNode(self):
        """The one wrapper of the scene's parameter node (a new one only when the node changed: a scene close)."""
        node = super().getParameterNode()
        if self._parameterNode is None or self._parameterNode.parameterNode is not node:
            self._parameterNode = RAMSICPRegistrationParameterNode(node)
        return self._parameterNode

    def close(self):
        """Stop the timer and the controller (which stops a moving robot): the module is going away."""
        self._serviceTimer.stop()
        self.controller.close()


class RAMSICPRegistrationTest(ScriptedLoadableModuleTest):
    """Runs the workflow scenario that pytest runs on slicer-core, here inside Slicer, through the controller."""

    def setUp(self):
        slicer.mrmlScene.Clear()

    def runTest(self):
        self.setUp()
        self.test_workflow_on_a_ct_phantom()

    def test_workflow_on_a_ct_phantom(self):
        from RAMSICPRegistrationLib.navigation.scenarios import check_workflow, make_patient_and_ct, run_workflow

        self.delayDisplay(_("Building a CT phantom of the tibia and running the workflow (about 30 s)"))
        patient, volume, truth = make_patient_and_ct()
        state = run_workflow(
            slicer.mrmlScene,
            patient,
            volume,
            truth,
            autosave_directory=os.path.join(slicer.app.temporaryPath, "RAMSICPSelfTest"),
        )
        try:
            figures = check_workflow(state)
        finally:
            state["controller"].close()
        self.delayDisplay(
            _("Workflow passed: marker centres {marker:.3f} mm, targets {target:.2f} mm").format(
                marker=figures["marker_error_mm"], target=figures["target_error_mm"]
            )
        )
