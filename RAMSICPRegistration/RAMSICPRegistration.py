"""RAMSICPRegistration: the surgeon's workflow from CT to a verified patient-to-image registration (CR-RAMSICP).

A thin Slicer shell: the widget wires the GUI to ``RAMSICPRegistrationLib.navigation.navigation.NavigationLogic``,
which does the work on the MRML nodes it is given; the self-test runs ``RAMSICPRegistrationLib.navigation.scenarios``.
"""

import importlib.util
import logging
import os
from typing import Annotated

import qt
import slicer
import vtk
from slicer import (
    vtkMRMLLinearTransformNode,
    vtkMRMLMarkupsFiducialNode,
    vtkMRMLModelNode,
    vtkMRMLScalarVolumeNode,
)
from slicer.parameterNodeWrapper import Choice, WithinRange, parameterNodeWrapper
from slicer.ScriptedLoadableModule import (
    ScriptedLoadableModule,
    ScriptedLoadableModuleLogic,
    ScriptedLoadableModuleTest,
    ScriptedLoadableModuleWidget,
)
from slicer.util import VTKObservationMixin

#: Python packages the library needs that Slicer may not ship: import name -> pip requirement.
RUNTIME_REQUIREMENTS = {"nrrd": "pynrrd", "nibabel": "nibabel", "pydicom": "pydicom", "scipy": "scipy"}


def ensure_requirements():
    """Install missing runtime packages after the user agrees; returns True when all are importable."""
    missing = [
        requirement for module, requirement in RUNTIME_REQUIREMENTS.items() if importlib.util.find_spec(module) is None
    ]
    if not missing:
        return True
    if not slicer.util.confirmOkCancelDisplay(
        f"RAMSICP Navigator needs these Python packages: {', '.join(missing)}.\nInstall them now (internet needed)?",
        "RAMSICP Navigator",
    ):
        return False
    with _busy():
        slicer.util.pip_install(" ".join(missing))
    return all(importlib.util.find_spec(module) is not None for module in RUNTIME_REQUIREMENTS)


class _busy:
    def __enter__(self):
        slicer.app.setOverrideCursor(qt.Qt.WaitCursor)

    def __exit__(self, *args):
        slicer.app.restoreOverrideCursor()


class RAMSICPRegistration(ScriptedLoadableModule):
    def __init__(self, parent):
        ScriptedLoadableModule.__init__(self, parent)
        self.parent.title = "RAMSICP Registration"
        self.parent.categories = ["IGT"]
        self.parent.dependencies = []
        self.parent.contributors = ["RAMSICP Navigator developers"]
        self.parent.helpText = (
            "Patient-to-image registration for robot-assisted long-bone osteotomy: coarse registration on the "
            "reference body's marker spheres, then range-adaptive ICP (CR-RAMSICP) on probe points. Steps: image, "
            "tracker, patient points, register, verify, robot, save."
        )
        self.parent.acknowledgementText = (
            "Method after Zhang et al., CR-RAMSICP. Bone geometry: Visible Human Female, University of Denver, "
            "CC BY 4.0. NDI tool geometries: PLUS Toolkit, BSD-3-Clause."
        )


@parameterNodeWrapper
class RAMSICPRegistrationParameterNode:
    ctVolume: vtkMRMLScalarVolumeNode
    thresholdHU: Annotated[float, WithinRange(-1000, 3000)] = 200.0
    probeTipToProbe: vtkMRMLLinearTransformNode
    probeToReference: vtkMRMLLinearTransformNode
    referenceToTracker: vtkMRMLLinearTransformNode
    ipcModel: vtkMRMLModelNode
    markersImage: vtkMRMLMarkupsFiducialNode
    markersPatient: vtkMRMLMarkupsFiducialNode
    probePoints: vtkMRMLMarkupsFiducialNode
    targetsImage: vtkMRMLMarkupsFiducialNode
    targetsPatient: vtkMRMLMarkupsFiducialNode
    robotPositions: vtkMRMLMarkupsFiducialNode
    trackerPositions: vtkMRMLMarkupsFiducialNode
    method: Annotated[str, Choice(["cr-ramsicp", "cr-icp", "cr"])] = "cr-ramsicp"
    policy: Annotated[str, Choice(["rms-plateau", "fixed", "targets"])] = "rms-plateau"
    autoCollectDistanceMm: Annotated[float, WithinRange(0.5, 50.0)] = 5.0


