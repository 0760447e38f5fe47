"""The OpenIGTLinkBridge module's behaviour, Qt-free: the tracker feed into a scene, for the widget and tests.

Two ways to get poses into the scene:

* **connect** to an OpenIGTLink server already running (PLUS, ``ramsicp-tracker-server``, or any PLUS-named
  source) at the parameter node's ``host``:``port``;
* **start the tracker here**: an NDI Vega on the network, an NDI Polaris on a serial line, or the simulator,
  served by our PLUS-compatible server on ``127.0.0.1``:``port``, and connected to at once. An extension install
  has no ``ramsicp-tracker-server`` command; this is how Slicer users start the feed. Given a Python executable
  (``tracker_python``; the Slicer module hands in ``PythonSlicer``) the server runs as ``ramsicp-tracker-server``
  in its own process (``tracker_process``), whose log ``status()`` shows: inside Slicer, threads of Slicer's
  process advance only while its GUI thread runs Python, and a server there would starve. Without one (plain
  Python: the browser view, scripts) it runs in threads of this process.

``poll()`` (the widget's timer) moves poses into the transform nodes; ``status()`` reports the connection and each
tool (valid / missing / stale / never seen / disconnected). What the connection receives can be recorded to a PLUS
sequence file (``start_recording``), which PLUS, Slicer's Sequences module and ``--replay`` read back. A scene close
drops the connection (its nodes are gone) and connects again to the new scene if it was connected. Host, port and
tracker choice are kept in the module's parameter node, so they are saved with the scene.
"""

import importlib.util
import logging
import socket
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

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
    tracker_log: tuple = ()  # the last lines of the tracker process's log (when the tracker runs in its own process)


