"""The simulated operating room for the live demo and the tests: a reference body fixed in the tracker's view
and a probe whose tip touches a list of points (reference coordinates), dwelling on each, then moving on; for the
cut, the markers on the robot's cutting tool, wherever the robot simulator (``robot_simulator``) has moved it.

Optionally the script starts with a pivot phase (the tip rests in a divot while the probe swivels about it, for
the pivot calibration) and loops, so that a demo left running shows the whole workflow again and again. A
``HandHeldProbe`` is moved step by step by a test or a benchmark instead."""

import threading
from dataclasses import dataclass

import numpy as np

from .ndi_simulator import Scenario, VegaSimulator

#: Tip of the probe in the probe tool's frame (mm): below the first marker of NDI 8700340, along its axis.
PROBE_TIP_MM = np.array([0.0, 0.0, -110.0])
#: Height (mm) to which the tip is lifted off the bone between touches.
LIFT_MM = 20.0
DEFAULT_REFERENCE_TO_TRACKER = np.array(
    [[0.0, -1.0, 0.0, 40.0], [0.0, 0.0, -1.0, 120.0], [1.0, 0.0, 0.0, -1600.0], [0.0, 0.0, 0.0, 1.0]]
)
#: Swivel of the probe about its tip during a pivot: amplitude (degrees) and the periods (s) of its tilts about the
#: probe's x and y axes. Incommensurate periods make every pose new; two axes fix all three tip coordinates.
PIVOT_SWIVEL_DEG = 25.0
PIVOT_PERIODS_S = (2.3, 3.1)


def pivot_pose(time_s, divot, swivel_deg=PIVOT_SWIVEL_DEG):
    """ProbeToReference (4, 4) at ``time_s`` (s) while the tip rests in ``divot`` (3,) (reference coordinates, mm)
    and the probe swivels about it, as a surgeon does for the pivot calibration."""
    tilt_x, tilt_y = (np.radians(swivel_deg) * np.sin(2 * np.pi * time_s / period) for period in PIVOT_PERIODS_S)
    about_x = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(tilt_x), -np.sin(tilt_x)], [0.0, np.sin(tilt_x), np.cos(tilt_x)]])
    about_y = np.array([[np.cos(tilt_y), 0.0, np.sin(tilt_y)], [0.0, 1.0, 0.0], [-np.sin(tilt_y), 0.0, np.cos(tilt_y)]])
    transform = np.eye(4)
    transform[:3, :3] = about_x @ about_y
    transform[:3, 3] = np.asarray(divot, dtype=np.float64) - transform[:3, :3] @ PROBE_TIP_MM
    return transform


@dataclass(frozen=True)
class TouchScript:
    """When the tip rests on which point. Until ``start_s`` the tip circles ``LIFT_MM`` above the first point
    (a hand waiting in the air is never still, and a tip held still in the air would be taken for a touch);
    touch ``i`` then spans [start + i * period + move_s, start + (i + 1) * period] (period = move_s + dwell_s),
    each reached by a lifted move of ``move_s``; after the last touch the tip lifts off and circles again.

    With ``pivot_s`` the script first swivels the probe about its tip resting on the first point for that long
    (``pivot_pose``), and the timeline above starts after it; with ``loop`` the whole script plays again after
    ``duration_s``. ``tip`` is the timeline without the pivot phase."""

    points_reference: np.ndarray
    reference_to_tracker: np.ndarray
    dwell_s: float
    move_s: float
    start_s: float = 0.5
    pivot_s: float = 0.0
    loop: bool = False

    @property
    def period_s(self):
        return self.dwell_s + self.move_s

    @property
    def duration_s(self):
        """Time of the last lift-off's end: every touch is over."""
        return self.pivot_s + self.start_s + len(self.points_reference) * self.period_s + self.move_s

    def touch_interval(self, index):
        """(start, end) in s of touch ``index``."""
        end = self.pivot_s + self.start_s + (index + 1) * self.period_s
        return end - self.dwell_s, end

    def tip(self, time_s):
        """Tip position (3,) in reference coordinates at ``time_s``."""
        points = self.points_reference
        lift = np.array([0.0, 0.0, LIFT_MM])
        position = (time_s - self.start_s) / self.period_s
        index = int(np.floor(position))
        phase = (position - index) * self.period_s
        if index < 0:
            return points[0] + lift + _circle(time_s - self.start_s)
        if index >= len(points):  # lifted off after the last touch
            since = time_s - self.start_s - len(points) * self.period_s
            if since >= self.move_s:
                return points[-1] + lift + _circle(since - self.move_s)
            return points[-1] + lift * np.sin(0.5 * np.pi * since / self.move_s)
        if phase >= self.move_s:
            return points[index]
        fraction = phase / self.move_s
        start = points[index - 1] if index > 0 else points[0] + lift
        return (1 - fraction) * start + fraction * points[index] + lift * np.sin(np.pi * fraction) * (index > 0)

    def probe_to_reference(self, time_s):
        """ProbeToReference at ``time_s``: swivelling in the divot during the pivot phase, then the tip (above)
        with the probe tilted differently for each touch."""
        if self.loop:
            time_s = time_s % self.duration_s
        if time_s < self.pivot_s:
            return pivot_pose(time_s, self.points_reference[0])
        time_s -= self.pivot_s
        position = (time_s - self.start_s) / self.period_s
        index = int(np.clip(np.floor(position), 0, len(self.points_reference) - 1))
        tilt = 0.3 * np.sin(0.7 * index + 1.0)
        rotation = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(tilt), -np.sin(tilt)], [0.0, np.sin(tilt), np.cos(tilt)]])
        transform = np.eye(4)
        transform[:3, :3] = rotation
        transform[:3, 3] = self.tip(time_s) - rotation @ PROBE_TIP_MM
        return transform


