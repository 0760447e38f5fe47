"""Fused registration (``cr-fused``): the marker pairs and the probe points in one weighted least-squares fit.

Beyond the paper. After the CR (eq. 5), ICP and RAMSICP forget what the markers know and let a few dozen points
on one face of a bone decide all six degrees of freedom, two of which (slide along and spin about a shaft) they
barely constrain. Here both kinds of data enter one fit, each weighted by its own noise (Maurer et al.,
"Registration of head CT images to physical space using a weighted combination of points and surfaces",
IEEE TMI 17(5), 1998). With ``T`` the ReferenceToImage transform:

    E(T) = sum_k |T m_k - y_k|^2 / s_m^2 + sum_i rho(r_i / s_s),   r_i = n_i . (T p_i - c_i) ........ (F1)

* ``m_k``, ``y_k``: the K marker centres in reference and image coordinates (the CR's pairs, eq. 5);
  ``s_m^2 = FLE^2 / 3`` per coordinate, FLE being the RMS 3-D marker localisation error (F2).
* ``p_i``: the N probe points; ``c_i`` the IPC point closest to ``T p_i`` and ``n_i`` the IPC's unit normal
  there, both found again at every iteration (eq. 9's correspondence); ``s_s`` the RMS point-to-surface noise
  (F3); ``rho(u) = u^2`` up to ``|u| = HUBER_THRESHOLD = k`` and ``2 k |u| - k^2`` beyond (Huber's loss, F5),
  solved by reweighting: a point's weight is ``min(1, k / |u|) / s_s^2``.

Weights from each registration's own data, no targets needed:

    FLE^2 = FRE^2 / (1 - 2/K), at least FLE_FLOOR_MM ........................................ (F2)

(Fitzpatrick, West and Maurer 1998: E[FRE^2] = (1 - 2/K) FLE^2 for a rigid fit in 3-D); the floor stands for
what 4 markers cannot show: the tracker's own error on the reference body and the CT's resolution.

    s_s^2 = probe^2 / 3 + h^2 / 12 ........................................................... (F3)

``probe`` the RMS 3-D probe-tip error (only its normal third moves a point off the surface) and ``h`` the IPC's
point spacing (a surface known to one spacing, uniform quantisation). With ``MIN_POINTS_FOR_SIGMA`` probe points
or more, the residuals of the converged fit re-estimate it, ``s_s^2 = sum r_i^2 / (N - trace(C H_s))`` (the
points' share of the 6 pose parameters taken out), and a larger value replaces the prior and the fit goes on: a
noisier surface than expected must not be over-trusted.

Solution: Gauss-Newton on a small rotation ``w`` (about the points' centroid ``c``) and translation ``t``,
applied as ``T <- (R(w), t) T``; the rows of the Jacobian are

    marker k:  [-[T m_k - c]_x, I]          (3 rows, weight 1 / s_m^2)
    point i:   [((T p_i - c) x n_i)^T, n_i^T]  (1 row, weight min(1, k s_s / |r_i|) / s_s^2) ........... (F4)

and the covariance of the pose is ``C = (J^T W J)^-1`` at the solution; the predicted error at an image point
``y`` is ``sqrt(trace(A C A^T))`` with ``A = [-[y - c]_x, I]`` (F4). With no surface weight this is exactly
the Fitzpatrick-West-Maurer prediction of the CR (``metrics.predicted_tre``).

Two safeguards. A probe point flipping between two IPC points makes Gauss-Newton cycle (its steps stop
shrinking): the matches are then kept, and the fit settles at once. A fit that ends with the probe points
``RESTART_RATIO`` times farther from the surface than their noise has found a wrong basin (on a thin plate, the
other table): it starts again from 12 poses at +-2 standard deviations of the CR's own uncertainty (then at +-4 and
+-6 while the best still ends off the surface) and keeps the one with the lowest F1.

Variants measured (``benchmarks/compare_fused_variants.py --trials 100``, the README's "The fused registration"
has the table; right tibia and right ilium, 6 conditions each): the point-to-point SVD (Procrustes over both kinds
of pair) is up to 4.5 times worse, because the surface pairs pin the pose where it stands along the directions the
markers should decide; RAMSICP's ranges (eqs. 6-8) instead of the closest point change nothing or lose (up to
0.05 mm); variance-component estimation of both noises (the markers' FLE from the fused residuals too) gains
0.01 mm on a clean IPC and loses 0.08 mm on the ilium's IPC with its inner cortical surfaces; Huber's loss equals
least squares on a clean IPC and gains 0.01 mm with an inner wall in it. ``FUSED_DEFAULTS`` holds the winner, best
or within 0.02 mm of the best variant in every condition.
"""

