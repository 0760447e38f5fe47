"""The other poses a few probe points fit as well: the local minima of cr-fused's F1 within the markers' reach.

F4's covariance describes one minimum of F1 (``core.fused``) and the pose error near it, linearised. F1 is ``-2 log``
of the data's likelihood, and its closest-point matches make it multimodal: 5 or 8 touches on a thin bone's shaft
also fit the shaft turned or slid by a few millimetres, to another place where the surface under them has the same
shape, and markers with an FLE of 2.5 mm cannot tell those poses apart. The true pose then lies in another basin
in a share of registrations that the Gaussian around the chosen minimum puts at almost nothing (measured on the
right fibula with 5 points in one sub-area and an FLE of 2.5 mm: 1 trial in 17 ends 6-11 mm off at the targets
where 0.6-2.6 mm were predicted, and the mean error was 1.21 times the predicted over 1680 trials).

Each minimum ``k`` found from the starts ``core.fused`` restarts from (both ends of each axis of the CR's
uncertainty at 2 standard deviations, then at 4 and 6 while the last ring found a minimum not seen before) holds a
share of the pose's posterior probability, by Laplace's approximation (the same flat prior for every pose)

    w_k  proportional to  exp(-F1_k / 2) sqrt(det C_k) ............................................... (M1)

and if the truth lies in basin ``k`` the chosen pose ``T_0`` errs at an image point ``y`` by
``o_k(y) = T_0 T_k^-1 y - y``. The predicted error's covariance (E1-E3 of ``core.error_prediction``) gains the
modes' second moment about the chosen pose:

    S_modes(y) = sum_k w_k o_k(y) o_k(y)^T ......................................................... (M2)

Each mode is taken with the chosen one's spread and replaced by its second moment (a Gaussian of the mixture's
covariance): exact for the RMS, a little high for the mean when one far mode holds a small share. This changes the
prediction only, never the pose. It is searched for with fewer than ``MIN_POINTS_FOR_SIGMA`` probe points
(``core.fused``): 40 points leave hardly a second basin within the markers' reach (searched on 12 40-point cells
of ``benchmarks/calibrate_predicted_tre.py``, 120 trials each: no ratio moved by more than 0.04), and a few
touches are cheap to refit (12 to 36 fits of 5-11 points), so a registration from 40 points, the demo's, pays
nothing.
"""

import numpy as np

from .fused import (
    DEFAULT_MAX_ITERATIONS,
    FUSED_DEFAULTS,
    MIN_POINTS_FOR_SIGMA,
    RESTART_SPREADS,
    _fit_from,
    _objective,
    _starts,
)
from .icp import DEFAULT_TOLERANCE_MM
from .transforms import invert_transform

#: Two minima within this Mahalanobis distance of each other (under the chosen fit's covariance) are one mode.
SAME_MODE_DISTANCE = 1.0


def searched(fit, point_count):
    """Whether ``register`` searches for other modes of this fit: both kinds of data weighted, and fewer probe
    points than ``MIN_POINTS_FOR_SIGMA``."""
    weights = fit.weights
    return point_count < MIN_POINTS_FOR_SIGMA and weights.marker_weight > 0 and weights.surface_weight > 0


def other_modes(fit, index, ppc, markers_patient, markers_image):
    """The minima of F1 other than ``fit``'s (a ``core.fused.FusedFit``) and their posterior shares (M1).

    Args:
        fit: the chosen FusedFit (its weights are kept for every refit: F1 must be the same function).
        index: SurfaceIndex of the IPC; ppc: (N, 3) probe points (reference, mm); markers_patient,
            markers_image: (K, 3) marker centres in reference and image coordinates (mm).

    Returns:
        (weights (M,), motions (M, 4, 4)): for each other mode ``k`` its share ``w_k`` of the posterior (the chosen
        mode's share is ``1 - sum``) and ``T_0 T_k^-1``, which takes an image point to where the chosen pose puts
        it when the truth is ``T_k`` (M2). Empty when no other mode was found.
    """
    weights = fit.weights
    ppc, markers_patient, markers_image = (np.asarray(a, float) for a in (ppc, markers_patient, markers_image))

    def match(moving):
        return index.nearest(moving)[1]

    data = (index, match, ppc, markers_patient, markers_image, FUSED_DEFAULTS["loss"])
    options = (FUSED_DEFAULTS["solver"], "fixed", DEFAULT_MAX_ITERATIONS, DEFAULT_TOLERANCE_MM)
    information = fit.marker_information + fit.surface_information
    centre = np.asarray(fit.centre_mm, dtype=np.float64)
    modes = [(_objective(fit.transform, weights, data), _log_det(fit.covariance), fit.transform)]
    for spread in RESTART_SPREADS:
        found = len(modes)
        for start in _starts(data, weights, spread):
            candidate = _fit_from(start, weights, data, options)
            log_det = _log_det(candidate.covariance)
            if log_det is None:
                continue
            objective = _objective(candidate.transform, weights, data)
            same = [
                k for k, (_, _, transform) in enumerate(modes)
                if _distance(candidate.transform, transform, centre, information) < SAME_MODE_DISTANCE
            ]  # fmt: skip
            if not same:
                modes.append((objective, log_det, candidate.transform))
            elif same[0] > 0 and objective < modes[same[0]][0]:
                modes[same[0]] = (objective, log_det, candidate.transform)
        if len(modes) == found:  # this ring found no new minimum: one farther out would start still higher up F1
            break
    if len(modes) == 1:
        return np.zeros(0), np.zeros((0, 4, 4))
    objectives = np.array([mode[0] for mode in modes])
    log_dets = np.array([mode[1] for mode in modes])
    log_shares = -0.5 * objectives + 0.5 * log_dets  # M1
    shares = np.exp(log_shares - log_shares.max())
    shares /= shares.sum()
    motions = np.array([fit.transform @ invert_transform(transform) for _, _, transform in modes[1:]])
    return shares[1:], motions


def _log_det(covariance):
    if not np.all(np.isfinite(covariance)):
        return None
    sign, value = np.linalg.slogdet(covariance)
    return float(value) if sign > 0 else None


def _distance(transform, other, centre, information):
    """Mahalanobis distance of the small motion from ``other`` to ``transform`` (rotation vector about ``centre``,
    then the centre's shift) under ``information``."""
    from scipy.spatial.transform import Rotation

    relative = transform @ invert_transform(other)
    shift = relative[:3, :3] @ centre + relative[:3, 3] - centre
    delta = np.concatenate([Rotation.from_matrix(relative[:3, :3]).as_rotvec(), shift])
    return float(np.sqrt(max(delta @ information @ delta, 0.0)))