class RAMSICPRegistrationWidget(ScriptedLoadableModuleWidget, VTKObservationMixin):
    def __init__(self, parent=None):
        ScriptedLoadableModuleWidget.__init__(self, parent)
        VTKObservationMixin.__init__(self)
        self.logic = None
        self._parameterNode = None
        self._parameterNodeGuiTag = None
        self._pivotPoses = None
        self._timer = qt.QTimer()

    def setup(self):
        ScriptedLoadableModuleWidget.setup(self)
        uiWidget = slicer.util.loadUI(self.resourcePath("UI/RAMSICPRegistration.ui"))
        self.layout.addWidget(uiWidget)
        self.ui = slicer.util.childWidgetVariables(uiWidget)
        uiWidget.setMRMLScene(slicer.mrmlScene)
        if not ensure_requirements():
            self.ui.statusLabel.text = "Missing Python packages: the module cannot run until they are installed."
            return
        self.logic = RAMSICPRegistrationLogic()
        self.addObserver(slicer.mrmlScene, slicer.mrmlScene.StartCloseEvent, self.onSceneStartClose)
        self.addObserver(slicer.mrmlScene, slicer.mrmlScene.EndCloseEvent, self.onSceneEndClose)
        self.ui.processCTButton.connect("clicked(bool)", self.onProcessCT)
        self.ui.pivotButton.connect("toggled(bool)", self.onPivotToggled)
        self.ui.markersPatientButton.connect("clicked(bool)", self.onMarkersPatient)
        self.ui.collectButton.connect("clicked(bool)", self.onCollect)
        self.ui.collectMarkerButton.connect("clicked(bool)", self.onCollectMarker)
        self.ui.autoCollectCheckBox.connect("toggled(bool)", self.onAutoCollectToggled)
        self.ui.registerButton.connect("clicked(bool)", self.onRegister)
        self.ui.robotButton.connect("clicked(bool)", self.onRobot)
        self.ui.saveButton.connect("clicked(bool)", self.onSave)
        self._shortcut = qt.QShortcut(qt.QKeySequence("Ctrl+Space"), slicer.util.mainWindow())
        self._shortcut.connect("activated()", self.onCollect)
        self._timer.setInterval(200)
        self._timer.connect("timeout()", self.onTimer)
        self.initializeParameterNode()

    def cleanup(self):
        self._timer.stop()
        self.removeObservers()

    def enter(self):
        self.initializeParameterNode()
        self._timer.start()

    def exit(self):
        self._timer.stop()
        if self._parameterNode:
            self._parameterNode.disconnectGui(self._parameterNodeGuiTag)
            self._parameterNodeGuiTag = None

    def onSceneStartClose(self, caller, event):
        self.setParameterNode(None)

    def onSceneEndClose(self, caller, event):
        if self.parent.isEntered:
            self.initializeParameterNode()

    def initializeParameterNode(self):
        if self.logic is not None:
            self.setParameterNode(self.logic.getParameterNode())

    def setParameterNode(self, inputParameterNode):
        if self._parameterNode:
            self._parameterNode.disconnectGui(self._parameterNodeGuiTag)
        self._parameterNode = inputParameterNode
        if self._parameterNode:
            self._parameterNodeGuiTag = self._parameterNode.connectGui(self.ui)

    # Step 1
    def onProcessCT(self):
        with slicer.util.tryWithErrorDisplay("Could not build the IPC and find the marker spheres.", waitCursor=True):
            parameters = self._parameterNode
            image = self.logic.navigation.process_ct(parameters.ctVolume, parameters.thresholdHU)
            parameters.ipcModel, parameters.markersImage = image.ipc_model, image.markers_image
            self._showWarnings(image.warnings)

    # Step 2
    def onPivotToggled(self, recording):
        parameters = self._parameterNode
        if recording:
            self._pivotPoses = []
            self.addObserver(parameters.probeToReference, vtk.vtkCommand.ModifiedEvent, self.onPivotPose)
            self.ui.pivotButton.text = "Stop pivoting and calibrate"
            return
        self.removeObserver(parameters.probeToReference, vtk.vtkCommand.ModifiedEvent, self.onPivotPose)
        self.ui.pivotButton.text = "Start pivoting"
        with slicer.util.tryWithErrorDisplay("Pivot calibration failed.", waitCursor=True):
            result = self.logic.navigation.pivot_calibrate(self._pivotPoses, parameters.probeTipToProbe)
            self.ui.pivotResultLabel.text = (
                f"RMS {result.rms_mm:.2f} mm from {int(result.inliers.sum())} of {len(result.inliers)} poses"
            )

    def onPivotPose(self, caller, event):
        from RAMSICPRegistrationLib.navigation.navigation import matrix_of

        self._pivotPoses.append(matrix_of(caller))

    # Step 3
    def onMarkersPatient(self):
        with slicer.util.tryWithErrorDisplay("Could not add the reference body's marker centres."):
            self._parameterNode.markersPatient = self.logic.navigation.markers_patient_node()

    def onCollect(self):
        parameters = self._parameterNode
        with slicer.util.tryWithErrorDisplay("The probe point was not collected."):
            if parameters.probePoints is None:
                parameters.probePoints = slicer.mrmlScene.AddNewNodeByClass("vtkMRMLMarkupsFiducialNode", "PPC")
            self.logic.navigation.collect_point(
                parameters.probePoints, parameters.probeToReference, parameters.probeTipToProbe
            )

    def onCollectMarker(self):
        """Touch a marker sphere's centre with the probe (a calibrated divot) instead of using the tool geometry."""
        parameters = self._parameterNode
        with slicer.util.tryWithErrorDisplay("The marker centre was not collected."):
            if parameters.markersPatient is None:
                parameters.markersPatient = slicer.mrmlScene.AddNewNodeByClass(
                    "vtkMRMLMarkupsFiducialNode", "MarkersPatient"
                )
            self.logic.navigation.collect_point(
                parameters.markersPatient, parameters.probeToReference, parameters.probeTipToProbe
            )

    def onAutoCollectToggled(self, enabled):
        node = self._parameterNode.probeToReference
        if enabled:
            self.addObserver(node, vtk.vtkCommand.ModifiedEvent, self.onProbeMoved)
        else:
            self.removeObserver(node, vtk.vtkCommand.ModifiedEvent, self.onProbeMoved)

    def onProbeMoved(self, caller, event):
        parameters = self._parameterNode
        try:
            self.logic.navigation.collect_point(
                parameters.probePoints,
                caller,
                parameters.probeTipToProbe,
                min_distance_mm=parameters.autoCollectDistanceMm,
            )
        except (RuntimeError, ValueError, TypeError) as error:
            self.ui.statusLabel.text = str(error)

    # Step 4
    def onRegister(self):
        parameters = self._parameterNode
        with slicer.util.tryWithErrorDisplay("Registration failed.", waitCursor=True):
            result = self.logic.navigation.register(
                parameters.ipcModel,
                parameters.probePoints,
                parameters.markersImage,
                parameters.markersPatient,
                parameters.targetsImage,
                parameters.targetsPatient,
                method=parameters.method,
                sweep=True,
                policy=parameters.policy if parameters.method == "cr-ramsicp" else None,
            )
            tre = "–" if result.tre_mm is None else f"{result.tre_mm:.2f} mm"
            predicted = (
                ""
                if result.predicted_cr_tre_mm is None
                else (f", CR TRE predicted {max(result.predicted_cr_tre_mm):.2f} mm (FLE {result.fle_mm:.2f} mm)")
            )
            scale = "" if result.scale is None else f", L = {result.scale:g} ({result.scale_policy})"
            self.ui.resultsLabel.text = (
                f"{result.method.upper()}{scale}: FRE {result.fre_mm:.2f} mm, probe points {result.ppc_rms_mm:.2f} mm "
                f"RMS, TRE {tre}{predicted}"
            )
            self._showWarnings(result.warnings)
            if parameters.probeTipToProbe and parameters.probeToReference:  # the probe now moves over the CT
                self.logic.navigation.build_hierarchy(
                    parameters.probeTipToProbe,
                    parameters.probeToReference,
                    slicer.mrmlScene.GetFirstNodeByName("ReferenceToImage"),
                )
            self.ui.residualTableView.setMRMLTableNode(slicer.mrmlScene.GetFirstNodeByName("RegistrationResiduals"))

    # Step 5: live readouts
    def onTimer(self):
        parameters = self._parameterNode
        if self.logic is None or parameters is None or parameters.probeToReference is None:
            return
        try:
            self.logic.navigation.check_tracking(parameters.probeToReference)
            self.ui.trackingStatusLabel.text = "probe: tracked"
        except RuntimeError as error:
            self.ui.trackingStatusLabel.text = f"probe: {error}"
            return
        reference_to_image = slicer.mrmlScene.GetFirstNodeByName("ReferenceToImage")
        if parameters.ipcModel is not None and reference_to_image is not None and parameters.probeTipToProbe:
            distance = self.logic.navigation.tip_to_surface_mm(
                parameters.ipcModel, parameters.probeToReference, parameters.probeTipToProbe, reference_to_image
            )
            self.ui.tipDistanceLabel.text = f"tip to bone surface: {distance:.1f} mm"

    # Step 6
    def onRobot(self):
        from RAMSICPRegistrationLib.navigation.navigation import points_of

        parameters = self._parameterNode
        with slicer.util.tryWithErrorDisplay("Robot calibration failed."):
            self.logic.navigation.robot_calibration(
                points_of(parameters.robotPositions, "robot positions"),
                points_of(parameters.trackerPositions, "tracker positions"),
                parameters.referenceToTracker,
                slicer.mrmlScene.GetFirstNodeByName("ReferenceToImage"),
            )

    # Step 7
    def onSave(self):
        path = qt.QFileDialog.getSaveFileName(None, "Save the navigation scene", "", "MRML scene (*.mrml)")
        if path:
            with slicer.util.tryWithErrorDisplay("Saving failed.", waitCursor=True):
                self.logic.navigation.save(path)

    def _showWarnings(self, warnings):
        self.ui.warningsTextEdit.plainText = "\n".join(warnings) if warnings else "No warnings."