from dataclasses import dataclass, replace

import numpy as np

from .icp import DEFAULT_TOLERANCE_MM, MatchingRanges
from .metrics import fle_from_fre
from .paired_point import rigid_procrustes
from .small_motion import cross_rows, invert_information, motion, point_jacobians, skew, solve
from .transforms import apply_transform

_IDENTITY = np.eye(3)

#: Smallest marker FLE the weights assume (mm), see F2. It binds only when the 4 markers agree to about 0.015 mm
#: (FRE), as centres found automatically in a CT do; a real tracker's own 0.1 mm would show in the FRE. Measured
#: on the ilium phantom with automatic centres (40 trials): a floor of 0.05 mm let the IPC's 0.08 mm segmentation
#: bias pull cr-fused 0.03 mm above the CR, 0.02 mm keeps it within 0.005 mm.
FLE_FLOOR_MM = 0.02
#: Probe points needed before the residuals may re-estimate the surface noise (F3).
MIN_POINTS_FOR_SIGMA = 12
#: Huber's threshold on the normalised residual (F5): quadratic below, linear above.
HUBER_THRESHOLD = 2.0
DEFAULT_MAX_ITERATIONS = 100
SOLVERS = ("point-to-plane", "point-to-point")
CORRESPONDENCES = ("closest", "ramsicp")
LOSSES = ("least-squares", "huber")
VARIANCES = ("fixed", "surface", "vce")
#: The variant kept after measuring all of them (module docstring).
FUSED_DEFAULTS = {
    "solver": "point-to-plane",
    "correspondence": "closest",
    "loss": "huber",
    "variance": "surface",
}
#: Re-estimations of the weights after convergence, at most.
MAX_REESTIMATIONS = 5
#: A fit whose probe points end this many times their noise from the surface is started again (``restarts``) ...
RESTART_RATIO = 3.0
#: ... from +-2 standard deviations of the CR's uncertainty along each of its axes, then, while the best fit is still
#: off the surface, from 4 and 6: the FLE behind those deviations is the FRE's estimate, with 6 degrees of freedom for
#: 4 markers, and in 1 trial in 20 the true FLE is 1.9 times the estimate or more. Measured on the fibula with an
#: FLE of 2.5 mm (300 trials): 3 fits off the surface after the first round, all on it (TRE 0.14-0.29 mm instead of
#: 6.5-9.0) after the second or third.
RESTART_SPREADS = (2.0, 4.0, 6.0)
#: A fit whose F1 lies above its chi-square's 1 - MISFIT_P quantile is started again too: on a thin bone (the fibula,
#: 8 points, FLE 2.5 mm) the probe points can fit the surface well in another basin, the markers pulled far from
#: their CR (F1 29-47 against 14 expected); 1 fit in 100 that is right is started again for nothing.
MISFIT_P = 0.01


