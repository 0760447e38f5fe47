"""The OpenIGTLinkBridge module's behaviour, Qt-free: the tracker feed into a scene, for the widget and tests.

Two ways to get poses into the scene:

* **connect** to an OpenIGTLink server already running (PLUS, ``ramsicp-tracker-server``, or any PLUS-named
  source) at the parameter node's ``host``:``port``;
* **start the tracker here**: an NDI Vega on the network, an NDI Polaris on a serial line, or the simulator,
  served by our PLUS-compatible server inside this process on ``127.0.0.1``:``port``, and connected to at once.
  An extension install has no ``ramsicp-tracker-server`` command; this is how Slicer users start the feed.

``poll()`` (the widget's timer) moves poses into the transform nodes; ``status()`` reports the connection and each
tool (valid / missing / stale / never seen / disconnected). What the connection receives can be recorded to a PLUS
sequence file (``start_recording``), which PLUS, Slicer's Sequences module and ``--replay`` read back. A scene close
drops the connection (its nodes are gone) and connects again to the new scene if it was connected. Host, port and
tracker choice are kept in the module's parameter node, so they are saved with the scene.
"""

import importlib.util
import logging
import time
from dataclasses import dataclass

from RAMSICPRegistrationLib.navigation.parameters import Parameter, ParameterSet

from .igtl_server import DEFAULT_NAMES, DEFAULT_PORT, TrackerServer
from .ndi_driver import NDI_PORT, parse_ndi_address
from .receiver import TrackerReceiver

logger = logging.getLogger(__name__)

SOURCES = ("ndi-network", "ndi-serial", "simulator")

BRIDGE = ParameterSet(
    "OpenIGTLinkBridge",
    (
        Parameter("host", "text", "OpenIGTLink server to connect to", default="127.0.0.1"),
        Parameter("port", "int", "OpenIGTLink port", default=DEFAULT_PORT, minimum=1, maximum=65535),
        Parameter("trackerSource", "choice", "tracker to start in Slicer", default="ndi-network", choices=SOURCES),
        Parameter("trackerAddress", "text", "NDI Vega HOST[:PORT] or serial device", default=""),
    ),
)

#: Python packages a tracker source needs that Slicer does not ship: import name -> pip requirement.
SOURCE_REQUIREMENTS = {"ndi-serial": {"serial": "pyserial"}}


@dataclass(frozen=True)
class BridgeStatus:
    """What the widget shows: the connection in words, each tool's state, and the tracker started here."""

    connection: str
    tools: tuple  # (device name, state) for the probe and the reference body
    tracker: str
    recording: str = ""
    message: str = ""
    message_is_error: bool = False


