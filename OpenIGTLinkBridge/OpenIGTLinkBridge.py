"""OpenIGTLinkBridge: the live tracker feed in Slicer (NDI tracker -> OpenIGTLink with PLUS names -> transform nodes).

A thin shell over ``OpenIGTLinkBridgeLib.bridge_controller.BridgeController`` (Qt-free, tested on slicer-core): a
timer asks it to poll, labels show each tool's status (valid, missing, stale, disconnected), and
``ProbeToReference`` (paper eq. 2) is kept up to date for the RAMSICPRegistration module. The tracker can be an
OpenIGTLink server already running (PLUS, ``ramsicp-tracker-server``) or be started here: then
``ramsicp-tracker-server`` runs in its own process with Slicer's Python (``PythonSlicer``, as Slicer's
``slicer.util._executePythonModule`` finds it), its log shown in the module, because threads of Slicer's own
process only advance while its GUI thread runs Python (PythonQt keeps the lock while Qt's event loop waits).
"""

import os
import shutil
from typing import Annotated

import qt
import slicer
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

from OpenIGTLinkBridgeLib.bridge_controller import SOURCES, BridgeController

POLL_INTERVAL_MS = 20

#: PLACEHOLDER until publication: the same address as EXTENSION_HOMEPAGE in the top-level CMakeLists.txt.
DOCUMENTATION_URL = "https://example.invalid/SlicerRAMSICPNavigator#live-tracker-feed"

#: Push button -> controller action.
BUTTON_ACTIONS = {
    "connectButton": "connect",
    "disconnectButton": "disconnect",
    "stopTrackerButton": "stop_tracker",
}


class OpenIGTLinkBridge(ScriptedLoadableModule):
    def __init__(self, parent):
        ScriptedLoadableModule.__init__(self, parent)
        self.parent.title = _("OpenIGTLink Bridge")
        self.parent.categories = [translate("qSlicerAbstractCoreModule", "IGT")]
        self.parent.dependencies = []
        self.parent.contributors = ["RAMSICP Navigator developers"]
        self.parent.helpText = (
            _(
                "Receives ProbeToTracker and ReferenceToTracker over OpenIGTLink (PLUS names, port 18944), keeps "
                "ProbeToReference = inv(ReferenceToTracker) * ProbeToTracker up to date and shows each tool's status. "
                "Connect to a running server (PLUS, or ramsicp-tracker-server from 'pip install ramsicp-navigator'), "
                "or start an NDI Vega, an NDI Polaris or the simulator from this module."
            )
            + f' <a href="{DOCUMENTATION_URL}">{_("Documentation")}</a>'
        )
        self.parent.acknowledgementText = _("NDI tool geometries: PLUS Toolkit, BSD-3-Clause.")


@parameterNodeWrapper
class OpenIGTLinkBridgeParameterNode:
    """The fields of ``OpenIGTLinkBridgeLib.bridge_controller.BRIDGE``, which the controller reads."""

    host: str = "127.0.0.1"
    port: Annotated[int, WithinRange(1, 65535)] = 18944
    trackerSource: Annotated[str, Choice(list(SOURCES))] = "ndi-network"
    trackerAddress: str = ""


