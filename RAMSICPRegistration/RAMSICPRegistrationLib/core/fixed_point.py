"""The point a moving rigid body holds still: least squares over its poses (a pivot, a swivel about a landmark).

Every pose ``(R_i, t_i)`` (4, 4) of a moving frame (a probe) in a fixed one (the reference) maps the held point
``p`` (moving frame, mm) to where it stays, ``q`` (fixed frame, mm): ``R_i p + t_i = q``. Over N poses this is the
pivot calibration's algebraic one-step least squares ``[R_i  -I] [p; q] = -t_i`` (Yaniv 2015, section 2.1.2; PLUS's
``vtkIGSIOPivotCalibrationAlgo::GetPivotPointPosition``; scikit-surgerycore's ``pivot_calibration``).

Eliminating ``q = R_mean p + t_mean`` (means over the poses) leaves ``H p = -g`` with
``H = sum (R_i - R_mean)^T (R_i - R_mean) = N (I - R_mean^T R_mean)`` and ``g = sum (R_i - R_mean)^T (t_i - t_mean)``,
both from running sums: a stream of poses updates the fit in constant time per pose (``FixedPointSums``). The
eigenvalues of ``H / N`` are the squared RMS turns (rad^2) of the body about each eigen-direction, and ``p`` is only
known along the directions it turned about: a probe held still (no turn) says nothing about its tip offset, a
swivel about two axes fixes all three coordinates. Two ways of completing ``p`` from a prior ``p0`` (the tip's
calibration) are given: within ``max_offset_mm`` of ``p0`` (``within``), or the data where they are precise enough
and ``p0`` elsewhere (``determined``). With no turn at all both give ``p = p0`` and ``q`` = the mean of the tips
``R_i p0 + t_i``; with a full swivel both are the plain least squares, independent of ``p0``.
"""

from dataclasses import dataclass

import numpy as np

#: Eigenvalues of H / N below this (rad^2, an RMS turn of 0.06 degrees) are no turn at all, only rounding.
_NO_TURN = 1e-12 + (np.radians(0.06) ** 2)


@dataclass(frozen=True)
class FixedPoint:
    """``p`` (3,) mm in the moving frame, ``q`` (3,) mm in the fixed frame, and how many of p's three directions
    the poses themselves determined (``determined_axes``, 0 = ``p`` is the prior, 3 = plain least squares)."""

    p: np.ndarray
    q: np.ndarray
    determined_axes: int


