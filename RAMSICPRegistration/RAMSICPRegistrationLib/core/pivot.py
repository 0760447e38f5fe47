"""Pivot calibration of a tracked probe: the tip's offset in the probe frame (``ProbeTipToProbe``).

While the tip rests in a divot and the probe swivels, every pose ``(R_i, t_i)`` of ProbeToReference satisfies
``R_i p_tip + t_i = p_pivot``: the least squares ``[R_i  -I] [p_tip; p_pivot] = -t_i`` over all poses (the algebraic
one-step method, Yaniv 2015, section 2.1.2; ``core.fixed_point``). Two methods:

- ``lsq``: that least squares over every pose, exactly as scikit-surgerycore's ``pivot_calibration`` (commit
  8f71235, ``sksurgerycore/algorithms/pivot.py``: SVD of the 3N x 6 system, refused below rank 6) and PLUS's
  ``vtkIGSIOPivotCalibrationAlgo`` (before its outlier rejection) compute it;
- ``robust`` (the default): the same least squares, repeated without the poses whose tip lands more than
  ``OUTLIER_FACTOR`` times the median residual from the pivot (all poses' residuals under the current fit, so that
  the threshold comes from the data and holds up to half of them being off), until the poses kept no longer change.
  ``OUTLIER_FACTOR`` is the 99.9th percentile of the distance of a 3-D Gaussian error over its median
  (4.033 / 1.538): with tracker noise alone, one pose in a thousand is dropped. The dropped poses are named as
  consecutive ranges with their times and residuals (a tip that slipped out of the divot for a moment).

Residuals are reported two ways: ``rms_mm``, the per-pose 3-D RMS ``sqrt(sum |r_i|^2 / N)`` over the kept poses;
and ``residual_per_axis_mm``, scikit-surgery's ``sqrt(sum of squared components / 3N)``, ``rms_mm / sqrt(3)``. PLUS
reports the mean of ``|r_i|`` (``ComputePivotCalibrationError``).
"""

from dataclasses import dataclass, field

import numpy as np

from .fixed_point import fixed_point_fit, rotation_range_deg

MIN_POSES = 10
MIN_ROTATION_DEG = 15.0
#: A pose is dropped when its tip lands this many times the median residual away from the pivot ...
OUTLIER_FACTOR = 2.62
#: ... and farther than this (mm, below every optical tracker's noise): exact poses are never dropped.
OUTLIER_FLOOR_MM = 0.1
METHODS = ("robust", "lsq")
#: scikit-surgerycore's rank test: a singular value of the 3N x 6 system below this fails the calibration.
_SKSURGERY_MIN_SINGULAR_VALUE = 0.01


@dataclass(frozen=True)
class DroppedRange:
    """Consecutive poses ``first..last`` (indices) the robust fit left out, their times (s, when known) and the
    largest and RMS distance (mm) of their tips from the pivot."""

    first: int
    last: int
    start_s: float
    end_s: float
    max_residual_mm: float
    rms_residual_mm: float

    @property
    def count(self):
        return self.last - self.first + 1

    def to_dict(self):
        return {
            "first_pose": int(self.first),
            "last_pose": int(self.last),
            "poses": int(self.count),
            "start_s": None if self.start_s is None else float(self.start_s),
            "end_s": None if self.end_s is None else float(self.end_s),
            "max_residual_mm": float(self.max_residual_mm),
            "rms_residual_mm": float(self.rms_residual_mm),
        }