@dataclass(frozen=True)
class FusedWeights:
    """The noise levels behind the weights of F1, in mm, and where they came from.

    Attributes:
        marker_fle_mm: RMS 3-D marker localisation error used (F2); each marker coordinate is weighted
            ``3 / marker_fle_mm^2``.
        surface_sigma_mm: RMS point-to-surface noise used (F3); each probe point is weighted ``1 / sigma^2``.
        fle_source: 'fre' (estimated from the CR's FRE), 'floor' (the estimate was below ``FLE_FLOOR_MM``)
            or 'given'.
        sigma_source: 'prior' (probe noise and IPC spacing) or 'residuals' (re-estimated after the fit).
        probe_noise_mm: RMS 3-D probe-tip error assumed.
        ipc_spacing_mm: the IPC's median point spacing.
    """

    marker_fle_mm: float
    surface_sigma_mm: float
    fle_source: str
    sigma_source: str
    probe_noise_mm: float
    ipc_spacing_mm: float

    @property
    def marker_weight(self):
        """Weight of one marker coordinate, 1/mm^2 (0 when the FLE is infinite)."""
        return 3.0 / self.marker_fle_mm**2 if np.isfinite(self.marker_fle_mm) else 0.0

    @property
    def surface_weight(self):
        """Weight of one probe point's distance to the surface, 1/mm^2 (0 when sigma is infinite)."""
        return 1.0 / self.surface_sigma_mm**2 if np.isfinite(self.surface_sigma_mm) else 0.0

    def to_dict(self):
        def finite(value):
            return float(value) if np.isfinite(value) else None

        return {
            "marker_fle_mm": finite(self.marker_fle_mm),
            "surface_sigma_mm": finite(self.surface_sigma_mm),
            "marker_weight_per_mm2": self.marker_weight,
            "surface_weight_per_mm2": self.surface_weight,
            "fle_source": self.fle_source,
            "sigma_source": self.sigma_source,
            "probe_noise_mm": self.probe_noise_mm,
            "ipc_spacing_mm": self.ipc_spacing_mm,
        }

    def describe(self):
        """The weights in words, as the command line and the GUI show them."""
        return (
            f"markers: FLE {self.marker_fle_mm:.2f} mm ({FLE_SOURCES[self.fle_source]}); probe points: "
            f"{self.surface_sigma_mm:.2f} mm from the surface ({SIGMA_SOURCES[self.sigma_source]})"
        )


#: Where the marker FLE and the surface noise behind the weights came from, in words.
FLE_SOURCES = {"fre": "from the CR's FRE", "floor": "the floor: the FRE was smaller", "given": "given"}
SIGMA_SOURCES = {
    "prior": "from the probe noise and the IPC spacing",
    "residuals": "from the residuals: noisier than the probe",
}


def marker_fle(fre_mm, marker_count, floor_mm=FLE_FLOOR_MM):
    """FLE (RMS 3-D, mm) for the weights from the CR's FRE (F2); returns (fle, 'fre' | 'floor')."""
    estimate = fle_from_fre(fre_mm, marker_count)
    return (estimate, "fre") if estimate >= floor_mm else (float(floor_mm), "floor")


def surface_sigma(probe_noise_mm, ipc_spacing_mm):
    """Prior RMS point-to-surface noise (mm) from the probe noise and the IPC spacing (F3)."""
    return float(np.sqrt(probe_noise_mm**2 / 3.0 + ipc_spacing_mm**2 / 12.0))


