"""How well do the probe points fix the pose? A warning, in words, when they leave a motion free.

A surface registration can only feel motions that move the probe points off the surface. For points ``p_i`` with
surface normals ``n_i`` the first-order change of the point-to-surface distances under a small rotation ``w``
and translation ``t`` is ``n_i . (w x (p_i - c) + t)`` (Gelfand et al., "Geometrically stable sampling for the
ICP algorithm", 3DIM 2003). The 6x6 matrix ``A = sum_i a_i a_i^T`` with ``a_i = [(p_i - c) x n_i / r, n_i]``
(``c`` the centroid, ``r`` the RMS radius, so rotations are measured as mm of arc at radius r) tells which
motions the points constrain. A probe-point noise of ``sigma`` mm leaves each eigen-motion uncertain by about
``sigma / sqrt(lambda)`` mm: on a long bone's smooth shaft the rotation about its axis is the usual weak one.

The warning rule is scale-free: a motion is poorly constrained when ``lambda < 1``, that is when all the probe
points together pin it down less well than one touch pins down a translation along its own surface normal
(its uncertainty exceeds the probe noise itself).
"""

from dataclasses import dataclass

import numpy as np

#: Warn when the weakest eigenvalue is below this: the points fix that motion less well than one touch would.
MIN_EIGENVALUE = 1.0
#: Probe-tip noise assumed for the uncertainty (RMS, mm).
DEFAULT_PROBE_NOISE_MM = 0.25


@dataclass(frozen=True)
class ConstraintReport:
    """Eigen-analysis of the pose constraint of a set of surface points.

    Attributes:
        uncertainty_mm: (6,) expected pose uncertainty along each eigen-motion, weakest first (mm; inf if free).
        weakest_motion: (6,) the weakest eigen-motion, rotation part (3,) first then translation part (3,).
        is_rotation: True when the weakest motion is mostly a rotation.
        axis: (3,) unit rotation axis or translation direction of the weakest motion (image coordinates).
        radius_mm: RMS distance of the points from their centroid; the arc length of rotations is taken there.
        warning: the plain-words warning, or None when the pose is well constrained.
    """

    uncertainty_mm: np.ndarray
    weakest_motion: np.ndarray
    is_rotation: bool
    axis: np.ndarray
    radius_mm: float
    warning: str = None


def analyse_pose_constraint(points, normals, probe_noise_mm=DEFAULT_PROBE_NOISE_MM, long_axis=None):
    """Analyse how well surface points (N, 3) with unit normals (N, 3) fix a rigid pose.

    Args:
        points: registered probe points in image coordinates (mm).
        normals: IPC surface normals at their matches (sign irrelevant).
        probe_noise_mm: RMS probe noise used to turn the eigenvalues into uncertainties (mm).
        long_axis: optional (3,) direction of the bone's long axis, named in the warning when the weak motion
            is about or along it.
    """
    centre = points.mean(axis=0)
    offsets = points - centre
    radius = float(np.sqrt(np.mean(np.sum(offsets**2, axis=1)))) or 1.0
    rows = np.hstack((np.cross(offsets, normals) / radius, normals))
    eigenvalues, eigenvectors = np.linalg.eigh(rows.T @ rows)
    scale = max(eigenvalues[-1], 1.0)
    with np.errstate(divide="ignore"):
        uncertainty = np.where(eigenvalues > 1e-12 * scale, probe_noise_mm / np.sqrt(np.abs(eigenvalues)), np.inf)
    weakest = eigenvectors[:, 0]
    is_rotation = bool(np.linalg.norm(weakest[:3]) >= np.linalg.norm(weakest[3:]))
    part = weakest[:3] if is_rotation else weakest[3:]
    axis = part / np.linalg.norm(part)
    warning = None
    if eigenvalues[0] < MIN_EIGENVALUE:
        warning = _describe(uncertainty[0], is_rotation, axis, radius, probe_noise_mm, long_axis)
    return ConstraintReport(
        uncertainty_mm=uncertainty,
        weakest_motion=weakest,
        is_rotation=is_rotation,
        axis=axis,
        radius_mm=radius,
        warning=warning,
    )


def _describe(uncertainty, is_rotation, axis, radius, noise, long_axis):
    direction = f"({axis[0]:+.2f}, {axis[1]:+.2f}, {axis[2]:+.2f})"
    relation = ""
    if long_axis is not None:
        angle = np.degrees(np.arccos(min(1.0, abs(float(np.dot(axis, long_axis))))))
        if angle < 30.0:
            relation = f", {angle:.0f} deg from the bone's long axis"
    amount = (
        "is not constrained at all"
        if not np.isfinite(uncertainty)
        else (f"is uncertain by about {uncertainty:.1f} mm for {noise:.2f} mm probe noise")
    )
    if is_rotation:
        motion = f"rotation about the axis {direction}{relation} (arc at {radius:.0f} mm from the points' centre)"
    else:
        motion = f"translation along {direction}{relation}"
    return (
        f"The probe points poorly constrain the pose: {motion} {amount}. "
        "Collect points on surfaces facing other directions (around the bone and at its ends)."
    )
