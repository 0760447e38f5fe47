"""The registration error cr-fused predicts at image points: its RMS, its mean and its percentiles, per point.

cr-fused's pose covariance ``C`` (F4 of ``core.fused``) makes the error vector ``e`` at an image point ``y`` (how
far the registered patient point lands from ``y``) Gaussian, ``e = A d`` with ``A = [-[y - c]_x, I]`` and ``d`` the
pose error, of covariance ``S = A C A^T`` (3 x 3). Its length ``|e|`` then follows a generalised chi distribution:
with ``e = S^(1/2) r u``, ``r`` a chi variable of 3 degrees of freedom and ``u`` a direction uniform on the sphere,

    P(|e| <= q) = E_u[ F_chi2(3)( q^2 / (u^T S u) ) ],   E|e| = E[r] E_u[ sqrt(u^T S u) ],  E[r] = 2 sqrt(2 / pi)  (E1)

both averaged over ``DIRECTIONS`` directions of a Fibonacci lattice (exact to 1e-3 in probability). The RMS,
``sqrt(trace S)``, is F4's predicted TRE.

The weights behind ``C`` are estimates. The markers' FLE comes from the FRE of K markers (F2 of ``core.fused``),
with ``nu = 3K - 6`` degrees of freedom: the true FLE^2 is ``FLE_used^2 nu / chi2(nu)`` (Student's prediction
interval, or the posterior under the prior 1 / FLE^2; ``nu = 6`` for 4 markers: its 95th percentile is 3.7 times
the estimate). The fit weighted the markers by the estimate, so for a true ratio ``rho = FLE^2 / FLE_used^2`` the pose
error's covariance is the sandwich ``C (rho H_m + H_s) C``, ``H_m`` and ``H_s`` the markers' and the probe points'
information (``FusedFit.marker_information``, ``surface_information``):

    S(rho) = A C (rho H_m + H_s) C A^T,   P(|e| <= q) = E_rho[ E1 at S(rho) ],   rho ~ nu / chi2(nu) ............ (E2)

averaged over ``RATIO_QUANTILES`` values of ``rho``. The percentiles (the "95 % confidence" of
``core.touch_guidance``) use E2. The RMS and the mean must be right on average over registrations, not only safe:
the FRE's estimate of FLE^2 is unbiased, so they take ``rho = 1``, but a fit whose weight on the markers is off
errs more than ``C`` says (``C`` is the least error, at the right weight), so they add the mean excess E3
(``_weighting_bias``): the predicted error's covariance is ``A (C + B) A^T``. An FLE given by the user is taken as
known (``rho = 1``, no E3); an FRE below the floor (F2) leaves ``rho`` at least 1.

A few probe points may fit other poses as well (other minima of F1): ``core.pose_modes`` finds them and their
shares of the posterior, and every part here adds their second moment about the chosen pose (M2) to ``S``, as a
part that does not scale with the FLE.
"""

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from .small_motion import invert_information, point_jacobians, surface_rows

#: Directions of the Fibonacci lattice on the sphere that E1 averages over (a half sphere: u and -u agree).
DIRECTIONS = 400
#: Values of the FLE's ratio rho that E2 averages over (Gauss-Legendre nodes, see ``_fle_ratios``).
RATIO_QUANTILES = 32
#: Mean of a chi variable with 3 degrees of freedom.
CHI3_MEAN = 2.0 * np.sqrt(2.0 / np.pi)