@dataclass(frozen=True)
class FusedFit:
    """Outcome of ``fused_fit``.

    Attributes:
        transform: (4, 4) ReferenceToImage.
        covariance: (6, 6) covariance of the pose (F4): small rotation (rad) about ``centre_mm`` then
            translation (mm), in image coordinates.
        centre_mm: (3,) the image point the rotations of ``covariance`` are taken about.
        iterations: Gauss-Newton (or SVD) iterations run; converged: False when the limit stopped them.
        matched_indices: (N,) IPC index matched to each probe point at the end.
        surface_residuals_mm: (N,) normal distance of each registered probe point to its match.
        surface_dof: how many of the 6 pose parameters the probe points fix, ``trace(C H_surface)`` (0 to 6);
            the markers fix the rest.
        weights: the FusedWeights used (after any re-estimation of the surface noise).
        starts: 1, or how many fits were run (13, 25 or 37) when the first was in doubt (``restarts``);
            chosen_start: which of them was kept (0: the first, from the CR).
        marker_information, surface_information: (6, 6) the two parts of ``covariance``'s inverse at the solution,
            ``J^T W J`` of the markers' rows and of the probe points' rows (F4): the predicted error's distribution
            when the markers' FLE is itself uncertain, and a new touch's effect, need them apart
            (``core.error_prediction``).
    """

    transform: np.ndarray
    covariance: np.ndarray
    centre_mm: np.ndarray
    iterations: int
    converged: bool
    matched_indices: np.ndarray
    surface_residuals_mm: np.ndarray
    surface_dof: float
    weights: FusedWeights
    starts: int = 1
    chosen_start: int = 0
    marker_information: np.ndarray = None
    surface_information: np.ndarray = None

    def predicted_errors_mm(self, points_image):
        """Predicted RMS registration error (mm) at each (T, 3) image point, from the covariance (F4)."""
        return predicted_errors(self.covariance, self.centre_mm, points_image)


