"""Pivot calibration of a tracked probe: the tip's offset in the probe frame (``ProbeTipToProbe``).

While the tip rests in a divot and the probe swivels, every pose ``(R_i, t_i)`` of ProbeToReference satisfies
``R_i p_tip + t_i = p_pivot``: a linear least-squares problem in the tip offset ``p_tip`` (probe frame) and
the pivot point ``p_pivot`` (reference frame). Poses that disagree with the fit (a slipped tip, a tracking
glitch) are rejected and the fit repeated.
"""

from dataclasses import dataclass

import numpy as np

#: A pose is an outlier when its tip lands this many times the median residual away from the pivot (and > 0.5 mm).
OUTLIER_FACTOR = 3.0
MIN_POSES = 10
MIN_ROTATION_DEG = 15.0


@dataclass(frozen=True)
class PivotResult:
    """``tip_in_probe`` (3,) mm, ``pivot_in_reference`` (3,) mm, RMS error (mm), kept poses (mask), warnings."""

    tip_in_probe: np.ndarray
    pivot_in_reference: np.ndarray
    rms_mm: float
    inliers: np.ndarray
    rotation_range_deg: float

    @property
    def probe_tip_to_probe(self):
        """(4, 4) ``ProbeTipToProbe``: a translation by the tip offset."""
        transform = np.eye(4)
        transform[:3, 3] = self.tip_in_probe
        return transform


def pivot_calibration(probe_to_reference):
    """Solve the pivot calibration from (N, 4, 4) ProbeToReference poses recorded while pivoting.

    Raises:
        ValueError: fewer than 10 poses, non-finite poses, or poses that swivel less than 15 degrees (the tip
            offset is then undetermined): with what to do.
    """
    poses = np.asarray(probe_to_reference, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise ValueError(f"pivot poses: expected an (N, 4, 4) array of ProbeToReference, got shape {poses.shape}")
    if len(poses) < MIN_POSES:
        raise ValueError(f"pivot calibration: {len(poses)} poses recorded, at least {MIN_POSES} needed; keep pivoting")
    if not np.isfinite(poses).all():
        raise ValueError("pivot calibration: some poses contain NaN or infinity; record again")
    spread = _rotation_range_deg(poses[:, :3, :3])
    if spread < MIN_ROTATION_DEG:
        raise ValueError(
            f"pivot calibration: the probe swivelled only {spread:.0f} degrees; swivel it at least "
            f"{MIN_ROTATION_DEG:.0f} degrees in two directions with the tip in the divot"
        )
    inliers = np.ones(len(poses), dtype=bool)
    for _ in range(3):
        tip, pivot = fixed_point_fit(poses[inliers])
        residuals = np.linalg.norm(poses[:, :3, :3] @ tip + poses[:, :3, 3] - pivot, axis=1)
        limit = max(OUTLIER_FACTOR * np.median(residuals[inliers]), 0.5)
        updated = residuals <= limit
        if updated.sum() < MIN_POSES or np.array_equal(updated, inliers):
            break
        inliers = updated
    tip, pivot = fixed_point_fit(poses[inliers])
    residuals = np.linalg.norm(poses[:, :3, :3] @ tip + poses[:, :3, 3] - pivot, axis=1)
    rms = float(np.sqrt(np.mean(residuals[inliers] ** 2)))
    return PivotResult(
        tip_in_probe=tip, pivot_in_reference=pivot, rms_mm=rms, inliers=inliers, rotation_range_deg=spread
    )


def fixed_point_fit(poses):
    """Least squares of ``R_i p + t_i = q`` over (N, 4, 4) poses ``(R_i, t_i)`` of a moving frame in a fixed one:
    ``p`` (3,) the point held still, in the moving frame, and ``q`` (3,) where it stays, in the fixed frame (mm).

    The pivot calibration (a probe tip in a divot) and the robot's four-point TCP calibration (``core.robot``: the
    tool-centre point held on one point while the flange turns) are both this fit.
    """
    count = len(poses)
    design = np.zeros((3 * count, 6))
    design[:, :3] = poses[:, :3, :3].reshape(3 * count, 3)
    design[:, 3:] = np.tile(-np.eye(3), (count, 1))
    solution, *_ = np.linalg.lstsq(design, -poses[:, :3, 3].reshape(3 * count), rcond=None)
    return solution[:3], solution[3:]


def _rotation_range_deg(rotations):
    """Largest rotation of any pose relative to the first one (degrees)."""
    cosines = (np.einsum("ij,nij->n", rotations[0], rotations) - 1.0) / 2.0  # trace(R0^T R_n)
    return float(np.degrees(np.arccos(np.clip(cosines, -1.0, 1.0))).max())