@dataclass(frozen=True)
class PivotResult:
    """``tip_in_probe`` (3,) mm, ``pivot_in_reference`` (3,) mm, per-pose 3-D RMS (mm) over the kept poses, kept
    poses (N,) bool, the swivel (largest angle between two poses, degrees), the method, every pose's residual (N,)
    mm, the robust threshold (mm; None for lsq) and the dropped ranges."""

    tip_in_probe: np.ndarray
    pivot_in_reference: np.ndarray
    rms_mm: float
    inliers: np.ndarray
    rotation_range_deg: float
    method: str = "robust"
    residuals_mm: np.ndarray = field(default_factory=lambda: np.zeros(0))
    threshold_mm: object = None
    dropped: tuple = ()

    @property
    def probe_tip_to_probe(self):
        """(4, 4) ``ProbeTipToProbe``: a translation by the tip offset."""
        transform = np.eye(4)
        transform[:3, 3] = self.tip_in_probe
        return transform

    @property
    def residual_per_axis_mm(self):
        """scikit-surgery's residual: sqrt(sum of squared residual components / 3N) over the kept poses."""
        return self.rms_mm / np.sqrt(3.0)

    @property
    def mean_residual_mm(self):
        """PLUS's calibration error: the mean distance of the kept poses' tips from the pivot."""
        return float(np.mean(self.residuals_mm[self.inliers]))

    def to_dict(self):
        return {
            "method": self.method,
            "tip_mm": [float(value) for value in self.tip_in_probe],
            "pivot_mm": [float(value) for value in self.pivot_in_reference],
            "rms_mm": float(self.rms_mm),
            "residual_per_axis_mm": float(self.residual_per_axis_mm),
            "mean_residual_mm": self.mean_residual_mm,
            "swivel_deg": float(self.rotation_range_deg),
            "poses": int(len(self.inliers)),
            "kept": int(self.inliers.sum()),
            "threshold_mm": None if self.threshold_mm is None else float(self.threshold_mm),
            "dropped": [entry.to_dict() for entry in self.dropped],
        }


def pivot_calibration(probe_to_reference, method="robust", times_s=None):
    """Solve the pivot calibration from (N, 4, 4) ProbeToReference poses recorded while pivoting.

    Args:
        probe_to_reference: (N, 4, 4) poses, N >= 10, swivelling at least 15 degrees.
        method: "robust" (default) or "lsq" (the module's docstring).
        times_s: optional (N,) times (s) of the poses, to name the dropped ranges by time.

    Raises:
        ValueError: fewer than 10 poses, non-finite poses, a swivel under 15 degrees (the tip offset is then
            undetermined), a rank-deficient system or an unknown method: with what to do.
    """
    if method not in METHODS:
        raise ValueError(f"pivot method {method!r}: choose one of {', '.join(METHODS)}")
    poses = _checked_poses(probe_to_reference)
    if times_s is not None:
        times_s = np.asarray(times_s, dtype=np.float64)
        if times_s.shape != (len(poses),):
            raise ValueError(f"pivot times of shape {times_s.shape}: expected one time per pose ({len(poses)},)")
    spread = rotation_range_deg(poses[:, :3, :3])
    if spread < MIN_ROTATION_DEG:
        raise ValueError(
            f"pivot calibration: the probe swivelled only {spread:.0f} degrees; swivel it at least "
            f"{MIN_ROTATION_DEG:.0f} degrees in two directions with the tip in the divot"
        )
    _check_rank(poses)
    inliers = np.ones(len(poses), dtype=bool)
    threshold = None
    tip, pivot = fixed_point_fit(poses)
    residuals = _residuals(poses, tip, pivot)
    if method == "robust":
        for _ in range(50):
            threshold = max(OUTLIER_FACTOR * float(np.median(residuals)), OUTLIER_FLOOR_MM)
            kept = residuals <= threshold
            if kept.sum() < MIN_POSES or np.array_equal(kept, inliers):
                break
            inliers = kept
            tip, pivot = fixed_point_fit(poses[inliers])
            residuals = _residuals(poses, tip, pivot)
    rms = float(np.sqrt(np.mean(residuals[inliers] ** 2)))
    return PivotResult(
        tip_in_probe=tip,
        pivot_in_reference=pivot,
        rms_mm=rms,
        inliers=inliers,
        rotation_range_deg=spread,
        method=method,
        residuals_mm=residuals,
        threshold_mm=threshold,
        dropped=dropped_ranges(~inliers, residuals, times_s),
    )


