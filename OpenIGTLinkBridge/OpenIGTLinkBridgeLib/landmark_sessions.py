"""Recordings of a stylus touching landmarks, drawn at random over what real PLUS recordings hold, for tests and the
benchmark of touch detection (``ramsicp collect``).

A session, as a surgeon or an engineer records one to register a phantom by its landmarks (PLUS's phantom
registration: a stylus swivelled about each landmark): the stylus lies on the table (a rest), is picked up and
moved a few hundred mm onto each landmark in turn, settles, swivels about it (a cone, a figure, a fan or a random
wobble of ``swivel_deg`` between its extreme poses, twisting a little about its shaft), settles again and is lifted
off; at the end it is put down again (a rest). The hand trembles (8-12 Hz; in the air the tip moves, in a divot the
shaft does), the tracker adds noise to both tools' poses, frames come at 10-60 Hz with jittered intervals and
gaps, runs of frames are INVALID (markers hidden), and the tip calibration handed to the detector is off by up to
2.5 mm. Everything is drawn from ``seed``; ``write`` saves the session as a PLUS sequence file with the project's
writer (``plus_sequence.write_sequence``), with PLUS's field layout.

Ground truth kept with the session: the landmarks (reference coordinates), the true and the calibrated tip, and the
time interval of each landmark's contact and of each rest.
"""

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from .plus_sequence import TrackedFrame, write_sequence

#: Tool names real recordings use for the pointer (PLUS configurations, SlicerIGT tutorials).
TOOL_NAMES = ("StylusToTracker", "PointerToTracker", "ProbeToTracker", "StylusTipToTracker", "NeedleToTracker")
REFERENCE_NAME = "ReferenceToTracker"
_UP = np.array([0.0, 0.0, 1.0])  # away from the phantom, in the reference frame


@dataclass(frozen=True)
class LandmarkSession:
    """A drawn session: its frames (TrackedFrame, ready for ``write_sequence``) and its ground truth.

    ``landmarks`` (L, 3) mm and ``rests`` (2, 3) mm: reference coordinates of each landmark and of the two rests
    (start, end); ``contacts`` (L, 2) s and ``rest_times`` (2, 2) s: when the tip was on each; ``tip_true`` and
    ``tip_calibrated`` (3,) mm: the tip in the stylus frame, as it is and as the detector is told.
    """

    frames: list
    landmarks: np.ndarray
    rests: np.ndarray
    contacts: np.ndarray
    rest_times: np.ndarray
    tip_true: np.ndarray
    tip_calibrated: np.ndarray
    tool: str
    settings: dict

    def write(self, path):
        return write_sequence(path, self.frames)


def random_landmark_session(seed, **overrides):
    """A session drawn from ``seed`` (see the module's docstring); ``overrides`` fix any of the drawn settings
    (e.g. ``rate_hz=15.0``, ``landmarks=8``, ``tip_error_mm=2.5``, ``invalid_runs=0``)."""
    rng = np.random.default_rng(seed)
    settings = {
        "landmarks": int(rng.integers(4, 13)),
        "rate_hz": float(rng.uniform(10.0, 60.0)),
        "noise_mm": float(rng.uniform(0.1, 0.25)),  # RMS 3-D noise of the tip from the stylus's pose
        "reference_noise_mm": float(rng.uniform(0.02, 0.08)),
        "tip_error_mm": float(rng.uniform(1.0, 2.5)),
        "tip_length_mm": float(rng.uniform(100.0, 220.0)),
        "swivel_deg": (34.0, 44.0),  # drawn per landmark in this range
        "swivel_s": (2.0, 5.0),
        "settle_s": (0.2, 1.0),
        "move_speed_mm_s": (150.0, 400.0),
        "rest_s": (1.0, 4.0),
        "tremor_mm": float(rng.uniform(0.05, 0.3)),  # the hand's tremor at the tip, in the air
        "invalid_runs": int(rng.integers(0, 4)),
        "tool": TOOL_NAMES[int(rng.integers(len(TOOL_NAMES)))],
    }
    unknown = set(overrides) - set(settings)
    if unknown:
        raise ValueError(f"unknown session settings {sorted(unknown)}; choose among {sorted(settings)}")
    settings.update(overrides)
    return _Session(rng, settings).build()