class BridgeController:
    """The tracker feed into ``scene``.

    Args:
        scene: the vtkMRMLScene the transform nodes go into.
        clock: monotonic clock (s) for the receiver's stale checks.
        simulator_options: keyword arguments for ``live_scenario.demo_simulator`` when the simulator is started
            in this process (e.g. a pivot phase and a loop for the browser view's demo).
        tracker_python: a Python executable: the tracker started here then runs as ``ramsicp-tracker-server`` in
            its own process (``tracker_process``). Slicer's module hands in ``PythonSlicer``.
        log_directory: where the tracker process's log goes (default: a new temporary folder).
    """

    ACTIONS = ("connect", "disconnect", "start_tracker", "stop_tracker", "start_recording", "stop_recording")

    def __init__(self, scene, clock=time.monotonic, simulator_options=None, tracker_python=None, log_directory=None):
        self.scene, self.clock = scene, clock
        self.simulator_options = dict(simulator_options or {})
        self.tracker_python, self.log_directory = tracker_python, log_directory
        self.receiver = None
        self.server = None
        self.simulator = None
        self.process = None  # the TrackerProcess, when the tracker runs in its own process
        self.process_port = None  # the port it serves on
        self._reconnect_after_close = None  # (host, port) to connect to again after a scene close
        self._last_log = ()  # the log of the last tracker process, once stopped
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

    # -- a tracker started here -----------------------------------------------------------------------------
    def missing_packages(self, source=None):
        """pip requirements the tracker source needs and lacks (installed by the shell right before first use)."""
        source = self.parameters.trackerSource if source is None else source
        needed = SOURCE_REQUIREMENTS.get(source, {})
        return [requirement for module, requirement in needed.items() if importlib.util.find_spec(module) is None]

    def start_tracker(self, port=None):
        """Start the chosen tracker behind a PLUS-compatible server on 127.0.0.1:``port`` (default: the parameter
        node's; 0: any free port), and connect to it. With ``tracker_python`` the server is a process of its own,
        and this returns once it is started (the receiver connects when it listens); its log is in ``status()``."""
        parameters = self.parameters
        source, address = parameters.trackerSource, str(parameters.trackerAddress).strip()
        port = parameters.port if port is None else port
        missing = self.missing_packages(source)
        if missing:
            raise RuntimeError(f"the {source} tracker needs the Python package(s) {', '.join(missing)}; install them")
        self.stop_tracker()
        if source == "ndi-network":
            parse_ndi_address(address)  # a bad address is a message now, not a line in a log later
        elif source == "ndi-serial" and not address:
            raise ValueError("give the Polaris's serial device, e.g. /dev/ttyUSB0 or COM3")
        if self.tracker_python is not None:
            self._start_tracker_process(source, address, port)
        else:
            self._start_tracker_here(source, address, port)

    def _start_tracker_process(self, source, address, port):
        from .tracker_process import TrackerProcess

        port = _free_port() if port == 0 else _check_port_free(port)
        arguments = {
            "simulator": ["--simulate"],
            "ndi-network": ["--ndi", address],
            "ndi-serial": ["--serial", address],
        }
        if self.log_directory is None:
            self.log_directory = tempfile.mkdtemp(prefix="ramsicp-tracker-")
        log_path = Path(self.log_directory) / "ramsicp-tracker-server.log"
        command = [*arguments[source], "--host", "127.0.0.1", "--port", str(port)]
        self.process = TrackerProcess(self.tracker_python, command, log_path).start()
        self.process_port = port
        self.connect("127.0.0.1", port)
        self._say(f"{source} tracker starting in its own process (pid {self.process.process.pid}), on 127.0.0.1:{port}")

    def _start_tracker_here(self, source, address, port):
        from RAMSICPRegistrationLib.io.ndi_tools import DEFAULT_PROBE_TOOL, DEFAULT_REFERENCE_TOOL, tool_rom_path

        from .ndi_driver import open_tracker

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
            host, ndi_port, serial = None, NDI_PORT, address

        def open_ndi():
            return open_tracker(host, ndi_port, serial, roms)

        try:
            self.server = TrackerServer(open_ndi, "127.0.0.1", port, names=DEFAULT_NAMES).start()
        except OSError as error:
            self.stop_tracker()
            raise OSError(_busy(port, error)) from None
        port = self.server.address[1]  # the port chosen by the system when 0 was asked for
        self.connect("127.0.0.1", port)
        self._say(f"{source} tracker started, served on 127.0.0.1:{port}")

    def stop_tracker(self):
        if self.process is not None:
            pid, code = self.process.process.pid, self.process.stop()
            self._last_log = tuple(self.process.log_lines())
            self._say(f"tracker process {pid} stopped (exit code {code})")
            self.process = None
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
        log = self._last_log
        if self.server is not None:
            tracker = f"tracker served on 127.0.0.1:{self.server.address[1]}"
        elif self.process is not None:
            log = tuple(self.process.log_lines())
            pid, code = self.process.process.pid, self.process.exit_code
            if code is None:
                tracker = f"tracker running in process {pid}, on 127.0.0.1:{self.process_port}"
            else:
                last = next((line for line in reversed(log) if line.strip()), "no output")
                tracker = f"tracker process {pid} ended (exit code {code}): {last}"
        recording = ""
        if receiver is not None and receiver.recorder is not None:
            recording = f"recording: {receiver.recorder.frames} frames to {receiver.recorder.path}"
        elif receiver is not None and receiver.recording_error:
            recording = f"recording stopped: {receiver.recording_error}"
        return BridgeStatus(connection, tools, tracker, recording, *self._message, tracker_log=log)

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


def _busy(port, error):
    return f"cannot serve OpenIGTLink on 127.0.0.1:{port} ({error.strerror or error}); choose another port"


def _check_port_free(port):
    """``port``, after checking that a server can listen on it on 127.0.0.1 (the process would say so only in its
    log, a moment later); raises OSError saying so."""
    try:
        with socket.create_server(("127.0.0.1", port)):
            return port
    except OSError as error:
        raise OSError(_busy(port, error)) from None


def _free_port():
    """A port on 127.0.0.1 that no server listens on now (the system's choice)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]