@dataclass(frozen=True)
class PoseUncertainty:
    """A registration's pose uncertainty (F4, E2): everything the predicted error at any image point needs.

    Attributes:
        covariance: (6, 6) pose covariance: small rotation (rad) about ``centre_mm``, then translation (mm).
        centre_mm: (3,) image point the rotations are taken about.
        marker_information, surface_information: (6, 6) the markers' and the probe points' parts of its inverse.
        marker_dof: degrees of freedom of the markers' FLE estimate (3K - 6), or None when the FLE is known.
        fle_estimate_ratio: the FRE's estimate of FLE^2 over the FLE^2 the weights used: 1, or below 1 when the
            floor (F2) was used instead.
        fle_ratio_floor: the smallest ``rho`` (E2): 1 when the FLE is the floor, else 0.
        surface_sigma_mm: RMS point-to-surface noise of one probe touch the fit assumed (F3), for a new touch.
        mode_weights, mode_motions: (M,) and (M, 4, 4) the other minima of F1 and their shares of the posterior
            (``core.pose_modes``, M1), or None when none were searched for.
    """

    covariance: np.ndarray
    centre_mm: np.ndarray
    marker_information: np.ndarray
    surface_information: np.ndarray
    marker_dof: object = None
    fle_estimate_ratio: float = 1.0
    fle_ratio_floor: float = 0.0
    surface_sigma_mm: float = np.inf
    mode_weights: np.ndarray = None
    mode_motions: np.ndarray = None

    @classmethod
    def from_fit(cls, fit, marker_count=None, fre_fle_mm=None):
        """From a ``core.fused.FusedFit``: ``marker_count`` K gives the FLE estimate's 3K - 6 degrees of freedom
        and ``fre_fle_mm`` the FRE's own estimate of the FLE (F2, before the floor); without them, or when the FLE
        was given, it is taken as known."""
        weights = fit.weights
        uncertain = marker_count is not None and weights.fle_source in ("fre", "floor") and 3 * marker_count > 6
        floor = weights.fle_source == "floor" and fre_fle_mm is not None
        return cls(
            covariance=fit.covariance,
            centre_mm=np.asarray(fit.centre_mm, dtype=np.float64),
            marker_information=fit.marker_information,
            surface_information=fit.surface_information,
            marker_dof=3 * marker_count - 6 if uncertain else None,
            fle_estimate_ratio=(fre_fle_mm / weights.marker_fle_mm) ** 2 if floor else 1.0,
            fle_ratio_floor=1.0 if weights.fle_source == "floor" else 0.0,
            surface_sigma_mm=weights.surface_sigma_mm,
        )

    @property
    def weighting_bias(self):
        """(6, 6) the mean excess of the pose error's covariance over ``covariance`` that weighting the markers by
        an estimated FLE brings (E3), or None when the FLE is known or the floor."""
        if self.marker_dof is None or self.fle_ratio_floor > 0.0:
            return None
        return _weighting_bias(self.marker_information, self.surface_information, self.marker_dof)

    def errors_at(self, points_image):
        """PredictedErrors at the (T, 3) image points (mm)."""
        points = np.asarray(points_image, dtype=np.float64).reshape(-1, 3)
        jacobians = point_jacobians(points - self.centre_mm)  # (T, 3, 6)
        mapped = jacobians @ self.covariance  # A C
        markers = np.einsum("tij,jk,tlk->til", mapped, self.marker_information, mapped)
        surface = np.einsum("tij,jk,tlk->til", mapped, self.surface_information, mapped)
        bias = self.weighting_bias
        if bias is not None:
            bias = np.einsum("tij,jk,tlk->til", jacobians, bias, jacobians)
        modes = None
        if self.mode_weights is not None and len(self.mode_weights):
            modes = _mode_covariances(points, self.mode_weights, self.mode_motions)
        return PredictedErrors(
            markers, surface, self.marker_dof, self.fle_estimate_ratio, self.fle_ratio_floor, bias, modes
        )

    def with_touches(self, points_image, normals, sigma_mm=None):
        """The uncertainty after probe touches at (N, 3) image points on the surface with unit normals (N, 3), each
        a distance along its normal with noise ``sigma_mm`` (default: the fit's, F3): the probe points' information
        grows by ``sum j j^T / sigma^2``, ``j = [(y - c) x n, n]`` (F4), and the covariance is its new inverse."""
        sigma = self.surface_sigma_mm if sigma_mm is None else sigma_mm
        rows = surface_rows(
            np.asarray(points_image, float).reshape(-1, 3), np.reshape(normals, (-1, 3)), self.centre_mm
        )
        surface = self.surface_information + rows.T @ rows / sigma**2
        return replace(
            self, surface_information=surface, covariance=invert_information(self.marker_information + surface)
        )


