"""The browser navigation view: a trame app on trame-slicer (real MRML and Slicer's displayable managers, no Qt).

A second thin shell over the same ``NavigationController`` as the Slicer module (DESIGN.md, "Two shells, one
controller"): buttons call ``controller.run(action, ...)``, the panel shows ``status()``, ``availability()``,
``last_result`` and the parameter node (``panel_state``), and the only listener is ``controller.add_listener``.
The tracker feed is a ``BridgeController`` (connect to an OpenIGTLink server, or the simulator started here).
What this module adds is display only: views, the probe needle, residual-coloured points, slices that follow the
tip (``scene_display``).

The event loop (asyncio, trame's) does everything in one thread, as Slicer's GUI thread does: it polls the
receiver every ``POLL_INTERVAL_S`` (new poses reach the MRML nodes, the controller and the displayable managers,
which ask trame-rca for a render) and services the robot link (``controller.service()``), and refreshes the panel
every ``PANEL_INTERVAL_S``.

The page can open no file: it has no path input and no upload; the scene is saved into the output folder named
on the command line, in a new sub-folder per save.
"""

import asyncio
import itertools
import logging
import os
import socket
import tempfile
import time
import zipfile
from pathlib import Path

from ..core.transforms import apply_transform, invert_transform
from ..navigation import mrml_nodes
from ..navigation.controller import NavigationController
from ..navigation.navigation import load_scene
from .panel_state import panel_state
from .scene_display import (
    bone_as_saved,
    follow_tip,
    move_needle,
    quiet_transform_managers,
    style_workflow_nodes,
    update_needle,
    update_residual_points,
)
from .vtk_warnings import views_created_quietly

logger = logging.getLogger(__name__)

POLL_INTERVAL_S = 0.004
PANEL_INTERVAL_S = 0.2
#: Frames per second the 3D view and the slices are rendered at, at most; trame-rca renders only after a change.
#: The slices follow the tip at their rate: each move re-slices the CT in three views, and on two cores shared
#: with the encoder and the browser, slices at 30 Hz starve the 3D view (measured: 2 frames/s instead of 15).
TARGET_FPS = 30.0
SLICE_FPS = 10.0
#: Threads of VTK's threaded image filters (vtkMultiThreader, which the slices' reslicing of the CT uses), for the
#: whole server process. VTK's default is one per core; on two cores shared with the encoder, the tracker and the
#: browser, one thread gives the 3D view more distinct frames per second (benchmarks/bench_web_view.py, medians
#: with the IPC's display copy: 20.1 instead of 18.4 at trame-rca's JPEG defaults, 17.1 instead of 14.4 at quality
#: 90).
VTK_FILTER_THREADS = 1
LAYOUT_ID = "RAMSICP navigation"
#: The browser demo's simulated probe: a 10 s pivot, then each of the 40 touches held for 1.2 s; again and again.
DEMO_SIMULATOR = {"pivot_s": 10.0, "dwell_s": 1.2, "move_s": 0.4, "loop": True}
TRACKER_NODES = {"probeToReference": "ProbeToReference", "referenceToTracker": "ReferenceToTracker"}
SCENE_SUFFIXES = (".mrb", ".mrml")
_SERVER_NUMBERS = itertools.count(1)


def configure_environment():
    """Offscreen EGL rendering (no X server), and trame must not read ``ramsicp``'s own command line."""
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    os.environ.setdefault("TRAME_ARGS", "")


def parse_tracker_address(text):
    """'HOST:PORT' of an OpenIGTLink server -> (host, port); ValueError saying what is wrong."""
    host, separator, port = str(text).strip().rpartition(":")
    if not separator or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f"--tracker {text!r}: give HOST:PORT of the OpenIGTLink server, e.g. 127.0.0.1:18944")
    return host, int(port)


def check_port_free(host, port):
    """The port the page will be served on (a free one when ``port`` is 0); OSError when it is taken."""
    try:
        with socket.create_server((host, port)) as probe:
            return probe.getsockname()[1]
    except OSError as error:
        raise OSError(
            f"cannot serve the page on {host}:{port} ({error.strerror or error}); choose another --port"
        ) from None