def _circle(time_s, radius_mm=10.0, period_s=0.5):
    """Offset (3,) of a tip circling in the air, zero at ``time_s`` = 0 (so the motion joins on smoothly)."""
    angle = 2 * np.pi * time_s / period_s
    return radius_mm * np.array([np.cos(angle) - 1.0, np.sin(angle), 0.0])


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
    stepped=False,
    pivot_s=0.0,
    loop=False,
):
    """A VegaSimulator (not started) playing a TouchScript, and the script.

    ``points_reference`` default: the 40 probe points of the demo's tibia (seed 0). ``dropout(time_s)`` and
    ``out_of_volume(time_s)`` make the probe MISSING or out of volume when they return True; ``stepped``: see
    ``ndi_simulator.Scenario``; ``pivot_s`` and ``loop``: a pivot phase first, and the script played again and
    again (``TouchScript``).
    """
    from RAMSICPRegistrationLib.io.ndi_tools import tool_rom_path

    if points_reference is None:
        points_reference = default_touch_points(seed)
    script = TouchScript(
        np.asarray(points_reference, dtype=np.float64),
        np.asarray(reference_to_tracker),
        dwell_s,
        move_s,
        pivot_s=pivot_s,
        loop=loop,
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
        stepped=stepped,
    )
    return VegaSimulator(scenario, port=port), script


def default_touch_points(seed=0):
    """The demo's 40 probe points on the right tibia, in reference coordinates (noise-free)."""
    from RAMSICPRegistrationLib.simulation.patient_cache import shared_shipped_patient

    patient, _, _ = shared_shipped_patient("right-tibia")  # the patient of the demo's CT, made once per process
    return patient.simulate_trial(np.random.default_rng(seed), 0.0, probe_noise_mm=0.0).ppc


