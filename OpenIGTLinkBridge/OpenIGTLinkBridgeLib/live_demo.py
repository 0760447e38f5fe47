"""``ramsicp demo --live``: simulator -> OpenIGTLink server -> receiver -> probe-point collection -> registration.

The simulated Vega plays the demo patient's touches; our NDI driver reads it, our server streams it at 60 Hz,
our receiver writes the transform nodes of a real MRML scene, and points are collected the way a surgeon holds
the probe still: when the tip has stayed within ``HOLD_STILL_MM`` for ``HOLD_FRAMES`` frames, the mean of those
frames is taken. The collected points are registered with the default method (``DEFAULT_METHOD``), beside the
exact touches.
"""

import logging
import time
from dataclasses import dataclass

import numpy as np

from .igtl_server import TrackerServer
from .live_scenario import PROBE_TIP_MM, demo_simulator
from .ndi_driver import open_tracker

logger = logging.getLogger(__name__)

HOLD_FRAMES = 8
HOLD_STILL_MM = 0.8
MIN_SPACING_MM = 1.0


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


class DwellCollector:
    """Collects a point when the tip holds still: fed tip positions (3,) frame by frame."""

    def __init__(self, frames=HOLD_FRAMES, still_mm=HOLD_STILL_MM, spacing_mm=MIN_SPACING_MM):
        self.frames, self.still_mm, self.spacing_mm = frames, still_mm, spacing_mm
        self.recent = []
        self.points = []

    def add(self, tip):
        self.recent = (self.recent + [np.asarray(tip, dtype=np.float64)])[-self.frames :]
        if len(self.recent) < self.frames:
            return None
        window = np.array(self.recent)
        centre = window.mean(axis=0)
        if np.linalg.norm(window - centre, axis=1).max() > self.still_mm:
            return None
        if self.points and np.linalg.norm(centre - self.points[-1]) < self.spacing_mm:
            return None
        self.points.append(centre)
        return centre


def run_live_demo(
    scene, patient, index, trial, probe_noise_mm=0.25, header_version=1, dwell_s=0.25, move_s=0.1, progress=None
):
    """Play ``trial``'s touches through the whole tracking chain into ``scene`` and register what arrives.

    Args:
        scene: a vtkMRMLScene for the receiver's transform nodes.
        patient: the VirtualPatient (targets); index: SurfaceIndex of the IPC; trial: TrialData whose ``ppc``
            (reference coordinates) the probe touches and whose markers and targets the registration uses.
        probe_noise_mm: RMS 3-D noise of the tip in the reference frame (split between the two tools).
    """
    from RAMSICPRegistrationLib.core.registration import register

    from .receiver import TrackerReceiver

    touched = trial.ppc
    simulator, script = demo_simulator(touched, dwell_s=dwell_s, move_s=move_s, noise_mm=probe_noise_mm / np.sqrt(2))
    simulator.start()

    server = TrackerServer(
        lambda: open_tracker("127.0.0.1", simulator.address[1]), port=0, header_version=header_version
    ).start()
    receiver = TrackerReceiver(scene, port=server.address[1])
    collector = DwellCollector()
    frames = 0

    def on_update(device, matrix, timestamp_s):
        nonlocal frames
        if device != "ProbeToTracker" or "ReferenceToTracker" not in receiver.matrices:
            return
        frames += 1
        probe_to_reference = np.linalg.inv(receiver.matrices["ReferenceToTracker"]) @ matrix
        if (
            collector.add(probe_to_reference[:3, :3] @ PROBE_TIP_MM + probe_to_reference[:3, 3]) is not None
            and progress
        ):
            progress("live collection", len(collector.points), len(touched))

    receiver.on_update = on_update
    start = time.monotonic()
    try:
        while time.monotonic() - start < script.duration_s + 1.0 and len(collector.points) < len(touched):
            receiver.poll()
            time.sleep(0.005)
    finally:
        seconds = time.monotonic() - start
        server.stop()
        receiver.close()
        simulator.stop()
    collected = np.array(collector.points).reshape(-1, 3)
    if len(collected) < 3:
        raise RuntimeError(f"only {len(collected)} points were collected live; the tracking chain did not deliver")
    nearest = np.linalg.norm(collected[:, None] - touched[None], axis=2).min(axis=1)
    options = dict(
        markers_image=trial.markers_image,
        markers_patient=trial.markers_patient,
        targets_image=trial.targets_image,
        targets_patient=trial.targets_patient,
        probe_noise_mm=probe_noise_mm,
    )
    live = register(index, collected, **options)
    reference = register(index, touched, **options)
    return LiveResult(collected, touched, nearest, live, reference, frames, seconds)
