"""OpenIGTLinkBridge: the live tracker feed in Slicer (NDI tracker -> OpenIGTLink with PLUS names -> transform nodes).

A thin shell over ``OpenIGTLinkBridgeLib.receiver.TrackerReceiver``: a timer polls it, labels show each tool's
status (valid, missing, stale, disconnected), and ``ProbeToReference`` (paper eq. 2) is kept up to date for the
RAMSICPRegistration module. Nodes that SlicerOpenIGTLink already feeds under the same names are reused.
"""

import qt
import slicer
from slicer.ScriptedLoadableModule import (
    ScriptedLoadableModule,
    ScriptedLoadableModuleLogic,
    ScriptedLoadableModuleTest,
    ScriptedLoadableModuleWidget,
)
from slicer.util import VTKObservationMixin

POLL_INTERVAL_MS = 20


class OpenIGTLinkBridge(ScriptedLoadableModule):
    def __init__(self, parent):
        ScriptedLoadableModule.__init__(self, parent)
        self.parent.title = "OpenIGTLink Bridge"
        self.parent.categories = ["IGT"]
        self.parent.dependencies = []
        self.parent.contributors = ["RAMSICP Navigator developers"]
        self.parent.helpText = (
            "Receives ProbeToTracker and ReferenceToTracker over OpenIGTLink (PLUS names, port 18944), keeps "
            "ProbeToReference = inv(ReferenceToTracker) * ProbeToTracker up to date and shows each tool's status. "
            "Start the server with: ramsicp-tracker-server --ndi HOST (or --serial DEV, or --simulate)."
        )
        self.parent.acknowledgementText = "NDI tool geometries: PLUS Toolkit, BSD-3-Clause."


class OpenIGTLinkBridgeWidget(ScriptedLoadableModuleWidget, VTKObservationMixin):
    def __init__(self, parent=None):
        ScriptedLoadableModuleWidget.__init__(self, parent)
        VTKObservationMixin.__init__(self)
        self.logic = None
        self.timer = qt.QTimer()

    def setup(self):
        ScriptedLoadableModuleWidget.setup(self)
        uiWidget = slicer.util.loadUI(self.resourcePath("UI/OpenIGTLinkBridge.ui"))
        self.layout.addWidget(uiWidget)
        self.ui = slicer.util.childWidgetVariables(uiWidget)
        uiWidget.setMRMLScene(slicer.mrmlScene)
        self.logic = OpenIGTLinkBridgeLogic()
        self.ui.connectButton.connect("toggled(bool)", self.onConnectToggled)
        self.timer.setInterval(POLL_INTERVAL_MS)
        self.timer.connect("timeout()", self.onTimer)

    def cleanup(self):
        self.timer.stop()
        self.logic.disconnect()

    def onConnectToggled(self, connect):
        if connect:
            with slicer.util.tryWithErrorDisplay("Could not start the tracker feed."):
                self.logic.connect(self.ui.hostLineEdit.text, int(self.ui.portSpinBox.value))
                self.timer.start()
                self.ui.connectButton.text = "Disconnect"
        else:
            self.timer.stop()
            self.logic.disconnect()
            self.ui.connectButton.text = "Connect"
            self.onTimer()

    def onTimer(self):
        if self.logic.receiver is not None:
            self.logic.receiver.poll()
        self.ui.referenceStatusLabel.text = f"ReferenceToTracker: {self.logic.status('ReferenceToTracker')}"
        self.ui.probeStatusLabel.text = f"ProbeToTracker: {self.logic.status('ProbeToTracker')}"


class OpenIGTLinkBridgeLogic(ScriptedLoadableModuleLogic):
    """Facade over the Qt-free receiver, on Slicer's scene."""

    def __init__(self):
        ScriptedLoadableModuleLogic.__init__(self)
        self.receiver = None

    def connect(self, host, port):
        from OpenIGTLinkBridgeLib.receiver import TrackerReceiver

        self.disconnect()
        self.receiver = TrackerReceiver(slicer.mrmlScene, host=host, port=port)

    def disconnect(self):
        if self.receiver is not None:
            self.receiver.close()
            self.receiver = None

    def status(self, device):
        return "disconnected" if self.receiver is None else self.receiver.status(device)


class OpenIGTLinkBridgeTest(ScriptedLoadableModuleTest):
    """Simulator -> driver -> server -> this module's receiver, inside Slicer."""

    def runTest(self):
        slicer.mrmlScene.Clear()
        self.test_live_feed()

    def test_live_feed(self):
        import time

        import numpy as np

        from OpenIGTLinkBridgeLib.igtl_server import TrackerServer
        from OpenIGTLinkBridgeLib.live_scenario import demo_simulator
        from OpenIGTLinkBridgeLib.ndi_driver import open_tracker

        simulator, script = demo_simulator(np.zeros((2, 3)))
        simulator.start()

        server = TrackerServer(lambda: open_tracker("127.0.0.1", simulator.address[1]), port=0).start()
        logic = OpenIGTLinkBridgeLogic()
        logic.connect("127.0.0.1", server.address[1])
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            logic.receiver.poll()
            slicer.app.processEvents()
        self.assertEqual(logic.status("ProbeToTracker"), "valid")
        self.assertIsNotNone(slicer.mrmlScene.GetFirstNodeByName("ProbeToReference"))
        logic.disconnect()
        server.stop()
        simulator.stop()
        self.delayDisplay("Live tracker feed test passed")