class HandHeldProbe:
    """A probe a script moves step by step, for tests and benchmarks that wait for what a view shows: ``touch``
    holds the tip still on a point, ``pivot`` swivels it in a divot; the reference body stays put.

    ``poses(time_s)`` is the ``Scenario`` callable of a ``VegaSimulator`` (``serve_hand_held_probe``); it runs in
    the simulator's thread, so the pose is swapped under a lock.
    """

    def __init__(self, reference_to_tracker=DEFAULT_REFERENCE_TO_TRACKER):
        from RAMSICPRegistrationLib.io.ndi_tools import tool_rom_path

        self.reference_to_tracker = np.asarray(reference_to_tracker, dtype=np.float64)
        self.reference_rom = tool_rom_path("8700339").read_bytes()
        self.probe_rom = tool_rom_path("8700340").read_bytes()
        self._lock = threading.Lock()
        self._probe_to_reference = None
        self.touch(np.zeros(3))

    def touch(self, point, tilt_deg=10.0):
        """Hold the tip on ``point`` (3,) (reference coordinates, mm), the probe tilted by ``tilt_deg`` about x."""
        transform = self._held(point, tilt_deg)
        with self._lock:
            self._probe_to_reference = lambda time_s: transform

    @staticmethod
    def _held(point, tilt_deg):
        tilt = np.radians(tilt_deg)
        transform = np.eye(4)
        transform[:3, :3] = [[1.0, 0.0, 0.0], [0.0, np.cos(tilt), -np.sin(tilt)], [0.0, np.sin(tilt), np.cos(tilt)]]
        transform[:3, 3] = np.asarray(point, dtype=np.float64) - transform[:3, :3] @ PROBE_TIP_MM
        return transform

    def slide(self, start, end, period_s=2.0, tilt_deg=10.0):
        """Slide the tip back and forth between ``start`` and ``end`` (3,) (reference coordinates, mm), one round
        trip per ``period_s``: a probe in steady motion."""
        start, end = (np.asarray(point, dtype=np.float64) for point in (start, end))
        held = self._held(np.zeros(3), tilt_deg)

        def pose(time_s):
            fraction = 0.5 - 0.5 * np.cos(2 * np.pi * time_s / period_s)
            transform = held.copy()
            transform[:3, 3] += start + fraction * (end - start)
            return transform

        with self._lock:
            self._probe_to_reference = pose

    def pivot(self, divot):
        """Swivel the probe about its tip resting on ``divot`` (3,) (reference coordinates, mm)."""
        divot = np.asarray(divot, dtype=np.float64)
        with self._lock:
            self._probe_to_reference = lambda time_s: pivot_pose(time_s, divot)

    def poses(self, time_s):
        with self._lock:
            probe_to_reference = self._probe_to_reference(time_s)
        return {
            self.reference_rom: self.reference_to_tracker,
            self.probe_rom: self.reference_to_tracker @ probe_to_reference,
        }


def serve_simulator(simulator, port=0, rate_hz=60.0):
    """A started PLUS-compatible OpenIGTLink server on 127.0.0.1:``port`` reading a started simulator."""
    from .igtl_server import TrackerServer
    from .ndi_driver import open_tracker

    return TrackerServer(lambda: open_tracker("127.0.0.1", simulator.address[1]), port=port, rate_hz=rate_hz).start()


def serve_hand_held_probe(probe, port=0, rate_hz=60.0):
    """The started simulator of a HandHeldProbe and its OpenIGTLink server on 127.0.0.1; stop both."""
    simulator = VegaSimulator(Scenario(probe.poses, rate_hz=rate_hz)).start()
    return simulator, serve_simulator(simulator, port, rate_hz)


def robot_tool_poses(robot, robot_base_to_tracker, marker_to_flange):
    """ToolToTracker now (a function of time for a Scenario; the time is the robot's own): the markers fixed to
    the robot's tool, ``MarkerToFlange`` (4, 4), wherever the robot simulator has really moved its flange."""
    base_to_tracker = np.asarray(robot_base_to_tracker, dtype=np.float64)
    marker_to_flange = np.asarray(marker_to_flange, dtype=np.float64)

    def pose(time_s):
        return base_to_tracker @ robot.flange_pose() @ marker_to_flange

    return pose


def cutting_simulator(
    robot,
    robot_base_to_tracker,
    marker_to_flange,
    reference_to_tracker=DEFAULT_REFERENCE_TO_TRACKER,
    noise_mm=0.0,
    seed=0,
    rate_hz=60.0,
    port=0,
):
    """A VegaSimulator (not started) that sees the reference body (NDI 8700339) and the cutting tool's markers
    (NDI 8700449) on the robot simulator's tool; serve it with the names Reference and Tool."""
    from RAMSICPRegistrationLib.io.ndi_tools import DEFAULT_CUTTING_TOOL, DEFAULT_REFERENCE_TOOL, tool_rom_path

    reference_rom = tool_rom_path(DEFAULT_REFERENCE_TOOL).read_bytes()
    tool_rom = tool_rom_path(DEFAULT_CUTTING_TOOL).read_bytes()
    tool = robot_tool_poses(robot, robot_base_to_tracker, marker_to_flange)
    reference = np.asarray(reference_to_tracker, dtype=np.float64)

    def poses(time_s):
        return {reference_rom: reference, tool_rom: tool(time_s)}

    scenario = Scenario(poses, noise_mm=noise_mm, seed=seed, rate_hz=rate_hz)
    return VegaSimulator(scenario, port=port)