def check_scene_path(path):
    """A scene file the command line names: ValueError when it is missing, a folder, or not a Slicer scene."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"--scene {path}: is a folder; give a .mrb or .mrml file")
    if not path.is_file():
        raise ValueError(f"--scene {path}: no such file")
    if path.suffix.lower() not in SCENE_SUFFIXES:
        raise ValueError(f"--scene {path}: give a Slicer scene, .mrb or .mrml")
    return path


def check_output_directory(path):
    """The folder for autosaves and saved scenes, created and written to once; OSError saying so when it cannot
    be (a file is there, no permission, a full disk): before anything is collected, not after."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".write-check-"):
            pass
    except OSError as error:
        reason = error.strerror or error
        raise OSError(f"--output {path}: cannot write there ({reason}); choose another folder") from None
    return path


def navigation_layout():
    """The 3D view on the left, the axial, coronal and sagittal slices stacked on the right."""
    from trame_slicer.views import Layout, LayoutDirection, ViewLayoutDefinition

    slices = [ViewLayoutDefinition.axial_view(), ViewLayoutDefinition.coronal_view()]
    slices.append(ViewLayoutDefinition.sagittal_view())
    return Layout(
        LayoutDirection.Horizontal,
        [ViewLayoutDefinition.threed_view(), Layout(LayoutDirection.Vertical, slices)],
        flex_sizes=["3", "2"],
    )


def unrendered_while_built(view_class):
    """A constructor of ``view_class`` (trame-slicer's ThreeDView or SliceView) whose view does not render while it
    is being set up. trame-slicer's views render at once on every change until the factory hands them to trame-rca
    (which renders for the page, at most at the view's frame rate, once a page shows them): 244 renders of four
    views nobody sees, 2.0 s of a demo start at load 6 (cProfile). The factory replaces this strategy by its own."""
    from trame_slicer.views import NoScheduleRendering

    def build(**arguments):
        return view_class(scheduled_render_strategy=NoScheduleRendering(), **arguments)

    return build


