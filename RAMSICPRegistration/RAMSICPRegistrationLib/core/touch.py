"""One touch of a tracked probe, and where it is: the held tip's mean or the swivel's fixed point.

A touch's poses (ProbeToReference, their rotations (N, 3, 3) and translations (N, 3) mm) and the probe's calibrated
tip (3,) mm (probe frame) give its position in reference coordinates: the least-squares fixed point of the poses
(``core.fixed_point``) along every direction they determine, the calibrated tip along the others. A direction is
determined when the probe turned at least ``MIN_PIVOT_TURN_DEG`` RMS about an axis across it and the fit's standard
error along it (the residual noise over the square root of its eigenvalue) is at most ``PIVOT_MAX_ERROR_MM``:

- ``method`` "pivot": all three; the landmark itself, independent of the tip calibration (a swivel about it);
- "partial pivot": one or two (a swivel about one axis only, a fan); the calibrated tip completes it;
- "mean tip": none (held still): exactly the mean of the held tips ``R_i tip + t_i``.

A recording's touches share one probe, so its full pivots calibrate the tip again (``recording_tip``: the joint
least squares of the pivots whose own tips agree, one tip and a point each), and every touch but the rests is then
placed at the mean of its tips at that tip (``with_recording_tip``, ``tip_from`` "recording"): the least-squares
point of its poses for the recording's tip. A single swivel's own pivot is only as good as its weakest turn (on the
drawn recordings of ``OpenIGTLinkBridgeLib.landmark_sessions``, 0.1-0.2 mm RMS and up to 0.9 mm off at 34-44
degrees); the joint tip, from all of them, places the touches within 0.02-0.04 mm RMS, and a tip calibration
1-2.5 mm off costs nothing. ``method`` keeps saying what the touch's own poses determined.
"""

from dataclasses import dataclass, field, replace

import numpy as np

from .fixed_point import rotation_range_deg

#: A direction of the fixed point is taken from the poses when the probe turned this much about it (RMS) ...
MIN_PIVOT_TURN_DEG = 1.0
#: ... and the fit's standard error along it is at most this (mm); else the calibrated tip is used along it.
PIVOT_MAX_ERROR_MM = 0.1
#: PLUS's swivel test (vtkIGSIOLandmarkDetectionAlgo): a point this far up the shaft (mm) ...
SHAFT_POINT_MM = 100.0
#: ... moves at least this much (mm, bounding-box diagonal) during the touch.
SWIVEL_SHAFT_MOTION_MM = 30.0
#: A swivel agrees with the recording's tip when placing it with that tip instead of its own moves its tips by at
#: most this much (mm RMS): a tip that slipped in its divot moves them by more.
TIP_AGREEMENT_MM = 0.15


@dataclass(frozen=True)
class Touch:
    """One touch: ``position`` (3,) mm (reference frame) over frames ``first_frame..last_frame``.

    ``frames``: the frames used; ``spread_mm``: their RMS distance from the position (the probe's point at
    ``tip_in_probe``); ``method``: what the touch's own poses determine, "pivot", "partial pivot" or "mean tip" (the
    module's docstring); ``tip_in_probe`` (3,) mm: the probe's point placed at the position; ``tip_from``: where that
    point comes from, "pivot" (the touch's own), "calibration" or "recording" (``with_recording_tip``);
    ``swivel_deg``: the largest turn between two of its poses; ``shaft_motion_mm``: PLUS's swivel measure;
    ``rest``: the probe lying still at the stream's start or end; ``dropped_frames``: glitches left out.
    """

    position: np.ndarray
    first_frame: int
    last_frame: int
    start_s: float
    end_s: float
    frames: int
    spread_mm: float
    method: str = "mean tip"
    tip_in_probe: np.ndarray = field(default_factory=lambda: np.zeros(3))
    tip_from: str = "calibration"
    swivel_deg: float = 0.0
    shaft_motion_mm: float = 0.0
    rest: bool = False
    dropped_frames: int = 0
    sums: object = field(default=None, compare=False, repr=False)  # FixedPointSums of its poses

    @property
    def duration_s(self):
        return self.end_s - self.start_s

    @property
    def swivelled(self):
        """PLUS's test: a point SHAFT_POINT_MM up the shaft moved at least SWIVEL_SHAFT_MOTION_MM."""
        return self.shaft_motion_mm >= SWIVEL_SHAFT_MOTION_MM

    @property
    def kind(self):
        """ "rest", "swivel" or "hold"."""
        return "rest" if self.rest else ("swivel" if self.swivelled else "hold")

    def to_dict(self):
        return {
            "position_mm": [float(value) for value in self.position],
            "kind": self.kind,
            "method": self.method,
            "tip_from": self.tip_from,
            "first_frame": int(self.first_frame),
            "last_frame": int(self.last_frame),
            "start_s": float(self.start_s),
            "end_s": float(self.end_s),
            "frames": int(self.frames),
            "dropped_frames": int(self.dropped_frames),
            "spread_mm": float(self.spread_mm),
            "tip_in_probe_mm": [float(value) for value in self.tip_in_probe],
            "swivel_deg": float(self.swivel_deg),
            "shaft_motion_mm": float(self.shaft_motion_mm),
        }