class RAMSICPRegistrationLogic(ScriptedLoadableModuleLogic):
    """Facade: the module's parameter node, and the Qt-free NavigationLogic on Slicer's scene."""

    def __init__(self):
        ScriptedLoadableModuleLogic.__init__(self)
        from RAMSICPRegistrationLib.navigation.navigation import NavigationLogic

        autosave = os.path.join(slicer.app.temporaryPath, "RAMSICPNavigator-autosave")
        self.navigation = NavigationLogic(slicer.mrmlScene, autosave_directory=autosave)
        logging.info("RAMSICP Navigator saves every collected point to %s", autosave)

    def getParameterNode(self):
        return RAMSICPRegistrationParameterNode(super().getParameterNode())


class RAMSICPRegistrationTest(ScriptedLoadableModuleTest):
    """Runs the workflow scenario that pytest runs on slicer-core, here inside Slicer."""

    def setUp(self):
        slicer.mrmlScene.Clear()

    def runTest(self):
        self.setUp()
        self.test_workflow_on_a_ct_phantom()

    def test_workflow_on_a_ct_phantom(self):
        from RAMSICPRegistrationLib.navigation.scenarios import check_workflow, make_patient_and_ct, run_workflow

        self.delayDisplay("Building a CT phantom of the tibia (about 10 s)")
        patient, volume, truth = make_patient_and_ct()
        state = run_workflow(
            slicer.mrmlScene,
            patient,
            volume,
            truth,
            autosave_directory=os.path.join(slicer.app.temporaryPath, "RAMSICPSelfTest"),
        )
        figures = check_workflow(state)
        self.delayDisplay(
            f"Workflow passed: marker centres {figures['marker_error_mm']:.3f} mm, "
            f"targets {figures['target_error_mm']:.2f} mm"
        )