class OpenIGTLinkBridgeWidget(ScriptedLoadableModuleWidget, VTKObservationMixin):
    def __init__(self, parent=None):
        ScriptedLoadableModuleWidget.__init__(self, parent)
        VTKObservationMixin.__init__(self)
        self.logic = None
        self._parameterNode = None
        self._parameterNodeGuiTag = None
        self._timer = None

    def setup(self):
        ScriptedLoadableModuleWidget.setup(self)
        uiWidget = slicer.util.loadUI(self.resourcePath("UI/OpenIGTLinkBridge.ui"))
        self.layout.addWidget(uiWidget)
        self.ui = slicer.util.childWidgetVariables(uiWidget)
        uiWidget.setMRMLScene(slicer.mrmlScene)
        self.logic = OpenIGTLinkBridgeLogic()
        self.addObserver(slicer.mrmlScene, slicer.mrmlScene.StartCloseEvent, self.onSceneStartClose)
        self.addObserver(slicer.mrmlScene, slicer.mrmlScene.EndCloseEvent, self.onSceneEndClose)
        for button, action in BUTTON_ACTIONS.items():
            getattr(self.ui, button).connect("clicked(bool)", lambda checked, action=action: self.run(action))
        self.ui.startTrackerButton.connect("clicked(bool)", self.onStartTracker)
        self.ui.recordButton.connect("toggled(bool)", self.onRecordToggled)
        # The feed keeps running while other modules are shown: the timer runs from setup to cleanup.
        self._timer = qt.QTimer(self.parent)
        self._timer.setInterval(POLL_INTERVAL_MS)
        self._timer.connect("timeout()", self.onTimer)
        self._timer.start()
        self.initializeParameterNode()

    def cleanup(self):
        if self._timer is not None:
            self._timer.stop()
        self.removeObservers()
        self.setParameterNode(None)
        if self.logic is not None:
            self.logic.controller.close()

    def enter(self):
        self.initializeParameterNode()

    def exit(self):
        pass  # the GUI stays bound to the parameter node: binding again at each enter() would add an observer

    def onSceneStartClose(self, caller, event):
        self.setParameterNode(None)

    def onSceneEndClose(self, caller, event):
        if self.parent.isEntered:
            self.initializeParameterNode()

    def initializeParameterNode(self):
        """Bind the GUI to the logic's parameter-node wrapper, once per parameter node (see the logic)."""
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

    def run(self, action, *args):
        with slicer.util.tryWithErrorDisplay(_("Unexpected error; the details are in the log."), waitCursor=True):
            self.logic.controller.run(action, *args)
        self.showStatus()

    def onRecordToggled(self, recording):
        if not recording:
            self.run("stop_recording")
            return
        path = qt.QFileDialog.getSaveFileName(
            None, _("Record the tracking to"), "", _("PLUS sequence file (*.igs.mha *.seq.mha)")
        )
        if path:
            self.run("start_recording", path)
        self.showStatus()

    def onStartTracker(self):
        """Install a package the chosen tracker needs (pyserial for a Polaris) right before its first use."""
        missing = self.logic.controller.missing_packages()
        if missing:
            if not slicer.util.confirmOkCancelDisplay(
                _("This tracker needs the Python package(s) {packages}. Install them now (internet needed)?").format(
                    packages=", ".join(missing)
                ),
                windowTitle=_("OpenIGTLink Bridge"),
            ):
                return
            failed = _("Installing {packages} failed.").format(packages=", ".join(missing))
            with slicer.util.tryWithErrorDisplay(failed):
                slicer.util.pip_install(" ".join(missing))
        self.run("start_tracker")

    def onTimer(self):
        self.logic.controller.poll()
        if self.parent.isEntered:
            self.showStatus()

    def showStatus(self):
        status = self.logic.controller.status()
        self.ui.connectionStatusLabel.text = status.connection
        tools = dict(status.tools)
        self.ui.referenceStatusLabel.text = f"ReferenceToTracker: {tools['ReferenceToTracker']}"
        self.ui.probeStatusLabel.text = f"ProbeToTracker: {tools['ProbeToTracker']}"
        self.ui.trackerStatusLabel.text = status.tracker
        self.ui.recordingStatusLabel.text = status.recording
        recording = status.recording.startswith("recording:")
        if self.ui.recordButton.checked != recording:
            wasBlocked = self.ui.recordButton.blockSignals(True)
            self.ui.recordButton.checked = recording
            self.ui.recordButton.blockSignals(wasBlocked)
        self.ui.messageLabel.text = status.message
        self.ui.messageLabel.styleSheet = "color: #c62828" if status.message_is_error else ""
        log = "\n".join(status.tracker_log)
        if self.ui.trackerLogTextEdit.plainText != log:  # set only when it changed: keeps the reader's scroll
            self.ui.trackerLogTextEdit.plainText = log


class OpenIGTLinkBridgeLogic(ScriptedLoadableModuleLogic):
    """Facade: the module's parameter node and the Qt-free controller on Slicer's scene. A tracker started here
    runs as ``ramsicp-tracker-server`` with ``PythonSlicer`` (on the PATH Slicer's launcher sets), logging into
    Slicer's temporary folder."""

    def __init__(self):
        ScriptedLoadableModuleLogic.__init__(self)
        self.controller = BridgeController(
            slicer.mrmlScene,
            tracker_python=shutil.which("PythonSlicer") or "PythonSlicer",
            log_directory=os.path.join(slicer.app.temporaryPath, "RAMSICPNavigator-tracker"),
        )
        self._parameterNode = None

    def getParameterNode(self):
        """The one wrapper of the scene's parameter node (a new one only when the node changed: a scene close):
        Slicer's parameterNodeWrapper adds an observer at every ``connectGui`` that it never removes."""
        node = super().getParameterNode()
        if self._parameterNode is None or self._parameterNode.parameterNode is not node:
            self._parameterNode = OpenIGTLinkBridgeParameterNode(node)
        return self._parameterNode


class OpenIGTLinkBridgeTest(ScriptedLoadableModuleTest):
    """Simulator -> driver -> server (its own process, PythonSlicer) -> this module's controller and receiver."""

    def runTest(self):
        slicer.mrmlScene.Clear()
        self.test_live_feed()

    def test_live_feed(self):
        import time

        logic = OpenIGTLinkBridgeLogic()
        logic.controller.parameters.trackerSource = "simulator"
        try:
            logic.controller.start_tracker(port=0)  # a free port: a fixed one may be taken on a test machine
            end = time.monotonic() + 30.0  # the tracker process starts (Python, numpy, the simulator) first
            while time.monotonic() < end and dict(logic.controller.status().tools)["ProbeToTracker"] != "valid":
                logic.controller.poll()
                slicer.app.processEvents()
            self.assertEqual(dict(logic.controller.status().tools)["ProbeToTracker"], "valid")
            self.assertIsNotNone(slicer.mrmlScene.GetFirstNodeByName("ProbeToReference"))
        finally:
            logic.controller.close()
        self.delayDisplay(_("Live tracker feed test passed"))