class BridgeController:
    """The tracker feed into ``scene``.

    Args:
        scene: the vtkMRMLScene the transform nodes go into.
        clock: monotonic clock (s) for the receiver's stale checks.
        simulator_options: keyword arguments for ``live_scenario.demo_simulator`` when the simulator is started
            (e.g. a pivot phase and a loop for the browser view's demo).
    """

    ACTIONS = ("connect", "disconnect", "start_tracker", "stop_tracker", "start_recording", "stop_recording")

    def __init__(self, scene, clock=time.monotonic, simulator_options=None):
        self.scene, self.clock = scene, clock
        self.simulator_options = dict(simulator_options or {})
        self.receiver = None
        self.server = None
        self.simulator = None
        self._reconnect_after_close = None  # (host, port) to connect to again after a scene close
        self._message = ("", False)
        self._tags = [
            scene.AddObserver(scene.StartCloseEvent, self._on_scene_start_close),
            scene.AddObserver(scene.EndCloseEvent, self._on_scene_end_close),
        ]

    @property
    def parameters(self):
        return BRIDGE.on(BRIDGE.get_node(self.scene))

    def run(self, action, *args):
        """Run an action as the widget does: problems become the status message, never an exception."""
        if action not in self.ACTIONS:
            raise ValueError(f"unknown action {action!r}; actions are {', '.join(self.ACTIONS)}")
        try:
            return getattr(self, action)(*args)
        except (ValueError, RuntimeError, OSError) as error:
            self._say(str(error), True)
            return None

    def _say(self, text, is_error=False):
        self._message = (text, is_error)
        (logger.warning if is_error else logger.info)(text)

    # -- connection to a server ----------------------------------------------------------------------------
    def connect(self, host=None, port=None):
        """Connect to the OpenIGTLink server at ``host``:``port`` (default: the parameter node's); non-blocking."""
        parameters = self.parameters
        host = parameters.host if host is None else host
        port = parameters.port if port is None else port
        if not str(host).strip():
            raise ValueError("the OpenIGTLink server's host is empty: give its address, e.g. 127.0.0.1")
        parameters.host, parameters.port = host, port
        self.disconnect()
        self.receiver = TrackerReceiver(self.scene, host=host, port=port, clock=self.clock)
        self._say(f"connecting to {host}:{port}")

    def disconnect(self):
        if self.receiver is not None:
            self.receiver.close()
            self.receiver = None
            self._say("disconnected")

    def poll(self):
        """Apply what has arrived; returns the number of messages applied (0 when not connected)."""
        return 0 if self.receiver is None else self.receiver.poll()

    # -- recording ---------------------------------------------------------------------------------------------
    def start_recording(self, path):
        """Record every transform the connection receives to the PLUS sequence file ``path`` (.igs.mha)."""
        if self.receiver is None:
            raise ValueError("connect to a tracker first: the recording holds what the connection receives")
        self.receiver.start_recording(path)
        self._say(f"recording to {path}")

    def stop_recording(self):
        """Close the recording; returns its path."""
        if self.receiver is None or self.receiver.recorder is None:
            raise ValueError("nothing is being recorded")
        frames = self.receiver.recorder.frames
        path = self.receiver.stop_recording()
        self._say(f"recorded {frames} frames to {path}")
        return path

    # -- a tracker started in this process -----------------------------------------------------------------
    def missing_packages(self, source=None):
        """pip requirements the tracker source needs and lacks (installed by the shell right before first use)."""
        source = self.parameters.trackerSource if source is None else source
        needed = SOURCE_REQUIREMENTS.get(source, {})
        return [requirement for module, requirement in needed.items() if importlib.util.find_spec(module) is None]

    def start_tracker(self, port=None):
        """Start the chosen tracker behind a PLUS-compatible server on 127.0.0.1:``port`` (default: the parameter
        node's; 0: any free port), and connect to it."""
        from RAMSICPRegistrationLib.io.ndi_tools import DEFAULT_PROBE_TOOL, DEFAULT_REFERENCE_TOOL, tool_rom_path

        from .ndi_driver import open_tracker

        parameters = self.parameters
        source, address = parameters.trackerSource, parameters.trackerAddress
        port = parameters.port if port is None else port
        missing = self.missing_packages(source)
        if missing:
            raise RuntimeError(f"the {source} tracker needs the Python package(s) {', '.join(missing)}; install them")
        self.stop_tracker()
        roms = {"Reference": tool_rom_path(DEFAULT_REFERENCE_TOOL), "Probe": tool_rom_path(DEFAULT_PROBE_TOOL)}
        serial = None
        if source == "simulator":
            from .live_scenario import demo_simulator

            self.simulator, _ = demo_simulator(**self.simulator_options)
            self.simulator.start()
            host, ndi_port = self.simulator.address[:2]
        elif source == "ndi-network":
            host, ndi_port = parse_ndi_address(address)
        else:
            if not str(address).strip():
                raise ValueError("give the Polaris's serial device, e.g. /dev/ttyUSB0 or COM3")
            host, ndi_port, serial = None, NDI_PORT, address.strip()

        def open_ndi():
            return open_tracker(host, ndi_port, serial, roms)

        try:
            self.server = TrackerServer(open_ndi, "127.0.0.1", port, names=DEFAULT_NAMES).start()
        except OSError as error:
            self.stop_tracker()
            raise OSError(
                f"cannot serve OpenIGTLink on 127.0.0.1:{port} ({error.strerror or error}); choose another port"
            ) from None
        port = self.server.address[1]  # the port chosen by the system when 0 was asked for
        self.connect("127.0.0.1", port)
        self._say(f"{source} tracker started, served on 127.0.0.1:{port}")

    def stop_tracker(self):
        if self.server is not None:
            self.server.stop()
            self.server = None
        if self.simulator is not None:
            self.simulator.stop()
            self.simulator = None

    # -- what the widget shows -----------------------------------------------------------------------------
    def status(self):
        receiver = self.receiver
        devices = (DEFAULT_NAMES["Reference"], DEFAULT_NAMES["Probe"])
        if receiver is None:
            connection = "not connected"
        elif receiver.connected:
            connection = f"connected to {receiver.host}:{receiver.port}"
        else:
            connection = receiver.resolution_error or f"connecting to {receiver.host}:{receiver.port} ..."
        tools = tuple((device, "disconnected" if receiver is None else receiver.status(device)) for device in devices)
        tracker = "no tracker started here"
        if self.server is not None:
            tracker = f"tracker served on 127.0.0.1:{self.server.address[1]}"
        recording = ""
        if receiver is not None and receiver.recorder is not None:
            recording = f"recording: {receiver.recorder.frames} frames to {receiver.recorder.path}"
        elif receiver is not None and receiver.recording_error:
            recording = f"recording stopped: {receiver.recording_error}"
        return BridgeStatus(connection, tools, tracker, recording, *self._message)

    # -- scene -------------------------------------------------------------------------------------------------
    def _on_scene_start_close(self, caller=None, event=None):
        self._reconnect_after_close = None
        if self.receiver is not None:
            self._reconnect_after_close = (self.receiver.host, self.receiver.port)
            self.receiver.close()  # its transform nodes are being removed with the scene
            self.receiver = None

    def _on_scene_end_close(self, caller=None, event=None):
        if self._reconnect_after_close is not None:
            self.connect(*self._reconnect_after_close)  # the same server, into the new scene

    def close(self):
        """Stop everything this controller started and remove its observers (the widget is going away)."""
        self.disconnect()
        self.stop_tracker()
        for tag in self._tags:
            self.scene.RemoveObserver(tag)
        self._tags = []