@dataclass(frozen=True)
class PredictedErrors:
    """The predicted error's distribution at T image points (E1-E3), from its parts (T, 3, 3) in mm^2: ``markers``
    (the share of the markers' noise, ``A C H_m C A^T``), ``surface`` (the probe points'), and ``bias`` (E3's
    ``A B A^T``, or None) which the RMS and the mean add and E2's percentiles, which weigh every FLE, do not."""

    markers: np.ndarray
    surface: np.ndarray
    marker_dof: object = None
    fle_estimate_ratio: float = 1.0
    fle_ratio_floor: float = 0.0
    bias: np.ndarray = None
    modes: np.ndarray = None

    @property
    def covariances(self):
        """(T, 3, 3) mean covariance of each point's error vector (rho = 1, with E3's excess and the other modes'
        second moment, M2 of ``core.pose_modes``), mm^2."""
        total = self._fixed + self.markers
        return total if self.bias is None else total + self.bias

    @property
    def _fixed(self):
        """(T, 3, 3) the part that does not scale with the markers' FLE: the probe points' and the other modes'."""
        return self.surface if self.modes is None else self.surface + self.modes

    @property
    def rms_mm(self):
        """(T,) predicted RMS error, ``sqrt(trace S)`` (F4)."""
        return np.sqrt(np.maximum(np.trace(self.covariances, axis1=1, axis2=2), 0.0))

    @property
    def mean_mm(self):
        """(T,) predicted mean error length E|e| (E1 at rho = 1): about 0.92 times the RMS for an isotropic error,
        0.80 times for an error along one direction."""
        spread = _direction_variances(self.covariances)  # (T, M)
        return CHI3_MEAN * np.mean(np.sqrt(spread), axis=1)

    def probability_within(self, limits_mm):
        """(T,) probability that each point's error is at most ``limits_mm`` (scalar or (T,)), with the FLE's own
        uncertainty (E2)."""
        return self._distribution(limits_mm)[0]

    def quantile_mm(self, probability=0.95):
        """(T,) the error each point stays within with ``probability`` (E2), mm: Newton's method on E2 from the
        isotropic guess, kept inside a bracket that halves when a step leaves it; to 1e-6 in probability."""
        if not 0.0 < probability < 1.0:
            raise ValueError(f"probability {probability}: give a number between 0 and 1")
        from scipy import stats

        ratios, _ = self._ratios()
        total = np.trace(self._fixed, axis1=1, axis2=2) + np.trace(self.markers, axis1=1, axis2=2) * ratios.max()
        low, high = np.zeros(len(self.markers)), 10.0 * np.sqrt(np.maximum(total, 1e-24))
        variance = np.maximum(np.trace(self.covariances, axis1=1, axis2=2), 1e-24)
        guess = np.sqrt(variance / 3.0 * stats.chi2.ppf(probability, 3))
        for _ in range(60):
            value, slope = self._distribution(guess)
            below = value < probability
            low, high = np.where(below, guess, low), np.where(below, high, guess)
            if np.all(np.abs(value - probability) < 1e-6):
                break
            with np.errstate(divide="ignore", invalid="ignore"):
                step = guess + (probability - value) / slope
            inside = np.isfinite(step) & (step > low) & (step < high)
            guess = np.where(inside, step, 0.5 * (low + high))
        return guess

    def _distribution(self, limits_mm):
        """E2's probability (T,) and its derivative (T,) in 1/mm at ``limits_mm`` (scalar or (T,))."""
        from scipy.special import gammainc

        limits = np.broadcast_to(np.asarray(limits_mm, dtype=np.float64), (len(self.markers),))
        ratios, weights = self._ratios()  # (Q,)
        markers, surface = _direction_variances(self.markers), _direction_variances(self._fixed)  # (T, M)
        spread = surface[:, None, :] + ratios[None, :, None] * markers[:, None, :]  # (T, Q, M)
        with np.errstate(divide="ignore", invalid="ignore"):
            half = np.where(spread > 0.0, 0.5 * limits[:, None, None] ** 2 / spread, np.inf)
            # F_chi2(3)(x) = P(3/2, x/2) at x = q^2 / s; its derivative in q is chi2(3)'s density at x,
            # sqrt(x / 2 pi) exp(-x / 2), times 2 q / s = 2 x / q.
            density = np.where(np.isfinite(half), np.sqrt(half / np.pi) * np.exp(-half), 0.0)
            slope = np.where(limits[:, None, None] > 0.0, 4.0 * half * density / limits[:, None, None], 0.0)
        probability = np.mean(gammainc(1.5, half), axis=2) @ weights
        return probability, np.mean(slope, axis=2) @ weights

    def _ratios(self):
        return _fle_ratios(self.marker_dof, float(self.fle_estimate_ratio), float(self.fle_ratio_floor))