class NavigationWebApp:
    """The trame server, the Slicer views and the two controllers of one browser navigation session.

    Use: ``app = NavigationWebApp(output)``; optionally ``app.load_scene(path)``; then ``app.start_workflow()``;
    optionally ``app.add_demo_patient()``; then ``app.connect_tracker(host, port)`` or ``app.start_simulator()``;
    finally ``app.serve(host, port, on_ready)`` (blocks until the server stops).

    Args:
        output_directory: where collected points are autosaved and scenes are saved (created when needed).
        target_fps, slice_fps: the 3D view's and the slices' rendering rates, at most (frames per second).
    """

    def __init__(self, output_directory, target_fps=TARGET_FPS, slice_fps=SLICE_FPS):
        configure_environment()
        from trame.app import get_server
        from trame_slicer.core import LayoutManager, SlicerApp
        from trame_slicer.rca_view import RemoteViewFactory
        from trame_slicer.views import SliceView, ThreeDView, ViewType

        self.output_directory = Path(output_directory)
        from .panel import slice_view_gutter, three_d_view_gutter

        self.server = get_server(f"RAMSICP navigation {next(_SERVER_NUMBERS)}", client_type="vue3")
        self.slicer = SlicerApp()
        self.scene = self.slicer.scene
        # blur_fps=None: a second screen nobody hovers renders as fast as the focused one.
        for view_class, view_type, gutter, fps in (
            (ThreeDView, ViewType.THREE_D_VIEW, three_d_view_gutter, target_fps),
            (SliceView, ViewType.SLICE_VIEW, slice_view_gutter, slice_fps),
        ):
            self.slicer.view_manager.register_factory(
                RemoteViewFactory(
                    self.server,
                    unrendered_while_built(view_class),
                    view_type,
                    populate_view_ui_f=gutter,
                    target_fps=fps,
                    blur_fps=None,
                )
            )
        self.layout = LayoutManager(self.scene, self.slicer.view_manager, self.server)
        with views_created_quietly():  # the slice views' VTK 9.6 deprecation warning, and only it
            self.layout.register_layout(LAYOUT_ID, navigation_layout())  # creates the views
            self.layout.create_layout_views_if_needed(LAYOUT_ID)
        self.layout.set_layout(LAYOUT_ID)
        for view in self.slicer.view_manager.get_views():
            view.render_window().SetMultiSamples(0)  # 8x multisampling costs 10x on software GL
            quiet_transform_managers(view._displayable_manager_group)  # trame-slicer has no public accessor
        self.controller = None
        self.bridge = None
        self._tasks = []
        self._tip_moved = False
        self.follow_interval_s = 1.0 / slice_fps

    # -- what the session works on -------------------------------------------------------------------------
    def load_scene(self, path):
        """Read a scene saved by Slicer or by this view (.mrb, or .mrml with its data files); before
        ``start_workflow``. ValueError when the file is missing, a folder or unreadable."""
        path = check_scene_path(path)
        try:
            if path.suffix.lower() == ".mrb":
                with tempfile.TemporaryDirectory() as folder, zipfile.ZipFile(path) as archive:
                    archive.extractall(folder)
                    scenes = sorted(Path(folder).rglob("*.mrml"))
                    if not scenes:
                        raise ValueError(f"--scene {path}: the archive holds no .mrml scene")
                    load_scene(self.scene, scenes[0])
            else:
                load_scene(self.scene, path)
        except (RuntimeError, zipfile.BadZipFile, OSError) as error:
            raise ValueError(f"--scene {path}: cannot read it ({error})") from None

    def start_workflow(self, simulator_options=None):
        """Create the controllers on the scene, listen to the navigation controller and show its nodes."""
        from OpenIGTLinkBridgeLib.bridge_controller import BridgeController
        from OpenIGTLinkBridgeLib.robot_link import RobotLink

        check_output_directory(self.output_directory)
        self.controller = NavigationController(
            self.scene, autosave_directory=self.output_directory, robot_link_factory=RobotLink
        )
        options = DEMO_SIMULATOR if simulator_options is None else simulator_options
        self.bridge = BridgeController(self.scene, simulator_options=options)
        parameters = self.controller.parameters
        for name, node_name in TRACKER_NODES.items():  # the receiver writes into these nodes, found by name
            if getattr(parameters, name) is None:
                setattr(parameters, name, self.controller.steps.transform_node(node_name))
        self.controller.add_listener(self._on_workflow_event)
        self._show_workflow_nodes()

    def add_demo_patient(self):
        """The demo patient: its CT phantom processed into the IPC and marker centres, the reference body's
        marker centres, and the four osteotomy targets in both frames (so the page shows a TRE)."""
        from ..navigation.image_side_cache import cached_image_side
        from ..navigation.scenarios import cached_patient_and_ct

        patient, volume, built = cached_patient_and_ct()  # built once, then read from the user's cache (< 1 s)
        logger.info("demo CT phantom %s", "built and cached" if built else "read from the cache")
        parameters = self.controller.parameters
        parameters.ctVolume = mrml_nodes.volume_node(self.scene, volume, "CT")
        self.controller.steps.image_processor = cached_image_side  # the same CT at every start: processed once
        image = self.controller.process_ct()
        if image is None or image.warnings:
            reasons = "processing failed" if image is None else "; ".join(image.warnings)
            raise RuntimeError(f"the demo CT did not give clean marker spheres: {reasons}")
        self.controller.add_reference_body_markers()
        targets_patient = apply_transform(invert_transform(patient.reference_to_image), patient.targets_image)
        labels = [f"T{number + 1}" for number in range(len(targets_patient))]
        parameters.targetsImage = mrml_nodes.fiducial_node(self.scene, patient.targets_image, labels, "TargetsImage")
        parameters.targetsPatient = mrml_nodes.fiducial_node(self.scene, targets_patient, labels, "TargetsPatient")
        parameters.targetsImage.GetDisplayNode().SetGlyphSize(3.0)
        self._show_workflow_nodes()

    def connect_tracker(self, host, port):
        """Follow the OpenIGTLink server at ``host``:``port`` (reconnects by itself when it comes back)."""
        self.bridge.connect(host, port)

    def start_simulator(self):
        """The simulated Vega playing the demo patient's pivot and touches, served here on a free port."""
        self.bridge.parameters.trackerSource = "simulator"
        self.bridge.start_tracker(0)

    # -- display -------------------------------------------------------------------------------------------
    def _show_workflow_nodes(self):
        parameters = self.controller.parameters
        style_workflow_nodes(parameters)
        update_needle(self.scene, parameters.probeTipToProbe)
        update_residual_points(self.scene, parameters.residualTable, parameters.referenceToImage)
        if parameters.ctVolume is not None:
            self.slicer.display_manager.show_volume_in_slice_background(parameters.ctVolume)
        self.slicer.display_manager.reset_views()

    def _on_workflow_event(self, event, data):
        parameters = self.controller.parameters
        if event == "pose":
            if data == "ProbeToReference" and move_needle(self.scene, parameters.probeTipToProbe):
                self._tip_moved = True  # the slices follow in the poll loop, at most at the views' frame rate
            return
        if event == "pivot" and data is not None:
            update_needle(self.scene, parameters.probeTipToProbe)
        elif event in ("registered", "accepted"):
            update_residual_points(self.scene, parameters.residualTable, parameters.referenceToImage)
            move_needle(self.scene, parameters.probeTipToProbe)
            self._tip_moved = True
        elif event in ("collected", "reset", "image"):
            style_workflow_nodes(parameters)

    @staticmethod
    def _registered(parameters):
        probe, registration = parameters.probeToReference, parameters.referenceToImage
        return probe is not None and registration is not None and probe.GetParentTransformNode() is registration

    # -- the page's actions --------------------------------------------------------------------------------
    def run(self, action, *args):
        """Run a controller action as the page's buttons do, then refresh the panel. Poses that arrived while the
        event loop was busy (rendering, a save) are applied first: the action works on the newest pose, and a
        tracker that is streaming is never judged stale because this process was late to read it. Returns None:
        trame sends a handler's result to the page, and the page needs none (what happened is in the panel)."""
        self.bridge.poll()
        if action == "save":
            with bone_as_saved(self.scene):  # the scene as Slicer will show it: the IPC itself, not its display copy
                self.controller.run(action, *args)
        else:
            self.controller.run(action, *args)
        self.refresh_panel()

    def run_after_showing_busy(self, action, *args):
        """For a long action (registration, saving): show 'busy' on the page first, then run it."""
        with self.server.state:
            self.server.state.busy = action

        async def later():
            await asyncio.sleep(0.05)
            try:
                self.run(action, *args)
            finally:
                with self.server.state:
                    self.server.state.busy = ""

        self._tasks = [task for task in self._tasks if not task.done()] + [asyncio.ensure_future(later())]

    def register(self):
        self.run_after_showing_busy("register")

    def save(self):
        folder = self.output_directory / time.strftime("scene-%Y%m%d-%H%M%S")
        self.run_after_showing_busy("save", folder / "navigation.mrml")

    def set_included(self, index, included):
        self.run("set_included", int(index), bool(included))
        update_residual_points(
            self.scene, self.controller.parameters.residualTable, self.controller.parameters.referenceToImage
        )

    def set_target_tre(self, value):
        """The error the plan allows at its targets (mm), typed on the page: 'enough' is judged against it."""
        try:
            self.controller.parameters.targetTreMm = float(value)
        except (TypeError, ValueError) as error:  # an empty or out-of-range field: the old limit stays
            logger.info("target TRE %r not taken: %s", value, error)
        self.refresh_panel()

    def place_plane(self, level_mm, tilt_anterior_deg, tilt_side_deg, entry_deg):
        """Place the osteotomy plane from the page's fields (an empty field keeps the plane's value)."""
        values = [None if value in (None, "") else value for value in (level_mm, tilt_anterior_deg, tilt_side_deg)]
        self.run("place_osteotomy_plane", *values, None if entry_deg in (None, "") else entry_deg)
        self._show_plane_inputs()

    def place_plane_at_tip(self):
        self.run("place_plane_at_tip")
        self._show_plane_inputs()

    def _show_plane_inputs(self):
        """The page's plane fields show the placement the controller made."""
        placement = self.controller.status().plane_placement
        if placement is None:
            return
        with self.server.state:
            self.server.state.update(
                plane_level=round(placement.level_mm, 1) + 0.0,  # + 0.0: never '-0'
                plane_tilt_anterior=round(placement.tilt_anterior_deg, 1) + 0.0,
                plane_tilt_side=round(placement.tilt_side_deg, 1) + 0.0,
                plane_entry=round(placement.entry_deg) % 360,
            )

    def set_choice(self, name, value):
        """The method or policy chosen on the page, written into the parameter node."""
        try:
            setattr(self.controller.parameters, name, value)
        except ValueError as error:
            logger.warning("%s", error)
        self.refresh_panel()

    def refresh_panel(self):
        with self.server.state:
            self.server.state.update(panel_state(self.controller, self.bridge.status()))

    # -- serving -------------------------------------------------------------------------------------------
    def build_page(self):
        from .panel import build_page

        self.server.state.update(panel_state(self.controller, self.bridge.status()))
        self.server.state.busy = ""
        self.server.state.update(plane_level="", plane_tilt_anterior="", plane_tilt_side="", plane_entry="")
        self._show_plane_inputs()  # a scene's plane: its placement in the fields
        self.server.state.trame__title = "RAMSICP Navigator"
        build_page(self)

    async def _poll_loop(self):
        last_follow = 0.0
        while True:
            try:
                self.bridge.poll()
                self.controller.service()  # the robot link: its reports are read whether the page looks or not
                now = time.monotonic()
                if self._tip_moved and now - last_follow >= self.follow_interval_s:
                    self._follow_tip()
                    last_follow = now
            except Exception:  # a display error must not stop the tracker feed
                logger.exception("tracker poll failed")
            await asyncio.sleep(POLL_INTERVAL_S)

    def _follow_tip(self):
        """Move the slices through the tip once the registration puts it in the CT. Moving a slice re-cuts what
        it shows, so this runs at most at the views' frame rate, not at the tracker's."""
        self._tip_moved = False
        parameters = self.controller.parameters
        position = self.controller.tip_position()
        if position is not None and self._registered(parameters):
            follow_tip(self.scene, position, parameters.ctVolume)

    async def _panel_loop(self):
        while True:
            try:
                self.refresh_panel()
            except Exception:
                logger.exception("panel refresh failed")
            await asyncio.sleep(PANEL_INTERVAL_S)

    def serve(self, host="127.0.0.1", port=8080, on_ready=None):
        """Serve the page until the server stops (Ctrl+C); ``on_ready(url)`` once it listens."""
        port = check_port_free(host, port)
        self.build_page()
        from vtkmodules.vtkCommonCore import vtkMultiThreader

        vtkMultiThreader.SetGlobalMaximumNumberOfThreads(VTK_FILTER_THREADS)

        def ready(**_):
            self._tasks += [asyncio.ensure_future(self._poll_loop()), asyncio.ensure_future(self._panel_loop())]
            if on_ready is not None:
                on_ready(f"http://{host}:{port}/")

        self.server.controller.on_server_ready.add(ready)
        try:
            self.server.start(
                host=host, port=port, open_browser=False, show_connection_info=False, timeout=0, disable_logging=True
            )
        finally:
            self.close()

    def close(self):
        for task in self._tasks:
            task.cancel()
        if self.bridge is not None:
            self.bridge.close()
        if self.controller is not None:
            self.controller.close()