def predicted_errors(covariance, centre, points):
    """``sqrt(trace(A C A^T))`` for each (T, 3) point, ``A = [-[y - c]_x, I]`` (F4); (T,) mm."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    jacobians = point_jacobians(points - centre)  # (T, 3, 6)
    squared = np.einsum("tij,jk,tik->t", jacobians, covariance, jacobians)
    return np.sqrt(np.maximum(squared, 0.0))


def fused_fit(
    index,
    ppc,
    markers_patient,
    markers_image,
    initial_transform,
    weights,
    solver=FUSED_DEFAULTS["solver"],
    correspondence=FUSED_DEFAULTS["correspondence"],
    loss=FUSED_DEFAULTS["loss"],
    scale=5.0,
    variance=FUSED_DEFAULTS["variance"],
    restarts=True,
    max_iterations=DEFAULT_MAX_ITERATIONS,
    tolerance_mm=DEFAULT_TOLERANCE_MM,
):
    """Minimise F1 from ``initial_transform`` (the CR); see the module docstring.

    Args:
        index: SurfaceIndex of the IPC (image coordinates, mm).
        ppc: (N, 3) probe points in reference coordinates (mm), validated.
        markers_patient, markers_image: (K, 3) marker centres in reference and image coordinates, validated.
        initial_transform: (4, 4) ReferenceToImage start, normally the CR.
        weights: FusedWeights (its infinite FLE or sigma switch that kind of data off).
        solver, correspondence, loss: one of SOLVERS, CORRESPONDENCES, LOSSES.
        scale: L of RAMSICP's ranges when ``correspondence`` is 'ramsicp'.
        variance: 'fixed' (the weights as given), 'surface' (the surface noise re-estimated from the residuals,
            F3) or 'vce' (both, by variance-component estimation).
        restarts: when the fit ends with the probe points ``RESTART_RATIO`` times farther from the surface than
            their noise, start again from 12 poses around the CR (its uncertainty, +-2 sd; then +-4 and +-6 while
            the best still ends off the surface) and keep the lowest F1.
        tolerance_mm: stop when no probe point or marker moves by more than this in an iteration.

    Returns:
        FusedFit.
    """
    choices = ((solver, SOLVERS), (correspondence, CORRESPONDENCES), (loss, LOSSES), (variance, VARIANCES))
    if any(choice not in allowed for choice, allowed in choices):
        raise ValueError(
            f"fused variant {solver!r}, {correspondence!r}, {loss!r}, {variance!r}: use a solver from {SOLVERS}, "
            f"a correspondence from {CORRESPONDENCES}, a loss from {LOSSES} and a variance from {VARIANCES}"
        )
    if correspondence == "ramsicp":
        match = MatchingRanges(index, apply_transform(initial_transform, ppc), scale).matcher(scale)
    else:

        def match(moving):
            return index.nearest(moving)[1]

    data = (index, match, ppc, markers_patient, markers_image, loss)
    options = (solver, variance, max_iterations, tolerance_mm)
    fit = _fit_from(np.array(initial_transform, dtype=np.float64), weights, data, options)
    if restarts and weights.marker_weight > 0 and weights.surface_weight > 0 and _doubtful(fit, weights, data):
        # The fit ended off the surface, or explains its data worse than their noise allows: a local minimum of F1
        # far from the CR's error. Start again from both ends of each axis of the CR's uncertainty, farther out until
        # the best fit is no longer in doubt, and keep the lowest F1 (at the first weights).
        candidates = [fit]
        for spread in RESTART_SPREADS:
            candidates += [_fit_from(start, weights, data, options) for start in _starts(data, weights, spread)]
            best = int(np.argmin([_objective(candidate.transform, weights, data) for candidate in candidates]))
            if not _doubtful(candidates[best], weights, data):
                break
        fit = replace(candidates[best], starts=len(candidates), chosen_start=best)
    return fit


def _doubtful(fit, weights, data):
    """Whether a fit ends with its probe points ``RESTART_RATIO`` times farther from the surface than their noise, or
    with F1 above its ``1 - MISFIT_P`` quantile: chi-square with as many degrees of freedom as residuals less the 6
    pose parameters (N + 3K - 6)."""
    from scipy import stats  # here, not at the top: the command line's --help must not wait for scipy.stats

    if float(np.sqrt(np.mean(fit.surface_residuals_mm**2))) > RESTART_RATIO * weights.surface_sigma_mm:
        return True
    _, _, ppc, markers_patient, _, _ = data
    freedom = len(ppc) + 3 * len(markers_patient) - 6
    return _objective(fit.transform, weights, data) > stats.chi2.ppf(1.0 - MISFIT_P, freedom)


def _fit_from(transform, weights, data, options):
    """Gauss-Newton (or SVD) iterations of F1 from one start; the weights re-estimated at convergence (F2, F3)."""
    index, match, ppc, markers_patient, markers_image, loss = data
    solver, variance, max_iterations, tolerance_mm = options
    prior_sigma = weights.surface_sigma_mm
    sigma_reliable = len(ppc) >= MIN_POINTS_FOR_SIGMA and np.isfinite(prior_sigma)
    reestimations = MAX_REESTIMATIONS if variance != "fixed" else 0
    converged = False
    iterations = 0
    frozen, last_move = None, np.inf
    while iterations < max_iterations:
        iterations += 1
        state = _State(index, match, transform, ppc, markers_patient, markers_image, weights, loss, frozen)
        if solver == "point-to-point":
            step = _procrustes_step(state, markers_image, weights.marker_weight)
            move = _largest_move(step, state.moved_points, markers_image)
        else:  # Gauss-Newton on F4's normal equations
            delta = solve(state.information, -state.gradient)
            step = motion(delta, state.centre)
            # No point moves further than the translation plus the rotation's arc at the farthest point.
            move = float(np.linalg.norm(delta[3:]) + np.linalg.norm(delta[:3]) * state.radius)
        transform = step @ transform
        if solver == "point-to-plane" and iterations > 2 and move > 0.5 * last_move and frozen is None:
            # Gauss-Newton shrinks its steps many times over when it converges; a step as large as the last means
            # a probe point is flipping between two IPC points: keep these matches, and the fit settles at once.
            frozen = state.matched
        last_move = move
        if move >= tolerance_mm:
            continue
        if reestimations:
            reestimations -= 1
            updated = _reestimated(state, weights, variance, sigma_reliable, prior_sigma)
            if updated is not None:
                weights, frozen, last_move = updated, None, np.inf
                continue
        converged = True
        break
    if not converged:  # the last state is more than the tolerance away from where the loop stopped
        state = _State(index, match, transform, ppc, markers_patient, markers_image, weights, loss, frozen)
    covariance = invert_information(state.information)
    surface_dof = float(np.trace(covariance @ state.surface_information)) if np.isfinite(covariance).all() else 6.0
    return FusedFit(
        transform=transform,
        covariance=covariance,
        centre_mm=state.centre,
        iterations=iterations,
        converged=converged,
        matched_indices=state.matched,
        surface_residuals_mm=np.abs(
            np.einsum("ij,ij->i", apply_transform(transform, ppc) - state.matched_points, state.normals)
        ),
        surface_dof=surface_dof,
        weights=weights,
        marker_information=state.marker_weight * state.marker_information,
        surface_information=state.surface_information,
    )


def _objective(transform, weights, data):
    """F1 at a pose, with its closest points and these weights (Huber's rho itself, not its reweighting)."""
    index, match, ppc, markers_patient, markers_image, loss = data
    state = _State(index, match, transform, ppc, markers_patient, markers_image, weights, "least-squares")
    normalised = np.abs(state.surface_residuals) / weights.surface_sigma_mm
    if loss == "huber":
        beyond = normalised > HUBER_THRESHOLD
        normalised[beyond] = np.sqrt(2.0 * HUBER_THRESHOLD * normalised[beyond] - HUBER_THRESHOLD**2)
    return weights.marker_weight * float(np.sum(state.marker_residuals**2)) + float(np.sum(normalised**2))


def _starts(data, weights, spread=2.0):
    """Starts at +-``spread`` standard deviations along each eigen-motion of the CR's pose covariance (markers
    alone)."""
    _, _, _, markers_patient, markers_image, _ = data
    coarse = rigid_procrustes(markers_patient, markers_image)
    moved = apply_transform(coarse, markers_patient)
    centre = moved.mean(axis=0)
    information, _ = _marker_equations(moved - centre, moved - markers_image)
    variances, motions = np.linalg.eigh(np.linalg.inv(weights.marker_weight * information))
    return [
        motion(sign * spread * np.sqrt(variance) * direction, centre) @ coarse
        for variance, direction in zip(variances, motions.T)
        for sign in (-1.0, 1.0)
    ]


class _State:
    """Correspondences, residuals and normal equations of F1 at one pose (F4's rows about the centroid)."""

    def __init__(self, index, match, transform, ppc, markers_patient, markers_image, weights, loss, matched=None):
        self.moved_points = apply_transform(transform, ppc)
        self.moved_markers = apply_transform(transform, markers_patient)
        self.matched = match(self.moved_points) if matched is None else matched
        self.normals = index.normals(self.matched)
        self.matched_points = index.points[self.matched]
        self.surface_residuals = np.einsum("ij,ij->i", self.moved_points - self.matched_points, self.normals)
        self.marker_residuals = self.moved_markers - markers_image
        self.surface_weights = weights.surface_weight * _robust_weights(
            self.surface_residuals, weights.surface_sigma_mm, loss
        )
        self.marker_weight = weights.marker_weight
        count = len(self.moved_points) + len(self.moved_markers)
        self.centre = (self.moved_points.sum(axis=0) + self.moved_markers.sum(axis=0)) / count
        self.radius = float(np.sqrt(max(np.max(np.sum((self.moved_points - self.centre) ** 2, axis=1)),
                                        np.max(np.sum((self.moved_markers - self.centre) ** 2, axis=1)))))  # fmt: skip
        self.marker_information, marker_gradient = _marker_equations(
            self.moved_markers - self.centre, self.marker_residuals
        )
        rows = np.hstack((cross_rows(self.moved_points - self.centre, self.normals), self.normals))
        weighted = rows * self.surface_weights[:, None]
        self.surface_information = weighted.T @ rows
        self.information = self.marker_weight * self.marker_information + self.surface_information
        self.gradient = self.marker_weight * marker_gradient + weighted.T @ self.surface_residuals


def _reestimated(state, weights, variance, sigma_reliable, prior_sigma):
    """Weights re-estimated from the residuals of a converged fit, or None when they stay (F2, F3).

    Each kind of data gets ``sum r^2 / redundancy``, its redundancy being its number of residuals less its share
    of the 6 pose parameters, ``trace(C H_g)`` (variance-component estimation). With the surface switched off the
    markers' redundancy is ``3K - 6`` and this is F2 exactly. The surface noise never drops below its prior (F3).
    """
    covariance = invert_information(state.information)
    if not np.isfinite(covariance).all():
        return None
    sigma, fle = weights.surface_sigma_mm, weights.marker_fle_mm
    sigma_source, fle_source = weights.sigma_source, weights.fle_source
    if sigma_reliable and weights.surface_weight > 0:
        redundancy = len(state.surface_residuals) - float(np.trace(covariance @ state.surface_information))
        estimate = float(np.sqrt(np.sum(state.surface_weights / weights.surface_weight * state.surface_residuals**2)
                                 / max(redundancy, 1.0)))  # fmt: skip
        if estimate > prior_sigma:
            sigma, sigma_source = estimate, "residuals"
        else:
            sigma, sigma_source = prior_sigma, "prior"
    if variance == "vce" and weights.marker_weight > 0 and weights.fle_source != "given":
        redundancy = state.marker_residuals.size - float(
            np.trace(covariance @ (weights.marker_weight * state.marker_information))
        )
        if redundancy > 0.5:
            per_coordinate = float(np.sum(state.marker_residuals**2)) / redundancy
            fle, fle_source = float(np.sqrt(3.0 * per_coordinate)), "residuals"
            if fle < FLE_FLOOR_MM:
                fle, fle_source = FLE_FLOOR_MM, "floor"
    if abs(sigma / weights.surface_sigma_mm - 1.0) < 0.02 and abs(fle / weights.marker_fle_mm - 1.0) < 0.02:
        return None
    return replace(weights, surface_sigma_mm=sigma, sigma_source=sigma_source, marker_fle_mm=fle, fle_source=fle_source)


def _largest_move(step, moved_points, markers):
    """Largest displacement (mm) a step gives the probe points and the markers (near their image positions)."""
    before = np.vstack((moved_points, markers))
    return float(np.abs(apply_transform(step, before) - before).max())


def _robust_weights(residuals, sigma, loss):
    """IRLS multipliers of the surface weights for the loss (F5): 1 for least squares."""
    if loss == "least-squares" or not np.isfinite(sigma):
        return np.ones(len(residuals))
    normalised = np.abs(residuals) / sigma
    return np.minimum(1.0, HUBER_THRESHOLD / np.maximum(normalised, 1e-12))


def _marker_equations(offsets, residuals):
    """Information (6, 6) and gradient (6,) of unit-weight marker rows ``[-[d]_x, I]``, offsets d from the centre.

    In closed form: ``[[sum(|d|^2 I - d d^T), [sum d]_x], [-[sum d]_x, K I]]`` and ``[sum d x r, sum r]``.
    """
    block = np.zeros((6, 6))
    scatter = offsets.T @ offsets
    block[:3, :3] = np.trace(scatter) * _IDENTITY - scatter
    block[:3, 3:] = skew(offsets.sum(axis=0))
    block[3:, :3] = -block[:3, 3:]
    block[3:, 3:] = len(offsets) * _IDENTITY
    return block, np.concatenate((cross_rows(offsets, residuals).sum(axis=0), residuals.sum(axis=0)))


def _procrustes_step(state, markers_image, marker_weight):
    """The weighted SVD fit of both kinds of pair (point-to-point), as a motion to apply on the left of T."""
    source = np.vstack((state.moved_markers, state.moved_points))
    target = np.vstack((markers_image, state.matched_points))
    pair_weights = np.concatenate((np.full(len(markers_image), marker_weight), state.surface_weights))
    return rigid_procrustes(source, target, pair_weights)
