"""The simulated operating room for the live demo and the tests: a reference body fixed in the tracker's view
and a probe whose tip touches a list of points (reference coordinates), dwelling on each, then moving on."""

from dataclasses import dataclass

import numpy as np

from .ndi_simulator import Scenario, VegaSimulator

#: Tip of the probe in the probe tool's frame (mm): below the first marker of NDI 8700340, along its axis.
PROBE_TIP_MM = np.array([0.0, 0.0, -110.0])
DEFAULT_REFERENCE_TO_TRACKER = np.array(
    [[0.0, -1.0, 0.0, 40.0], [0.0, 0.0, -1.0, 120.0], [1.0, 0.0, 0.0, -1600.0], [0.0, 0.0, 0.0, 1.0]]
)


@dataclass(frozen=True)
class TouchScript:
    """When the tip rests on which point: touch ``i`` spans [start + i * period, start + i * period + dwell_s]."""

    points_reference: np.ndarray
    reference_to_tracker: np.ndarray
    dwell_s: float
    move_s: float
    start_s: float = 0.3

    @property
    def period_s(self):
        return self.dwell_s + self.move_s

    @property
    def duration_s(self):
        return self.start_s + len(self.points_reference) * self.period_s

    def probe_to_reference(self, time_s):
        """ProbeToReference at ``time_s``: the tip on a point while dwelling, sliding to the next between."""
        position = (time_s - self.start_s) / self.period_s
        index = int(np.clip(np.floor(position), 0, len(self.points_reference) - 1))
        phase = (position - np.floor(position)) * self.period_s
        tip = self.points_reference[index]
        if time_s > self.start_s and phase > self.dwell_s and index + 1 < len(self.points_reference):
            fraction = (phase - self.dwell_s) / self.move_s
            tip = (
                (1 - fraction) * tip
                + fraction * self.points_reference[index + 1]
                + np.array([0, 0, 20.0]) * (np.sin(np.pi * fraction))
            )  # lifted off the bone between touches
        tilt = 0.3 * np.sin(0.7 * index + 1.0)
        rotation = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(tilt), -np.sin(tilt)], [0.0, np.sin(tilt), np.cos(tilt)]])
        transform = np.eye(4)
        transform[:3, :3] = rotation
        transform[:3, 3] = tip - rotation @ PROBE_TIP_MM
        return transform


def demo_simulator(
    points_reference=None,
    reference_to_tracker=DEFAULT_REFERENCE_TO_TRACKER,
    dwell_s=0.25,
    move_s=0.1,
    noise_mm=0.0,
    seed=0,
    dropout=None,
    out_of_volume=None,
    disconnect_after_s=None,
    rate_hz=60.0,
    port=0,
):
    """A VegaSimulator (not started) playing a TouchScript, and the script.

    ``points_reference`` default: the 40 probe points of the demo's tibia (seed 0). ``dropout(time_s)`` and
    ``out_of_volume(time_s)`` make the probe MISSING or out of volume when they return True.
    """
    from RAMSICPRegistrationLib.io.ndi_tools import tool_rom_path

    if points_reference is None:
        points_reference = default_touch_points(seed)
    script = TouchScript(
        np.asarray(points_reference, dtype=np.float64), np.asarray(reference_to_tracker), dwell_s, move_s
    )
    reference_rom = tool_rom_path("8700339").read_bytes()
    probe_rom = tool_rom_path("8700340").read_bytes()

    def poses(time_s):
        probe = (
            None
            if dropout is not None and dropout(time_s)
            else script.reference_to_tracker @ (script.probe_to_reference(time_s))
        )
        return {reference_rom: script.reference_to_tracker, probe_rom: probe}

    def flagged(time_s, rom):
        return rom == probe_rom and out_of_volume is not None and out_of_volume(time_s)

    scenario = Scenario(
        poses,
        out_of_volume=flagged,
        noise_mm=noise_mm,
        seed=seed,
        disconnect_after_s=disconnect_after_s,
        rate_hz=rate_hz,
    )
    return VegaSimulator(scenario, port=port), script


def default_touch_points(seed=0):
    """The demo's 40 probe points on the right tibia, in reference coordinates (noise-free)."""
    from RAMSICPRegistrationLib.simulation.package_data import shipped_patient

    patient, _, _ = shipped_patient("right-tibia")
    return patient.simulate_trial(np.random.default_rng(seed), 0.0, probe_noise_mm=0.0).ppc
