"""``ramsicp demo --live``: simulator -> OpenIGTLink server -> receiver -> probe-point collection -> CR-RAMSICP.

The simulated Vega plays the demo patient's touches at 60 Hz, one frame per read (``stepped``: the session is
the same however loaded the machine is); our NDI driver reads it, our server streams each tracker frame once
from the moment the receiver connects, our receiver writes the transform nodes of a real MRML scene, and
points are collected the way a surgeon holds the probe still: the hold-still detector of
``core.hold_still`` (tip within ``HOLD_STILL_MM`` for ``HOLD_STILL_S``) gives each touch as the mean over its
whole hold, timed by the frames' own time stamps. The collected points are registered exactly as the offline
demo registers its points. The session can be recorded to a PLUS sequence file (``record``).
"""

import logging
import time
from dataclasses import dataclass

import numpy as np

from RAMSICPRegistrationLib.core.hold_still import HoldStillDetector

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


def collect_touches(receiver, detector, tip_mm=PROBE_TIP_MM, probe="ProbeToTracker", reference="ReferenceToTracker"):
    """Wire ``receiver.on_update`` to feed ``detector`` with the tip in reference coordinates (eq. 2) at each
    probe frame, timed by the frame's time stamp; returns a function giving the number of probe frames seen."""
    frames = 0

    def on_update(device, matrix, timestamp_s):
        nonlocal frames
        if device != probe or reference not in receiver.matrices:
            return
        probe_to_reference = np.linalg.inv(receiver.matrices[reference]) @ matrix
        detector.add(probe_to_reference[:3, :3] @ tip_mm + probe_to_reference[:3, 3], timestamp_s, frames)
        frames += 1

    receiver.on_update = on_update
    return lambda: frames


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
        scene: a vtkMRMLScene for the receiver's transform nodes.
        patient: the VirtualPatient (targets); index: SurfaceIndex of the IPC; trial: TrialData whose ``ppc``
            (reference coordinates) the probe touches and whose markers and targets the registration uses.
        probe_noise_mm: RMS 3-D noise of the tip in the reference frame (split between the two tools).
        record: a path: the session is recorded there as a PLUS sequence file.
        server_factory: optional callable returning a started TrackerServer instead of the simulator chain
            (``replay_server`` replays a recorded session); it is stopped at the end.
    """
    from RAMSICPRegistrationLib.core.registration import register

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
    detector = HoldStillDetector(HOLD_STILL_MM, HOLD_STILL_S)
    frames = collect_touches(receiver, detector)
    start = time.monotonic()
    timeout_s = (script.duration_s if script else _replay_seconds(server)) + 2.0
    try:
        while time.monotonic() - start < timeout_s and len(detector.touches) < len(touched):
            if receiver.poll() and progress:
                progress("live collection", len(detector.touches), len(touched))
            if server_factory is not None and server.finished.is_set() and not receiver.poll():
                break  # the replay is over and everything it sent has been read
            time.sleep(0.005)
    finally:
        seconds = time.monotonic() - start
        detector.finish()
        recording = receiver.stop_recording()
        server.stop()
        receiver.close()
        if simulator is not None:
            simulator.stop()
    touches = tuple(detector.touches)
    collected = np.array([touch.position for touch in touches]).reshape(-1, 3)
    if len(collected) < 3:
        raise RuntimeError(f"only {len(collected)} points were collected live; the tracking chain did not deliver")
    nearest = np.linalg.norm(collected[:, None] - touched[None], axis=2).min(axis=1)
    options = dict(
        markers_image=trial.markers_image,
        markers_patient=trial.markers_patient,
        targets_image=trial.targets_image,
        targets_patient=trial.targets_patient,
        sweep=True,
        policy="rms-plateau",
    )
    live = register(index, collected, **options)
    reference = register(index, touched, **options)
    return LiveResult(collected, touched, nearest, live, reference, frames(), seconds, touches, recording)


def replay_server(path, header_version=1):
    """A started TrackerServer replaying the PLUS sequence file ``path`` (for ``run_live_demo``)."""
    from .plus_sequence import read_sequence
    from .replay import ReplaySource

    return TrackerServer(source=ReplaySource(read_sequence(path)), port=0, header_version=header_version).start()


def _replay_seconds(server):
    offsets = getattr(server.source, "offsets_s", None)
    return 10.0 if offsets is None else float(offsets[-1]) / server.source.speed