def dropped_ranges(dropped, residuals_mm, times_s=None):
    """Consecutive runs of True in ``dropped`` (N,) as DroppedRange, with their residuals and times."""
    indices = np.flatnonzero(dropped)
    if not indices.size:
        return ()
    breaks = np.flatnonzero(np.diff(indices) > 1)
    starts = np.concatenate([[indices[0]], indices[breaks + 1]])
    ends = np.concatenate([indices[breaks], [indices[-1]]])
    ranges = []
    for first, last in zip(starts, ends):
        values = residuals_mm[first : last + 1]
        ranges.append(
            DroppedRange(
                int(first),
                int(last),
                None if times_s is None else float(times_s[first]),
                None if times_s is None else float(times_s[last]),
                float(values.max()),
                float(np.sqrt(np.mean(values**2))),
            )
        )
    return tuple(ranges)


def _checked_poses(probe_to_reference):
    poses = np.asarray(probe_to_reference, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise ValueError(f"pivot poses: expected an (N, 4, 4) array of ProbeToReference, got shape {poses.shape}")
    if len(poses) < MIN_POSES:
        raise ValueError(f"pivot calibration: {len(poses)} poses recorded, at least {MIN_POSES} needed; keep pivoting")
    if not np.isfinite(poses).all():
        raise ValueError("pivot calibration: some poses contain NaN or infinity; record again")
    return poses


def _check_rank(poses):
    """scikit-surgerycore's test: every singular value of the 3N x 6 system at least 0.01."""
    count = len(poses)
    design = np.zeros((3 * count, 6))
    design[:, :3] = poses[:, :3, :3].reshape(3 * count, 3)
    design[:, 3:] = np.tile(-np.eye(3), (count, 1))
    smallest = float(np.linalg.svd(design, compute_uv=False).min())
    if smallest < _SKSURGERY_MIN_SINGULAR_VALUE:
        raise ValueError(
            f"pivot calibration: the poses do not fix the tip (smallest singular value {smallest:.3g} < 0.01, rank "
            "under 6); swivel the probe about two different axes"
        )


def _residuals(poses, tip, pivot):
    """Distance (mm) of each pose's tip from the pivot, (N,)."""
    return np.linalg.norm(poses[:, :3, :3] @ tip + poses[:, :3, 3] - pivot, axis=1)


#: Distances (mm) of a probe's tip from its tool origin that a real probe can have: NDI's passive pointers and the
#: PlusLibData stylus (203.8 mm) lie between; 0 means a transform that is already the tip's (StylusTipToTracker).
TIP_DISTANCE_RANGE_MM = (30.0, 500.0)


def check_tip_offset(tip_mm, name="--tip"):
    """Raise ValueError unless the (3,) tip offset (mm, in the probe's frame) is 0 or lies within
    ``TIP_DISTANCE_RANGE_MM`` of the origin; the message names the unit it looks to be in (cm, m)."""
    tip = np.asarray(tip_mm, dtype=np.float64).reshape(3)
    distance = float(np.linalg.norm(tip))
    low, high = TIP_DISTANCE_RANGE_MM
    if distance == 0.0 or low <= distance <= high:
        return tip
    unit = next(
        (words for factor, words in ((10.0, "centimetres"), (1000.0, "metres")) if low <= distance * factor <= high),
        None,
    )
    cause = f"it looks to be in {unit}: give it in mm" if unit else "check the probe's calibration (pivot)"
    raise ValueError(
        f"{name} {' '.join(f'{value:g}' for value in tip)}: the tip is {distance:g} mm from the probe's origin, where "
        f"no probe's tip lies ({low:g} to {high:g} mm, or 0 for a transform that is already the tip's); {cause}"
    )