def _weighting_bias(marker_information, surface_information, marker_dof):
    """(6, 6) how much larger the pose error's covariance is, on average, than ``C`` for a fit that weighted its
    markers by an FLE estimated with ``marker_dof`` degrees of freedom (E3).

    With the estimate's weight ``l`` (the markers' information ``l M``) and the true one ``l0``, the fit's error
    covariance is ``C(l) (l^2 / l0 M + H_s) C(l)``, ``C(l) = (l M + H_s)^-1``: the least at ``l = l0``, where it is
    ``C(l0)``. Over the estimates ``l = l0 nu / chi2(nu)`` its mean exceeds the mean of the ``C(l)`` a fit reports by

        B = E[ C(l) (l^2 / l0 M + H_s) C(l) - C(l) ] ...................................................... (E3)

    (zero for the markers alone: their weight does not matter then). ``B`` is taken with ``l0`` at this fit's own
    estimate (a parametric bootstrap) over ``RATIO_QUANTILES`` Gauss-Legendre nodes of the chi2's probability.
    """
    from scipy import stats

    nodes, weights = np.polynomial.legendre.leggauss(RATIO_QUANTILES)
    levels, weights = 0.5 * (nodes + 1.0), 0.5 * weights
    bias = np.zeros((6, 6))
    for scale, weight in zip(marker_dof / stats.chi2.ppf(levels, marker_dof), weights):
        covariance = invert_information(scale * marker_information + surface_information)
        actual = covariance @ (scale**2 * marker_information + surface_information) @ covariance
        bias += weight * (actual - covariance)
    return bias


def _mode_covariances(points, weights, motions):
    """(T, 3, 3) the other modes' second moment about the chosen pose at (T, 3) image points (M2 of
    ``core.pose_modes``): ``sum_k w_k o_k o_k^T``, ``o_k = D_k y - y`` with ``D_k`` (M, 4, 4) and ``w_k`` (M,), mm^2."""
    offsets = np.einsum("mij,tj->mti", motions[:, :3, :3], points) + motions[:, None, :3, 3] - points  # (M, T, 3)
    return np.einsum("m,mti,mtj->tij", weights, offsets, offsets)


def _direction_variances(covariances):
    """(T, M) ``u^T S u`` of each (T, 3, 3) covariance over the lattice's directions."""
    directions = _directions()
    return np.einsum("mi,tij,mj->tm", directions, covariances, directions)


@lru_cache(maxsize=None)
def _directions():
    """(DIRECTIONS, 3) unit vectors of a Fibonacci lattice on the half sphere z >= 0 (equal areas)."""
    k = np.arange(DIRECTIONS) + 0.5
    z = 1.0 - k / DIRECTIONS  # uniform in z on [0, 1]: equal areas on the half sphere
    angle = np.pi * (1.0 + np.sqrt(5.0)) * k
    radius = np.sqrt(1.0 - z * z)
    directions = np.column_stack((radius * np.cos(angle), radius * np.sin(angle), z))
    directions.setflags(write=False)
    return directions


@lru_cache(maxsize=64)
def _fle_ratios(marker_dof, estimate, floor):
    """Values (Q,) of rho = FLE^2 / FLE_used^2 (E2), ``estimate nu / chi2(nu)`` at least ``floor``, and their
    weights (Q,), summing to 1: Gauss-Legendre on the chi2's probability ``s^2``, so that the large ratios of its
    lower tail, which the percentiles hang on, get their share of nodes; ([1], [1]) when the FLE is known."""
    if marker_dof is None:
        return np.ones(1), np.ones(1)
    from scipy import stats

    nodes, weights = np.polynomial.legendre.leggauss(RATIO_QUANTILES)
    root = 0.5 * (nodes + 1.0)  # s in (0, 1); the chi2's probability is s^2, its density 2 s
    ratios = np.maximum(estimate * marker_dof / stats.chi2.ppf(root**2, marker_dof), floor)
    weights = weights * root  # 0.5 (the interval) x 2 s
    for array in (ratios, weights):
        array.setflags(write=False)
    return ratios, weights / weights.sum()
