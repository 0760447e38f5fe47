"""Paired-point rigid registration by SVD (Arun et al. 1987, with Umeyama's 1991 reflection guard).

The coarse registration (CR) of the paper fits the 4 marker-sphere centres in reference coordinates to the
same centres in image coordinates; the fine registration repeats the same fit at every ICP iteration.
"""

from dataclasses import dataclass

import numpy as np

from .transforms import apply_transform, make_transform
from .validation import as_points, check_distinct, check_not_collinear


@dataclass(frozen=True)
class PairedPointFit:
    """Result of a paired-point fit.

    Attributes:
        transform: (4, 4) ``SourceToTarget``, e.g. ``ReferenceToImage`` for the coarse registration.
        fre_mm: fiducial registration error, the RMS of ``residuals_mm`` (weighted RMS when weights are given).
        residuals_mm: (N,) distance of each transformed source point from its target point.
    """

    transform: np.ndarray
    fre_mm: float
    residuals_mm: np.ndarray

    def to_dict(self):
        return {
            "transform": self.transform.tolist(),
            "fre_mm": self.fre_mm,
            "residuals_mm": self.residuals_mm.tolist(),
        }


def fit_rigid_transform(source, target, weights=None, source_name="source", target_name="target"):
    """Least-squares rigid transform mapping ``source`` onto ``target`` (paper eq. 5's CR, and eq. 9's step).

    Args:
        source: (N, 3) points in the moving frame (mm), N >= 3, distinct, not collinear.
        target: (N, 3) corresponding points in the fixed frame (mm), same order.
        weights: optional (N,) non-negative weights; at least 3 must be positive.
        source_name, target_name: names used in error messages.

    Returns:
        PairedPointFit with the (4, 4) transform, FRE and per-point residuals (mm).

    Raises:
        ValueError: fewer than 3 points, mismatched shapes, NaN/inf, duplicate or collinear points, bad weights.
    """
    source = as_points(source, source_name, min_count=3)
    target = as_points(target, target_name, min_count=3)
    if source.shape != target.shape:
        raise ValueError(
            f"{source_name} has {source.shape[0]} points but {target_name} has {target.shape[0]}; "
            "give the same points in the same order in both frames"
        )
    if weights is not None:
        weights = np.array(weights, dtype=np.float64)
        if weights.shape != (source.shape[0],) or not np.isfinite(weights).all() or (weights < 0).any():
            raise ValueError(
                f"weights: expected {source.shape[0]} finite non-negative numbers, got shape {weights.shape}"
            )
        if np.count_nonzero(weights) < 3:
            raise ValueError("weights: at least 3 points need a positive weight")
    used = slice(None) if weights is None else weights > 0
    for points, name in ((source, source_name), (target, target_name)):
        check_distinct(points[used], name)
        check_not_collinear(points[used], name)

    transform = rigid_procrustes(source, target, weights)
    residuals = np.linalg.norm(apply_transform(transform, source) - target, axis=1)
    if weights is None:
        fre = float(np.sqrt(np.mean(residuals**2)))
    else:
        fre = float(np.sqrt(np.sum(weights * residuals**2) / np.sum(weights)))
    return PairedPointFit(transform=transform, fre_mm=fre, residuals_mm=residuals)


def rigid_procrustes(source, target, weights=None):
    """The SVD solution without input checks, for validated (N, 3) arrays; returns a (4, 4) transform.

    Minimises ``sum_i w_i |R s_i + t - y_i|^2``; the sign correction keeps ``det(R) = +1`` so a reflection
    is never returned, even for noisy, nearly planar point sets.
    """
    if weights is None:
        source_centre = source.mean(axis=0)
        target_centre = target.mean(axis=0)
        covariance = (source - source_centre).T @ (target - target_centre)
    else:
        total = weights.sum()
        source_centre = weights @ source / total
        target_centre = weights @ target / total
        covariance = (source - source_centre).T @ ((target - target_centre) * weights[:, None])
    u, _, vt = np.linalg.svd(covariance)
    correction = np.ones(3)
    correction[2] = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rotation = (vt.T * correction) @ u.T
    return make_transform(rotation, target_centre - rotation @ source_centre)