def touch_of_poses(rotations, translations, tip, sums, tip_error_mm):
    """The Touch (position, method, spread, swivel) of a run's poses: rotations (N, 3, 3), translations (N, 3) mm,
    the calibrated tip (3,) mm, their FixedPointSums; frame numbers and times are left for the caller."""
    p, q, method, noise = _position(sums, tip, tip_error_mm)
    distances = np.linalg.norm(rotations @ p + translations - q, axis=1)
    return Touch(
        position=q,
        first_frame=0,
        last_frame=len(rotations) - 1,
        start_s=0.0,
        end_s=0.0,
        frames=len(rotations),
        spread_mm=float(np.sqrt(np.mean(distances**2))),
        method=method,
        tip_in_probe=p,
        tip_from="pivot" if method == "pivot" else "calibration",
        swivel_deg=rotation_range_deg(rotations),
        shaft_motion_mm=shaft_motion_mm(rotations, translations, tip),
        sums=sums,
    )


def _position(sums, tip, tip_error_mm):
    """(p, q, method, per-axis noise) of a touch's sums with ``tip`` completing the undetermined directions."""
    count = sums.count
    free = sums.within(tip, tip_error_mm)
    noise = sums.residual_rms(free.p) / np.sqrt(3.0) * np.sqrt(count / max(count - 2, 1))  # per axis, 6 unknowns
    fit = sums.determined(tip, noise, PIVOT_MAX_ERROR_MM, np.radians(MIN_PIVOT_TURN_DEG))
    method = {0: "mean tip", 3: "pivot"}.get(fit.determined_axes, "partial pivot")
    return fit.p, fit.q, method, noise


def shaft_motion_mm(rotations, translations, tip):
    """Diagonal (mm) of the bounding box of the point SHAFT_POINT_MM up the shaft from the tip (towards the probe's
    origin; along the probe's z axis when the tip is its origin), as PLUS's landmark detection measures it."""
    length = np.linalg.norm(tip)
    up = -tip / length if length > 0 else np.array([0.0, 0.0, 1.0])
    shaft = rotations @ (tip + SHAFT_POINT_MM * up) + translations
    return float(np.linalg.norm(shaft.max(axis=0) - shaft.min(axis=0)))


def recording_tip(touches, calibrated_tip):
    """The tip (3,) mm (probe frame) the recording's swivels agree on, and how many agreed; (None, 0) with fewer
    than two. The joint least squares of the swivels (PLUS's test; one tip, a point each), each weighing by how much
    it turned; the swivel that disagrees most (placing it with the joint tip moves its tips by more than
    TIP_AGREEMENT_MM RMS) is left out and the fit repeated. Along a direction no swivel turned about (at least
    MIN_PIVOT_TURN_DEG RMS) the calibrated tip is kept."""
    swivels = [touch for touch in touches if touch.swivelled and not touch.rest and touch.sums is not None]
    calibrated_tip = np.asarray(calibrated_tip, dtype=np.float64)
    while len(swivels) >= 2:
        equations = [touch.sums.normal_equations() for touch in swivels]
        h_total = sum(h for h, _, _ in equations)
        g_total = sum(g for _, g, _ in equations)
        count = sum(touch.sums.count for touch in swivels)
        values, vectors = np.linalg.eigh(h_total)
        beta = vectors.T @ (h_total @ calibrated_tip + g_total)
        turned = values >= count * np.radians(MIN_PIVOT_TURN_DEG) ** 2
        tip = calibrated_tip + vectors @ np.where(turned, -beta / np.where(turned, values, 1.0), 0.0)
        shifts = [_shift_mm(touch.sums, tip) for touch in swivels]
        worst = int(np.argmax(shifts))
        if shifts[worst] <= TIP_AGREEMENT_MM:
            return tip, len(swivels)
        del swivels[worst]
    return None, 0


def _shift_mm(sums, tip):
    """How far (mm RMS) a touch's tips move when placed with ``tip`` instead of its own least squares: the square root
    of the rise of its residual sum over its frames."""
    h, g, _ = sums.normal_equations()
    own = -np.linalg.pinv(h) @ g
    rise = (tip @ h @ tip + 2 * g @ tip) - (own @ h @ own + 2 * g @ own)
    return float(np.sqrt(max(rise, 0.0) / sums.count))


def with_recording_tip(touches, calibrated_tip, own_pivots=False):
    """``touches`` placed at the mean of their tips at ``recording_tip`` (``tip_from`` "recording"; the rests and,
    with ``own_pivots``, the full pivots are left as they are), and that tip: (touches, tip (3,) mm or None when the
    recording has fewer than two agreeing swivels, count of swivels used)."""
    tip, count = recording_tip(touches, calibrated_tip)
    if tip is None:
        return list(touches), None, 0
    refined = [
        touch
        if touch.rest or touch.sums is None or (own_pivots and touch.method == "pivot")
        else replace(
            touch,
            position=touch.sums.point_for(tip),
            tip_in_probe=tip,
            tip_from="recording",
            spread_mm=touch.sums.residual_rms(tip),
        )
        for touch in touches
    ]
    return refined, tip, count