class FixedPointSums:
    """Running sums of poses for the fixed-point least squares (see the module's docstring).

    Translations are summed relative to the first pose's, so that a fit far from the frame's origin (a tracker's
    coordinates, metres away) keeps its precision.
    """

    def __init__(self):
        self.count = 0
        self._origin = None
        self._sum_r = np.zeros((3, 3))
        self._sum_t = np.zeros(3)
        self._sum_rt = np.zeros(3)  # sum of R_i^T t_i
        self._sum_tt = 0.0  # sum of |t_i|^2

    def add(self, rotation, translation):
        """Add one pose: rotation (3, 3), translation (3,) mm."""
        if self._origin is None:
            self._origin = np.array(translation, dtype=np.float64)
        t = translation - self._origin
        self.count += 1
        self._sum_r += rotation
        self._sum_t += t
        self._sum_rt += rotation.T @ t
        self._sum_tt += float(t @ t)

    def copy(self):
        other = FixedPointSums()
        other.count, other._origin, other._sum_tt = self.count, self._origin, self._sum_tt
        other._sum_r, other._sum_t, other._sum_rt = self._sum_r.copy(), self._sum_t.copy(), self._sum_rt.copy()
        return other

    def normal_equations(self):
        """(H (3, 3), g (3,), c): the residual sum is ``p^T H p + 2 g^T p + c`` once q is eliminated."""
        n = self.count
        mean_r = self._sum_r / n
        h = n * (np.eye(3) - mean_r.T @ mean_r)
        g = self._sum_rt - mean_r.T @ self._sum_t
        c = self._sum_tt - float(self._sum_t @ self._sum_t) / n
        return 0.5 * (h + h.T), g, c

    def point_for(self, p):
        """``q`` (3,) mm where ``p`` stays on average: the mean of ``R_i p + t_i``."""
        return (self._sum_r @ p + self._sum_t) / self.count + self._origin

    def residual_rms(self, p):
        """RMS (mm) over the poses of ``|R_i p + t_i - q|`` with ``q = point_for(p)``: from the sums alone."""
        h, g, c = self.normal_equations()
        return float(np.sqrt(max(p @ h @ p + 2.0 * g @ p + c, 0.0) / self.count))

    def turns_rad(self):
        """RMS turn (rad) of the poses about the eigen-directions of H, smallest first, and those directions."""
        h, _, _ = self.normal_equations()
        values, vectors = np.linalg.eigh(h / max(self.count, 1))
        return np.sqrt(np.clip(values, 0.0, None)), vectors

    def within(self, p0, max_offset_mm):
        """The least squares with ``|p - p0| <= max_offset_mm`` (a trust region, Moré and Sorensen 1983)."""
        p0 = np.asarray(p0, dtype=np.float64)
        h, g, _ = self.normal_equations()
        values, vectors = np.linalg.eigh(h)
        turned = values > _NO_TURN * self.count
        beta = np.where(turned, vectors.T @ (h @ p0 + g), 0.0)  # the gradient at p0 / 2, in the eigen-basis
        step = -beta / np.where(turned, values, 1.0)
        if max_offset_mm <= 0:
            step = np.zeros(3)
        elif np.linalg.norm(step) > max_offset_mm:  # the constraint binds: |step(mu)| = max_offset_mm, mu > 0
            step = -beta / (values + _boundary_multiplier(values, beta, max_offset_mm))
        p = p0 + vectors @ step
        return FixedPoint(p, self.point_for(p), int(turned.sum()))

    def determined(self, p0, noise_mm, max_error_mm, min_turn_rad):
        """``p`` from the poses along each eigen-direction the body turned about by at least ``min_turn_rad`` RMS
        and where the fit's standard error ``noise_mm / sqrt(eigenvalue)`` is at most ``max_error_mm``; from ``p0``
        along the others. ``noise_mm``: the poses' residual per axis (mm)."""
        p0 = np.asarray(p0, dtype=np.float64)
        h, g, _ = self.normal_equations()
        values, vectors = np.linalg.eigh(h)
        beta = vectors.T @ (h @ p0 + g)
        standard_error = noise_mm / np.sqrt(np.clip(values, 1e-300, None))
        used = (values >= self.count * min_turn_rad**2) & (standard_error <= max_error_mm)
        step = np.where(used, -beta / np.where(used, values, 1.0), 0.0)
        p = p0 + vectors @ step
        return FixedPoint(p, self.point_for(p), int(used.sum()))


def _boundary_multiplier(values, beta, radius):
    """The mu > 0 with |beta / (values + mu)| = radius: Newton's method on 1/|step(mu)| - 1/radius, which is concave
    and increasing in mu, from the left, so that it converges monotonically (Moré and Sorensen 1983)."""
    mu = 1e-12 * (1.0 + float(values.max()))
    for _ in range(100):
        shifted = values + mu
        length = float(np.sqrt(np.sum((beta / shifted) ** 2)))
        excess = 1.0 / length - 1.0 / radius
        if excess >= -1e-12 / radius:
            break
        slope = float(np.sum(beta**2 / shifted**3)) / length**3
        mu -= excess / slope
    return mu


def fixed_point_fit(poses):
    """Plain least squares of ``R_i p + t_i = q`` over (N, 4, 4) poses: ``p`` (3,) the point held still, in the
    moving frame, and ``q`` (3,) where it stays, in the fixed frame (mm). Needs turns about two axes.

    The pivot calibration (a probe tip in a divot) and the robot's four-point TCP calibration (``core.robot``: the
    tool-centre point held on one point while the flange turns) are both this fit.
    """
    count = len(poses)
    design = np.zeros((3 * count, 6))
    design[:, :3] = poses[:, :3, :3].reshape(3 * count, 3)
    design[:, 3:] = np.tile(-np.eye(3), (count, 1))
    solution, *_ = np.linalg.lstsq(design, -poses[:, :3, 3].reshape(3 * count), rcond=None)
    return solution[:3], solution[3:]


def rotation_range_deg(rotations):
    """The largest angle (degrees) between any two of (N, 3, 3) rotations (exact, in blocks of 1024 poses)."""
    flat = np.asarray(rotations, dtype=np.float64).reshape(-1, 9)
    smallest_cosine = 1.0
    for start in range(0, len(flat), 1024):
        traces = flat[start : start + 1024] @ flat.T  # trace(R_a^T R_b) for every pair
        smallest_cosine = min(smallest_cosine, (float(traces.min()) - 1.0) / 2.0)
    return float(np.degrees(np.arccos(np.clip(smallest_cosine, -1.0, 1.0))))
