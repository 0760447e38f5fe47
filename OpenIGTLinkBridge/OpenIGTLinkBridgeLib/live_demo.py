"""``ramsicp demo --live``: simulator -> OpenIGTLink server -> receiver -> the navigation controller -> CR-RAMSICP.

The simulated Vega plays the demo patient's touches at 60 Hz, one frame per read (``stepped``: the session is
the same however loaded the machine is); our NDI driver reads it, our server streams each tracker frame once
from the moment the receiver connects, and our receiver writes the transform nodes of a real MRML scene. From
there on it is the surgeon's workflow exactly as the Slicer module runs it: the same ``NavigationController``
follows ``ProbeToReference``, collects a point each time the tip is held still (``core.hold_still``: the mean
over the whole hold, timed by the frames' own time stamps) and registers with the module's default method. The
same points are registered on the exact touches beside it. The session can be recorded to a PLUS sequence file.
"""

import logging
import time
from dataclasses import dataclass

import numpy as np

from .igtl_server import TrackerServer, TrackerSource
from .live_scenario import PROBE_TIP_MM, demo_simulator
from .ndi_driver import open_tracker

logger = logging.getLogger(__name__)

HOLD_STILL_MM = 0.8
HOLD_STILL_S = 0.15
TRACKER_RATE_HZ = 60.0


@dataclass(frozen=True)
class LiveResult:
    """Points collected live and their registration beside the same registration on the true touch points."""

    collected: np.ndarray
    touched: np.ndarray
    collection_error_mm: np.ndarray
    live: object  # RegistrationResult
    reference: object  # RegistrationResult on the exact touches
    frames: int
    seconds: float
    touches: tuple = ()  # the hold-still detector's Touch of each collected point
    recording: object = None  # path of the session's PLUS sequence file, when recorded


def run_live_demo(
    scene,
    patient,
    index,
    trial,
    probe_noise_mm=0.25,
    header_version=1,
    dwell_s=0.25,
    move_s=0.1,
    progress=None,
    record=None,
    server_factory=None,
):
    """Play ``trial``'s touches through the whole tracking chain into ``scene`` and register what arrives.

    Args:
        scene: a vtkMRMLScene for the receiver's transform nodes and the workflow's nodes.
        patient: the VirtualPatient (targets); index: SurfaceIndex of the IPC; trial: TrialData whose ``ppc``
            (reference coordinates) the probe touches and whose markers and targets the registration uses.
        probe_noise_mm: RMS 3-D noise of the tip in the reference frame (split between the two tools).
        record: a path: the session is recorded there as a PLUS sequence file.
        server_factory: optional callable returning a started TrackerServer instead of the simulator chain
            (``replay_server`` replays a recorded session); it is stopped at the end.
    """
    from RAMSICPRegistrationLib.core.registration import register
    from RAMSICPRegistrationLib.core.transforms import make_transform
    from RAMSICPRegistrationLib.navigation import mrml_nodes
    from RAMSICPRegistrationLib.navigation.controller import NavigationController
    from RAMSICPRegistrationLib.navigation.navigation import set_matrix

    from .receiver import TrackerReceiver

    touched = trial.ppc
    simulator, script = None, None
    if server_factory is None:
        simulator, script = demo_simulator(
            touched,
            dwell_s=dwell_s,
            move_s=move_s,
            noise_mm=probe_noise_mm / np.sqrt(2),
            rate_hz=TRACKER_RATE_HZ,
            stepped=True,  # every tracker frame is read once, however loaded the machine: a reproducible session
        )
        simulator.start()
        source = TrackerSource(
            lambda: open_tracker("127.0.0.1", simulator.address[1]), rate_hz=TRACKER_RATE_HZ, wait_for_client=True
        )
        server = TrackerServer(source=source, port=0, header_version=header_version).start()
    else:
        server = server_factory()
    receiver = TrackerReceiver(scene, port=server.address[1])
    if record is not None:
        receiver.start_recording(record)
    # The workflow as the module runs it: the tracked probe and its calibrated tip, hold-still collection.
    controller = NavigationController(scene, pose_time=lambda node: receiver.timestamps[receiver.probe_name])
    parameters = controller.parameters
    parameters.probeToReference = controller.steps.transform_node(receiver.probe_to_reference_name)
    parameters.probeTipToProbe = controller.steps.transform_node("ProbeTipToProbe")
    set_matrix(parameters.probeTipToProbe, make_transform(translation=PROBE_TIP_MM))
    parameters.holdStillMm, parameters.holdStillS = HOLD_STILL_MM, HOLD_STILL_S
    touches = []
    controller.add_listener(lambda event, data: touches.append(data[2]) if event == "collected" else None)
    start = time.monotonic()
    timeout_s = (script.duration_s if script else _replay_seconds(server)) + 2.0
    try:
        while time.monotonic() - start < timeout_s and len(touches) < len(touched):
            if receiver.poll():
                if not controller.status().hold_still_collect:
                    controller.run("set_hold_still_collect", True)  # as soon as the probe is tracked
                if progress:
                    progress("live collection", len(touches), len(touched))
            if server_factory is not None and server.finished.is_set() and not receiver.poll():
                break  # the replay is over and everything it sent has been read
            time.sleep(0.005)
    finally:
        seconds = time.monotonic() - start
        controller.run("set_hold_still_collect", False)  # the last hold ends with the session
        recording = receiver.stop_recording()
        server.stop()
        receiver.close()
        if simulator is not None:
            simulator.stop()
    collected = mrml_nodes.fiducial_positions(parameters.probePoints) if parameters.probePoints else np.zeros((0, 3))
    if len(collected) < 3:
        controller.close()
        raise RuntimeError(f"only {len(collected)} points were collected live; the tracking chain did not deliver")
    nearest = np.linalg.norm(collected[:, None] - touched[None], axis=2).min(axis=1)
    parameters.ipcModel = mrml_nodes.model_node(scene, index.points)
    for name, points in (
        ("markersImage", trial.markers_image),
        ("markersPatient", trial.markers_patient),
        ("targetsImage", trial.targets_image),
        ("targetsPatient", trial.targets_patient),
    ):
        setattr(parameters, name, mrml_nodes.fiducial_node(scene, points, name=name))
    live = controller.register()
    frames = controller.status().probe_poses
    controller.close()
    ramsicp = live.method == "cr-ramsicp"  # the controller sweeps L, with its policy, for CR-RAMSICP only
    reference = register(
        index,
        touched,
        trial.markers_image,
        trial.markers_patient,
        trial.targets_image,
        trial.targets_patient,
        method=live.method,
        sweep=ramsicp,
        policy=parameters.policy if ramsicp else None,
    )
    return LiveResult(collected, touched, nearest, live, reference, frames, seconds, tuple(touches), recording)


def replay_server(path, header_version=1):
    """A started TrackerServer replaying the PLUS sequence file ``path`` (for ``run_live_demo``)."""
    from .plus_sequence import read_sequence
    from .replay import ReplaySource

    return TrackerServer(source=ReplaySource(read_sequence(path)), port=0, header_version=header_version).start()


def _replay_seconds(server):
    offsets = getattr(server.source, "offsets_s", None)
    return 10.0 if offsets is None else float(offsets[-1]) / server.source.speed