class _Session:
    def __init__(self, rng, settings):
        self.rng, self.s = rng, settings
        direction = _unit(rng.normal(size=3))
        self.tip_true = settings["tip_length_mm"] * direction  # tip in the stylus frame, far from its markers
        self.shaft = -direction  # from the tip towards the markers, stylus frame
        error = _unit(rng.normal(size=3)) * settings["tip_error_mm"]
        self.tip_calibrated = self.tip_true + error
        self.reference_to_tracker = _pose(
            Rotation.random(random_state=rng).as_matrix(), rng.uniform((-300, -300, -2100), (300, 300, -1200))
        )
        self.segments = []  # (duration_s, function of local time -> (tip (3,), rotation (3, 3)), kind, index)

    # -- the script ----------------------------------------------------------------------------------------
    def build(self):
        rng, s = self.rng, self.s
        landmarks = self._landmarks(s["landmarks"])
        rests = np.array([self._rest_place(landmarks) for _ in range(2)])
        rest_rotations = [self._lying_rotation() for _ in range(2)]
        rotations = [self._touch_rotation() for _ in landmarks]
        self._add(rng.uniform(*s["rest_s"]), _still(rests[0], rest_rotations[0]), "rest", 0)
        position, rotation = rests[0], rest_rotations[0]
        for index, (landmark, mean_rotation) in enumerate(zip(landmarks, rotations)):
            self._add_move(position, rotation, landmark, mean_rotation, lift_mm=rng.uniform(30.0, 120.0))
            self._add(rng.uniform(*s["settle_s"]), self._on_landmark(landmark, mean_rotation), "contact", index)
            self._add_swivel(landmark, mean_rotation, index)
            self._add(rng.uniform(0.0, s["settle_s"][1]), self._on_landmark(landmark, mean_rotation), "contact", index)
            position, rotation = landmark, mean_rotation
        self._add_move(position, rotation, rests[1], rest_rotations[1], lift_mm=rng.uniform(60.0, 150.0))
        self._add(rng.uniform(*s["rest_s"]), _still(rests[1], rest_rotations[1]), "rest", 1)
        frames, contacts, rest_times = self._sample(len(landmarks))
        return LandmarkSession(
            frames, landmarks, rests, contacts, rest_times, self.tip_true, self.tip_calibrated, s["tool"], dict(s)
        )

    def _add(self, duration_s, motion, kind=None, index=None):
        self.segments.append((float(duration_s), motion, kind, index))

    def _landmarks(self, count):
        """Landmarks on a phantom of 100-250 mm, at least 20 mm apart, drawn in a shuffled order."""
        size = self.rng.uniform(100.0, 250.0)
        points = []
        while len(points) < count:
            candidate = self.rng.uniform(-size / 2, size / 2, size=3) * (1.0, 1.0, 0.4)
            if all(np.linalg.norm(candidate - point) >= 20.0 for point in points):
                points.append(candidate)
        return np.array(points)

    def _rest_place(self, landmarks):
        """Where the stylus lies on the table: 200-450 mm from the phantom's centre, below its top."""
        angle = self.rng.uniform(0, 2 * np.pi)
        distance = self.rng.uniform(200.0, 450.0)
        return landmarks.mean(axis=0) + (distance * np.cos(angle), distance * np.sin(angle), -60.0)

    def _lying_rotation(self):
        """The stylus lying flat: its shaft horizontal, in a random direction, rolled at random about it."""
        heading = self.rng.uniform(0, 2 * np.pi)
        return self._rotation_with_shaft((np.cos(heading), np.sin(heading), 0.0))

    def _touch_rotation(self):
        """The stylus's mean pose on a landmark: shaft tilted 5-40 degrees from straight up."""
        tilt, heading = np.radians(self.rng.uniform(5.0, 40.0)), self.rng.uniform(0, 2 * np.pi)
        return self._rotation_with_shaft((np.sin(tilt) * np.cos(heading), np.sin(tilt) * np.sin(heading), np.cos(tilt)))

    def _rotation_with_shaft(self, direction):
        """A rotation (stylus to reference) taking the stylus's shaft to ``direction``, rolled at random."""
        align, _ = Rotation.align_vectors([direction], [self.shaft])
        roll = Rotation.from_rotvec(np.asarray(direction) * self.rng.uniform(0, 2 * np.pi))
        return (roll * align).as_matrix()

    def _on_landmark(self, landmark, rotation):
        """The tip held in the landmark's divot: the shaft trembles about it (0.1-0.3 degrees at 8-12 Hz)."""
        tremor = self._tremor_rotation(np.radians(self.rng.uniform(0.1, 0.3)))
        return lambda t: (landmark, tremor(t) @ rotation)

    def _add_swivel(self, landmark, mean_rotation, index):
        """The swivel: the shaft turns about the tip, ``swivel_deg`` between its extreme poses."""
        rng = self.rng
        duration = rng.uniform(*self.s["swivel_s"])
        axis = mean_rotation @ self.shaft
        first = _unit(np.cross(axis, rng.normal(size=3)))
        second = np.cross(axis, first)
        pattern = ("cone", "figure", "fan", "wobble")[int(rng.integers(4))]
        period = rng.uniform(1.0, 3.0)
        times = np.linspace(0.0, duration, 400)
        phase = rng.uniform(0, 2 * np.pi, size=6)
        frequencies = rng.uniform(0.3, 1.2, size=6)

        def tilts(t):
            envelope = np.clip(np.minimum(t, duration - t) / 0.4, 0.0, 1.0) ** 2  # starts and ends at rest
            w = 2 * np.pi * np.asarray(t) / period
            if pattern == "cone":
                a, b = np.cos(w) - 1.0, np.sin(w)  # round the cone from the mean pose
            elif pattern == "figure":
                a, b = np.sin(w), np.sin(2 * w + phase[0])
            elif pattern == "fan":
                a, b = np.sin(w), 0.15 * np.sin(1.7 * w + phase[0])
            else:
                a = sum(np.sin(2 * np.pi * frequencies[k] * np.asarray(t) + phase[k]) for k in range(3))
                b = sum(np.sin(2 * np.pi * frequencies[k] * np.asarray(t) + phase[k]) for k in range(3, 6))
            twist = 0.2 * np.sin(w * 0.5 + phase[1])
            return envelope * a, envelope * b, envelope * twist

        a, b, twist = tilts(times)
        vectors = np.outer(a, first) + np.outer(b, second)
        span = max(np.linalg.norm(vectors[:, None] - vectors[None], axis=2).max(), 1e-9)
        scale = np.radians(rng.uniform(*self.s["swivel_deg"])) / span
        twist_scale = np.radians(rng.uniform(0.0, 15.0)) / max(np.abs(twist).max(), 1e-9)
        tremor = self._tremor_rotation(np.radians(rng.uniform(0.1, 0.3)))

        def motion(t):
            a, b, turn = tilts(t)
            rotation = Rotation.from_rotvec(scale * (a * first + b * second) + twist_scale * turn * axis)
            return landmark, tremor(t) @ rotation.as_matrix() @ mean_rotation

        self._add(duration, motion, "contact", index)

    def _add_move(self, start, start_rotation, end, end_rotation, lift_mm):
        """Lift off, move (minimum jerk) and come down on ``end``; the hand trembles in the air."""
        distance = np.linalg.norm(end - start)
        duration = 0.5 + distance / self.rng.uniform(*self.s["move_speed_mm_s"])
        turn = Slerp([0.0, 1.0], Rotation.from_matrix([start_rotation, end_rotation]))
        tremor = self._tremor_offset(self.s["tremor_mm"])

        def motion(t):
            tau = np.clip(t / duration, 0.0, 1.0)
            s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
            air = np.sin(np.pi * s)
            tip = start + (end - start) * s + _UP * lift_mm * air + tremor(t) * air
            return tip, turn([s]).as_matrix()[0]

        self._add(duration, motion)

    def _tremor_rotation(self, amplitude_rad):
        frequency, phases = self.rng.uniform(8.0, 12.0), self.rng.uniform(0, 2 * np.pi, size=3)
        axis = _unit(self.rng.normal(size=3))
        return lambda t: Rotation.from_rotvec(
            amplitude_rad * np.sin(2 * np.pi * frequency * t + phases[0]) * axis
        ).as_matrix()

    def _tremor_offset(self, amplitude_mm):
        frequency, phases = self.rng.uniform(8.0, 12.0), self.rng.uniform(0, 2 * np.pi, size=3)
        return lambda t: amplitude_mm * np.sin(2 * np.pi * frequency * t + phases)

    # -- the tracker ---------------------------------------------------------------------------------------
    def _sample(self, landmark_count):
        rng, s = self.rng, self.s
        total = sum(duration for duration, *_ in self.segments)
        times, clock = [], 0.0
        while clock <= total:
            times.append(clock)
            step = (1.0 + rng.uniform(-0.1, 0.1)) / s["rate_hz"]
            clock += step * (int(rng.integers(2, 4)) if rng.random() < 0.01 else 1)  # a frame missed now and then
        invalid = np.zeros(len(times), dtype=bool)
        for _ in range(s["invalid_runs"]):
            start = int(rng.integers(0, len(times)))
            invalid[start : start + int(rng.integers(1, 16))] = True
        contacts = np.full((landmark_count, 2), np.nan)
        rest_times = np.full((2, 2), np.nan)
        ends = np.cumsum([duration for duration, *_ in self.segments])
        for (duration, _, kind, index), end in zip(self.segments, ends):
            table = contacts if kind == "contact" else rest_times if kind == "rest" else None
            if table is not None:
                begin = end - duration
                table[index] = (np.fmin(table[index, 0], begin), np.fmax(table[index, 1], end))
        noise = s["noise_mm"]
        translation_sd = noise / np.sqrt(6.0)  # half the tip's variance from the markers' position ...
        rotation_sd = noise / (2.0 * s["tip_length_mm"])  # ... half from their orientation, at the tip
        reference_sd = s["reference_noise_mm"]
        start_time = rng.uniform(10.0, 5000.0)
        frames = []
        segment = 0
        for number, (time_s, lost) in enumerate(zip(times, invalid)):
            while segment < len(self.segments) - 1 and time_s > ends[segment]:
                segment += 1
            duration, motion, *_ = self.segments[segment]
            tip, rotation = motion(time_s - (ends[segment] - duration))
            stylus_to_reference = _pose(rotation, tip - rotation @ self.tip_true)
            reference = self.reference_to_tracker @ _noisy(_pose(np.eye(3), np.zeros(3)), rng, reference_sd, 2e-4)
            stylus = self.reference_to_tracker @ stylus_to_reference
            stylus = _noisy(stylus, rng, translation_sd, rotation_sd)
            statuses = {REFERENCE_NAME: "OK", s["tool"]: "INVALID" if lost else "OK"}
            frames.append(
                TrackedFrame(
                    start_time + time_s,
                    {s["tool"]: np.eye(4) if lost else stylus, REFERENCE_NAME: reference},
                    statuses,
                    {"FrameNumber": str(number)},
                )
            )
        return frames, contacts + start_time, rest_times + start_time


def _still(position, rotation):
    return lambda t: (position, rotation)


def _pose(rotation, translation):
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rotation, translation
    return pose


def _noisy(pose, rng, translation_sd, rotation_sd):
    """``pose`` with its markers' noise: a small random rotation about its origin and a random shift."""
    noisy = pose.copy()
    noisy[:3, :3] = Rotation.from_rotvec(rng.normal(scale=rotation_sd, size=3)).as_matrix() @ pose[:3, :3]
    noisy[:3, 3] = pose[:3, 3] + rng.normal(scale=translation_sd, size=3)
    return noisy


def _unit(vector):
    vector = np.asarray(vector, dtype=np.float64)
    return vector / np.linalg.norm(vector)
