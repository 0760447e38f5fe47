"""The whole registration: CR, then optionally ICP or RAMSICP (the paper), point-to-plane ICP, or the fused fit, with
errors and warnings.

``register`` is the one entry point the command line, the Slicer logic and the experiments call.
"""

import logging
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from .coarse_checks import diagnose_far_points, far_touches, marker_fit_alarm, mostly_far
from .constraint import DEFAULT_PROBE_NOISE_MM, analyse_pose_constraint
from .error_prediction import PoseUncertainty
from .fused import (
    FLE_FLOOR_MM,
    RESTART_RATIO,
    FusedWeights,
    fused_fit,
    marker_fle,
    surface_sigma,
)
from .icp import DEFAULT_MIN_RADIUS_MM, icp, ramsicp
from .metrics import fle_from_fre, predicted_tre, surface_residuals, target_errors
from .paired_point import fit_rigid_transform
from .plane_icp import icp_point_to_plane
from .pose_modes import other_modes, searched
from .surface_index import SurfaceIndex
from .sweep import PAPER_SCALES, sweep_scales
from .transforms import apply_transform
from .validation import as_points, check_not_collinear

logger = logging.getLogger(__name__)

METHODS = ("cr", "cr-icp", "cr-icp-plane", "cr-ramsicp", "cr-fused")

#: The method the command line, the demo, the Slicer module and the scenarios use unless told otherwise: the one
#: that measures best without targets (README, "The fused registration"): markers and probe points in one fit.
DEFAULT_METHOD = "cr-fused"

#: How L is chosen from a sweep.
#: ``targets``: the paper's choice, the L of minimum TRE (needs targets: evaluation only).
#: ``fixed``: ``DEFAULT_SCALE`` (or the given one) from the sweep.
#: ``rms-plateau``: target-free, the smallest L whose RMS objective is within ``PLATEAU_TOLERANCE`` of the
#: sweep's lowest: the tightest matching ranges that fit the probe points as well as the widest.
POLICIES = ("targets", "fixed", "rms-plateau")

#: Default L, from the demo phantoms (see README, "Choosing L"): the mean TRE falls with L up to 5 there.
DEFAULT_SCALE = 5.0
PLATEAU_TOLERANCE = 0.005

#: Marker fit (FRE) above which the marker centres are probably misplaced or paired in the wrong order (mm).
MARKER_FRE_LIMIT_MM = 2.0
#: A registered probe point farther than this from the surface (mm) and 3x the median is reported.
OUTLIER_LIMIT_MM = 1.0
#: cr-fused: markers moved off the CR further than their scatter explains at this significance are reported.
DISAGREEMENT_P = 0.01
#: cr-fused: probe points that fit the surface this many times worse than the prior noise are reported.
SURFACE_NOISE_RATIO = 2.0
#: The fine step (ICP, RAMSICP, cr-fused) is doubted when it moves a probe point or a target from where the CR put it
#: further than the CR's own error explains, at this significance: the move over the CR's predicted RMS error there
#: (Fitzpatrick-West-Maurer, ``metrics.predicted_tre``), squared, follows at worst chi-square(1) (all the error in one
#: direction), or F(1, 3K - 6) when the FLE is estimated from the FRE of K markers (``_shift_limit_ratio``).
ALARM_P = 1e-4
#: Moves, and the probe points' median distance to the surface, below this (mm) are never doubted, whatever the
#: marker error.
ALARM_FLOOR_MM = 1.0
#: How cr-fused's own warnings begin (for counting them).
FUSED_WARNINGS = (
    "The markers and the probe points disagree",
    "The probe points fit the surface worse",
    "cr-fused stopped",
    "cr-fused started again",
)


@dataclass(frozen=True)
class RegistrationResult:
    """A registration and everything measured about it. Distances in mm, transforms (4, 4).

    ``reference_to_image`` is the paper's ^P_I T (eq. 10); ``coarse_reference_to_image`` the CR alone (eq. 5).
    ``residuals_mm`` (N,) are the distances of every given probe point to the IPC after registration, ``ppc_rms_mm``
    their RMS over the points the fit used. ``far_points`` (0-based) lay far from the IPC after the CR
    (``core.coarse_checks``; ``coarse_distances_mm`` (N,) are those distances); ``left_out`` are those the fine step
    did not use (all far points but the ones given in ``include_far``). In ``to_dict`` both count from 1.
    ``tre_mm`` (eq. 11) and ``target_errors_mm`` need targets in both frames; ``predicted_cr_tre_mm`` is the
    Fitzpatrick-West-Maurer expectation of the CR's TRE at each target for the FLE in ``fle_mm`` (image targets are
    enough for it, and for the predicted errors below). ``targets_image`` are the image targets given, if any.

    ``alarms`` are the checks the result failed, in words (they lead ``warnings`` too): the fine step moved the probe
    points or targets from the CR far more than the marker error explains (``fine_shift_mm`` is its largest move),
    or the probe points end far from the surface. A result with alarms should not be used before it has been
    looked at.

    cr-fused also gives ``fused_weights`` (the FLE and surface noise behind its weights, ``core.fused.FusedWeights``),
    ``pose_covariance`` (6, 6: small rotation in rad about ``covariance_centre_mm``, then translation in mm, image
    coordinates) and, with targets, ``predicted_tre_mm``, the registration error that covariance predicts at each
    target (eq. F4 of ``core.fused``); ``predicted_error_mm`` gives it at any image point, e.g. along a planned cut.
    ``uncertainty`` (``core.error_prediction.PoseUncertainty``) holds the covariance's parts: the predicted error's
    mean and percentiles (``predicted_tre_mean_mm``, ``predicted_tre_95_mm``, with the FLE estimate's own
    uncertainty) and the effect of another touch (``core.touch_guidance``).
    """

    method: str
    reference_to_image: np.ndarray
    coarse_reference_to_image: np.ndarray
    fre_mm: float
    marker_residuals_mm: np.ndarray
    ppc_rms_mm: float
    residuals_mm: np.ndarray
    tre_mm: float = None
    target_errors_mm: np.ndarray = None
    predicted_cr_tre_mm: np.ndarray = None
    fle_mm: float = None
    scale: float = None
    scale_policy: str = None
    iterations: int = None
    converged: bool = None
    sweep: tuple = ()
    warnings: tuple = ()
    fused_weights: object = None
    pose_covariance: np.ndarray = None
    covariance_centre_mm: np.ndarray = None
    predicted_tre_mm: np.ndarray = None
    alarms: tuple = ()
    fine_shift_mm: float = None
    targets_image: np.ndarray = None
    uncertainty: object = None

    @property
    def predicted_tre_mean_mm(self):
        """(T,) the mean error length cr-fused predicts at each target (E1 of ``core.error_prediction``), or None;
        the figure to compare with the mean of measured target errors (the RMS is larger: 1.09 times for an
        isotropic error)."""
        if self.uncertainty is None or self.targets_image is None:
            return None
        return self.uncertainty.errors_at(self.targets_image).mean_mm

    @property
    def predicted_tre_95_mm(self):
        """(T,) the error cr-fused predicts each target stays within with 95 % confidence, the markers' FLE
        estimate's own uncertainty included (E2 of ``core.error_prediction``), or None."""
        if self.uncertainty is None or self.targets_image is None:
            return None
        return self.uncertainty.errors_at(self.targets_image).quantile_mm(0.95)

    far_points: tuple = ()
    left_out: tuple = ()
    coarse_distances_mm: np.ndarray = None

    @property
    def predicted_tre_rms_mm(self):
        """RMS over the targets of ``predicted_tre_mm`` (mm), the figure to compare with ``tre_mm``; or None."""
        if self.predicted_tre_mm is None:
            return None
        return float(np.sqrt(np.mean(np.square(self.predicted_tre_mm))))

    def predicted_error_mm(self, points_image):
        """Predicted RMS registration error (mm) at each (T, 3) image point from the fused covariance (cr-fused;
        ``core.error_prediction``)."""
        if self.uncertainty is None:
            raise ValueError(f"{self.method} gives no pose covariance; the predicted error needs cr-fused")
        return self.uncertainty.errors_at(points_image).rms_mm

    def to_dict(self):
        """JSON-ready dictionary with every figure of the result."""

        def listed(value):
            return None if value is None else np.asarray(value).tolist()

        return {
            "method": self.method,
            "reference_to_image": listed(self.reference_to_image),
            "coarse_reference_to_image": listed(self.coarse_reference_to_image),
            "fre_mm": self.fre_mm,
            "marker_residuals_mm": listed(self.marker_residuals_mm),
            "ppc_rms_mm": self.ppc_rms_mm,
            "residuals_mm": listed(self.residuals_mm),
            "tre_mm": self.tre_mm,
            "target_errors_mm": listed(self.target_errors_mm),
            "predicted_cr_tre_mm": listed(self.predicted_cr_tre_mm),
            "fle_mm": self.fle_mm,
            "scale": self.scale,
            "scale_policy": self.scale_policy,
            "iterations": self.iterations,
            "converged": self.converged,
            "sweep": [entry.to_dict() for entry in self.sweep],
            "warnings": list(self.warnings),
            "fused_weights": None if self.fused_weights is None else self.fused_weights.to_dict(),
            "pose_covariance": listed(self.pose_covariance),
            "covariance_centre_mm": listed(self.covariance_centre_mm),
            "predicted_tre_mm": listed(self.predicted_tre_mm),
            "predicted_tre_rms_mm": self.predicted_tre_rms_mm,
            "predicted_tre_mean_mm": listed(self.predicted_tre_mean_mm),
            "predicted_tre_95_mm": listed(self.predicted_tre_95_mm),
            "targets_image": listed(self.targets_image),
            "alarms": list(self.alarms),
            "fine_shift_mm": self.fine_shift_mm,
            "far_points": [index + 1 for index in self.far_points],
            "left_out": [index + 1 for index in self.left_out],
            "coarse_distances_mm": listed(self.coarse_distances_mm),
        }


def register(
    ipc,
    ppc,
    markers_image,
    markers_patient,
    targets_image=None,
    targets_patient=None,
    method=DEFAULT_METHOD,
    scale=None,
    sweep=False,
    scales=PAPER_SCALES,
    policy=None,
    fle_mm=None,
    min_radius_mm=DEFAULT_MIN_RADIUS_MM,
    probe_noise_mm=DEFAULT_PROBE_NOISE_MM,
    include_far=(),
):
    """Register the patient (reference frame) to the image: CR, CR-ICP (point to point or to plane), CR-RAMSICP or
    the fused fit (cr-fused).

    Args:
        ipc: SurfaceIndex, or (M, 3) IPC points in image coordinates (mm).
        ppc: (N, 3) probe points in reference coordinates (mm), N >= 3, not collinear.
        markers_image: (K, 3) marker-sphere centres in the image (mm), K >= 3.
        markers_patient: (K, 3) the same centres in reference coordinates, same order.
        targets_image, targets_patient: optional (T, 3) targets for the TRE (eq. 11); the image targets alone (the
            plan's endpoints) give the predicted error there, without a measured TRE.
        method: 'cr', 'cr-icp' (the paper's point-to-point ICP), 'cr-icp-plane' (point-to-plane ICP,
            ``core.plane_icp``), 'cr-ramsicp' or 'cr-fused' (default ``DEFAULT_METHOD``).
        scale: L for a single RAMSICP run (default ``DEFAULT_SCALE``); with ``sweep`` it is the 'fixed' L.
        sweep: run RAMSICP for every L in ``scales`` and choose one by ``policy``.
        policy: one of POLICIES; default 'targets' when targets are given, else 'rms-plateau'.
        fle_mm: marker localisation error (RMS 3-D, mm) for the predicted TRE and cr-fused's marker weights;
            estimated from the FRE when None.
        probe_noise_mm: RMS 3-D probe-tip error (mm) behind cr-fused's surface weights.
        include_far: 0-based probe points to use although they lie far from the IPC after the CR (the others that
            do are left out of the fine step: ``core.coarse_checks.far_touches``).

    Raises:
        ValueError: bad points (see ``fit_rigid_transform``), an IPC too coarse to be the surface under the probe
            points (``SurfaceIndex.check_covers``), unknown method or policy, a policy that needs targets without
            them, sweep or scale with a method other than cr-ramsicp.
    """
    if method not in METHODS:
        raise ValueError(f"method {method!r}: use one of {', '.join(METHODS)}")
    for value, name in ((fle_mm, "marker error (FLE)"), (probe_noise_mm, "probe noise")):
        if value is not None and not (np.isfinite(value) and value > 0):
            raise ValueError(f"{name} {value} mm: give a positive number of mm")
    if method != "cr-ramsicp" and (sweep or scale is not None or policy is not None):
        raise ValueError(f"scale, sweep and policy apply to cr-ramsicp only, not to {method}")
    index = ipc if isinstance(ipc, SurfaceIndex) else SurfaceIndex(ipc)
    ppc = as_points(ppc, "PPC (probe points)", min_count=3)
    check_not_collinear(ppc, "PPC (probe points)")
    targets_patient, targets_image = _check_targets(targets_patient, targets_image)
    coarse = fit_rigid_transform(
        markers_patient,
        markers_image,
        source_name="markers in the patient (reference)",
        target_name="markers in the image",
    )
    # A marker fit beyond the pairing tolerance is an alarm: the CR, and every limit scaled by its FRE, is off.
    marker_warnings = _marker_warnings(coarse, np.asarray(markers_patient, float), np.asarray(markers_image, float))
    warnings = []
    fle = fle_mm if fle_mm is not None else fle_from_fre(coarse.fre_mm, len(coarse.residuals_mm))
    markers_patient, markers_image = np.asarray(markers_patient, float), np.asarray(markers_image, float)
    touches = far_touches(index, ppc, coarse.transform, markers_image, fle, probe_noise_mm)
    coarse_alarms = ()
    if mostly_far(touches):  # not outliers: a mistake in the inputs, refused when a unit or frame explains it
        message, explained = diagnose_far_points(index, ppc, markers_patient, markers_image, touches, coarse.fre_mm)
        if explained:
            raise ValueError(message)
        index.check_covers(ppc)  # an IPC too sparse to be a surface says so first
        coarse_alarms, left_out = (message,), ()
    else:
        left_out = tuple(i for i in touches.indices if i not in set(int(k) for k in include_far))
    ppc_all, ppc = ppc, np.delete(ppc, left_out, axis=0)
    if left_out:
        warnings.append(
            f"{len(left_out)} probe point(s) lie far from the bone after the coarse registration and were left out "
            f"of the fit: {touches.describe(left_out)} (numbered from 1). Touched in the air or off the bone? "
            "Include one by hand only if it was touched on the bone."
        )
    if len(ppc) < 3:
        raise ValueError(
            f"only {len(ppc)} probe points lie on the bone after the coarse registration (far: "
            f"{touches.describe(touches.indices)}); collect more points on the bone"
        )
    check_not_collinear(ppc, "PPC (probe points near the bone)")
    index.check_covers(ppc)

    transform, fine, entries, chosen_policy, fused = coarse.transform, None, (), None, None
    if method == "cr-fused":
        fused = _fused(index, ppc, coarse, markers_patient, markers_image, fle_mm, probe_noise_mm)
        fine = fused
        warnings += _fused_warnings(fused, coarse, np.asarray(markers_patient, float), np.asarray(markers_image, float))
    elif method == "cr-icp":
        fine = icp(index, ppc, coarse.transform)
    elif method == "cr-icp-plane":
        fine = icp_point_to_plane(index, ppc, coarse.transform)
    elif method == "cr-ramsicp":
        if sweep:
            chosen_policy = policy or ("targets" if targets_patient is not None else "rms-plateau")
            entries = sweep_scales(
                index, ppc, coarse.transform, scales, targets_patient, targets_image, min_radius_mm=min_radius_mm
            )
            chosen = entries[select_scale(entries, chosen_policy, DEFAULT_SCALE if scale is None else scale)]
            fine = chosen.result
            warnings += _sweep_warnings(entries, chosen, chosen_policy)
        else:
            if policy not in (None, "fixed"):
                raise ValueError(f"policy {policy!r} chooses L from a sweep; ask for the sweep, or give a scale")
            chosen_policy = "fixed"
            fine = ramsicp(
                index,
                ppc,
                coarse.transform,
                DEFAULT_SCALE if scale is None else float(scale),
                min_radius_mm=min_radius_mm,
            )
    if fine is not None:
        transform = fine.transform
        if not fine.converged:
            warnings.append(
                f"{method} stopped after {fine.iterations} iterations before it settled (its last step still moved "
                "the points by over 1e-5 mm); the result may still move: check the CR and the probe points"
            )

    residuals = surface_residuals(index, transform, ppc)
    warnings += _outlier_warnings(residuals, np.delete(np.arange(len(ppc_all)), left_out))
    registered = apply_transform(transform, ppc)
    _, matches = index.nearest(registered)
    report = analyse_pose_constraint(registered, index.normals(matches), probe_noise_mm, long_axis=index.long_axis)
    if report.warning:
        held = " cr-fused holds that motion with the markers; see its predicted TRE." if fused is not None else ""
        warnings.append(report.warning + held)

    shift, alarms = _alarms(
        method,
        coarse.transform,
        None if fine is None else transform,
        ppc,
        targets_patient,
        np.asarray(markers_image, float),
        (fle, fle_mm is not None),
        residuals,
        index,
        probe_noise_mm,
        np.delete(np.arange(len(ppc_all)), left_out),
    )
    fit_alarm = marker_fit_alarm(coarse.fre_mm, len(coarse.residuals_mm), fle_mm, ALARM_P)
    alarms = coarse_alarms + alarms + ((fit_alarm,) if fit_alarm else ()) + tuple(marker_warnings)
    warnings = list(alarms) + warnings
    tre = errors = predicted = predicted_fused = uncertainty = None
    if fused is not None:
        fre_fle = fle_from_fre(coarse.fre_mm, len(coarse.residuals_mm))
        uncertainty = PoseUncertainty.from_fit(fused, None if fle_mm is not None else len(coarse.residuals_mm), fre_fle)
        if searched(fused, len(ppc)):  # a few touches may fit elsewhere as well: the prediction counts those poses
            shares, motions = other_modes(fused, index, ppc, markers_patient, markers_image)
            uncertainty = replace(uncertainty, mode_weights=shares, mode_motions=motions)
    if targets_patient is not None:
        errors = target_errors(transform, targets_patient, targets_image)
        tre = float(np.sqrt(np.mean(errors**2)))
    if targets_image is not None:
        predicted = predicted_tre(np.asarray(markers_image, float), targets_image, fle)
        if fused is not None:
            predicted_fused = uncertainty.errors_at(targets_image).rms_mm
    for warning in warnings:
        logger.info("registration warning: %s", warning)
    return RegistrationResult(
        method=method,
        reference_to_image=transform,
        coarse_reference_to_image=coarse.transform,
        fre_mm=coarse.fre_mm,
        marker_residuals_mm=coarse.residuals_mm,
        ppc_rms_mm=float(np.sqrt(np.mean(residuals**2))),
        residuals_mm=surface_residuals(index, transform, ppc_all) if left_out else residuals,
        tre_mm=tre,
        target_errors_mm=errors,
        predicted_cr_tre_mm=predicted,
        fle_mm=float(fle),
        scale=None if fine is None or fused is not None else fine.scale,
        scale_policy=chosen_policy,
        iterations=None if fine is None else fine.iterations,
        converged=None if fine is None else fine.converged,
        sweep=entries,
        warnings=tuple(warnings),
        fused_weights=None if fused is None else fused.weights,
        pose_covariance=None if fused is None else fused.covariance,
        covariance_centre_mm=None if fused is None else fused.centre_mm,
        predicted_tre_mm=predicted_fused,
        alarms=alarms,
        fine_shift_mm=shift,
        targets_image=targets_image,
        uncertainty=uncertainty,
        far_points=touches.indices,
        left_out=left_out,
        coarse_distances_mm=touches.distances_mm,
    )


def _alarms(
    method, coarse, fine, ppc, targets_patient, markers_image, marker_error, residuals, index, noise_mm, numbers
):
    """The checks a result must pass to be used: (the fine step's largest move from the CR in mm or None, alarms).

    The fine step (``fine``, None for the CR alone) must not move a probe point or target from where the CR put it by
    more than ``_shift_limit_ratio`` times the CR's predicted error there (nor less than ``ALARM_FLOOR_MM``). Half
    the probe points (the median distance) must end within ``RESTART_RATIO`` times the surface noise that the probe
    noise and the IPC's spacing explain (F3 of ``core.fused``) of the IPC; after the CR alone, within that plus the
    CR's predicted error (the same ratio times its median over the probe points); never less than
    ``ALARM_FLOOR_MM``.
    ``marker_error`` is (FLE in mm, whether it was given rather than estimated from the FRE); ``numbers`` (0-based)
    are the probe points' rows in the input (some may have been left out).
    """
    fle, fle_given = marker_error
    points = ppc if targets_patient is None else np.vstack((ppc, targets_patient))
    at_cr = apply_transform(coarse, points)
    expected = predicted_tre(markers_image, at_cr, fle)
    ratio = _shift_limit_ratio(len(markers_image), fle_given)
    alarms, largest = [], None
    if fine is not None:
        moves = np.linalg.norm(apply_transform(fine, points) - at_cr, axis=1)
        limits = np.maximum(ratio * expected, ALARM_FLOOR_MM)
        largest, worst = float(moves.max()), int(np.argmax(moves / limits))
        if moves[worst] > limits[worst]:
            which = f"probe point {numbers[worst] + 1}" if worst < len(ppc) else f"target {worst - len(ppc) + 1}"
            alarms.append(
                f"{method} moved {which} {moves[worst]:.1f} mm from where the CR put it, more than the marker error "
                f"can explain (the CR's predicted error there is {expected[worst]:.2f} mm RMS for FLE {fle:.2f} mm; "
                f"limit {limits[worst]:.1f} mm, p < {ALARM_P:g}): the probe points and the markers disagree. Either "
                "the fine step slid to another fit of the probe points to the IPC (an IPC that is not this bone's "
                "surface, probe points not touched on it) or the marker centres are further off than their spread "
                "shows; check both before using this result."
            )
    typical = float(np.median(residuals))  # the median: one point touched off the bone is an outlier warning
    limit = RESTART_RATIO * surface_sigma(noise_mm, index.spacing_mm)
    if fine is None:
        limit += ratio * float(np.median(expected[: len(ppc)]))
    limit = max(limit, ALARM_FLOOR_MM)
    if typical > limit:
        explained = "the probe noise and the IPC's point spacing" + (" and the CR's error" if fine is None else "")
        alarms.append(
            f"After {method} half the probe points lie more than {typical:.1f} mm from the IPC, far more than "
            f"{explained} explain (limit {limit:.1f} mm): the registration has not found the bone's surface. Do not "
            "use this result: check that the IPC is this bone's surface and the probe points were touched on it."
        )
    return largest, tuple(alarms)


@lru_cache(maxsize=None)
def _shift_limit_ratio(marker_count, fle_given):
    """How many times the CR's predicted RMS error a fine step may move a point before it is doubted (``ALARM_P``)."""
    from scipy import stats  # here, not at the top: the command line's --help must not wait for scipy.stats

    if fle_given:
        return float(np.sqrt(stats.chi2.ppf(1.0 - ALARM_P, 1)))
    return float(np.sqrt(stats.f.ppf(1.0 - ALARM_P, 1, 3 * marker_count - 6)))


def _fused(index, ppc, coarse, markers_patient, markers_image, fle_mm, probe_noise_mm):
    """cr-fused (``core.fused``) from the CR, with weights from this registration's own data (F2, F3)."""
    if fle_mm is None:
        fle, fle_source = marker_fle(coarse.fre_mm, len(coarse.residuals_mm))
    else:
        fle, fle_source = float(fle_mm), "given"
    spacing = index.spacing_mm
    weights = FusedWeights(fle, surface_sigma(probe_noise_mm, spacing), fle_source, "prior", probe_noise_mm, spacing)
    return fused_fit(
        index,
        ppc,
        np.asarray(markers_patient, float),
        np.asarray(markers_image, float),
        coarse.transform,
        weights,
    )


def _fused_warnings(fused, coarse, markers_patient, markers_image):
    """Plain-words warnings when the markers and the probe points of a fused fit do not agree within their noise.

    The markers: the fused pose may move them off the CR only as far as their noise allows. With ``S`` the sum of
    squared marker residuals, ``(S_fused - S_cr) / p`` over ``S_cr / (3K - 6)`` follows an F distribution with
    ``p`` (the pose parameters the probe points fix) and ``3K - 6`` degrees of freedom; the CR's own residuals
    count for at least the FLE floor's.
    """
    from scipy import stats  # here, not at the top: the command line's --help must not wait for scipy.stats

    warnings = []
    weights = fused.weights
    count = len(markers_patient)
    moved = np.linalg.norm(apply_transform(fused.transform, markers_patient) - markers_image, axis=1)
    cr_sum = max(float(np.sum(coarse.residuals_mm**2)), (3 * count - 6) * FLE_FLOOR_MM**2 / 3.0)
    extra = max(fused.surface_dof, 0.5)
    ratio = (float(np.sum(moved**2)) - cr_sum) / extra / (cr_sum / (3 * count - 6))
    if ratio > stats.f.ppf(1.0 - DISAGREEMENT_P, extra, 3 * count - 6):
        worst = int(np.argmax(moved))
        warnings.append(
            f"The markers and the probe points disagree: the fused pose puts marker {worst + 1} {moved[worst]:.2f} mm "
            f"from its image position, more than the markers' own scatter (FRE {coarse.fre_mm:.2f} mm) explains "
            f"(p < {DISAGREEMENT_P:g}). Check that marker's centre, the probe points and the IPC; a probe point "
            "matched to the wrong wall of a thin bone does this."
        )
    if fused.chosen_start > 0:
        warnings.append(
            f"cr-fused started again: its first fit ended with the probe points more than {RESTART_RATIO:g} times "
            "their noise from the surface, or fit its data worse than their noise allows, and of "
            f"{fused.starts - 1} poses around the CR another one led to a better fit, which was kept. Check the CR "
            "(marker order and centres) and that the probe points were touched on this bone."
        )
    prior = surface_sigma(weights.probe_noise_mm, weights.ipc_spacing_mm)
    if weights.surface_sigma_mm > SURFACE_NOISE_RATIO * prior:
        warnings.append(
            f"The probe points fit the surface worse than the probe noise allows ({weights.surface_sigma_mm:.2f} mm "
            f"RMS against {prior:.2f} mm expected); cr-fused has weighted them down. Look for points not touched on "
            "bone, or an IPC that is not this bone's surface."
        )
    return warnings


def select_scale(entries, policy, fixed_scale=DEFAULT_SCALE):
    """Index of the chosen entry of a sweep (a tuple of SweepEntry) under ``policy`` (see POLICIES)."""
    if policy == "targets":
        if entries[0].tre_mm is None:
            raise ValueError(
                "policy 'targets' picks the L of minimum TRE and needs target points; "
                "give targets or use 'rms-plateau' or 'fixed'"
            )
        return int(np.argmin([entry.tre_mm for entry in entries]))
    if policy == "fixed":
        return int(np.argmin([abs(entry.scale - fixed_scale) for entry in entries]))
    if policy == "rms-plateau":
        rms = np.array([entry.result.rms_mm for entry in entries])
        return int(np.flatnonzero(rms <= rms.min() * (1.0 + PLATEAU_TOLERANCE))[0])
    raise ValueError(f"policy {policy!r}: use one of {', '.join(POLICIES)}")


def _check_targets(targets_patient, targets_image):
    if targets_patient is not None and targets_image is None:
        raise ValueError(
            "targets: patient targets need the same targets in the image (the plan's endpoints); give the image "
            "targets too, or only them for the predicted error"
        )
    if targets_image is None:
        return None, None
    targets_image = as_points(targets_image, "targets in the image", min_count=1)
    if targets_patient is None:
        return None, targets_image
    targets_patient = as_points(targets_patient, "targets in the patient (reference)", min_count=1)
    if targets_patient.shape != targets_image.shape:
        raise ValueError(
            f"targets: {len(targets_patient)} in the patient but {len(targets_image)} in the image; "
            "give the same targets in the same order"
        )
    return targets_patient, targets_image


def _marker_warnings(coarse, markers_patient, markers_image):
    if coarse.fre_mm <= MARKER_FRE_LIMIT_MM:
        return []
    worst = int(np.argmax(coarse.residuals_mm))
    spacing_patient = np.linalg.norm(markers_patient[:, None] - markers_patient[None], axis=2)
    spacing_image = np.linalg.norm(markers_image[:, None] - markers_image[None], axis=2)
    mismatch = np.abs(spacing_patient - spacing_image).max()
    return [
        f"Marker fit is poor: FRE {coarse.fre_mm:.2f} mm (marker {worst + 1} is off by "
        f"{coarse.residuals_mm[worst]:.2f} mm; inter-marker distances differ by up to {mismatch:.1f} mm). "
        "Check that the image markers are in the same order as the tool's and centred on the spheres "
        "(io.marker_files.pair_marker_sets pairs them by their distances)."
    ]


def _outlier_warnings(residuals, numbers):
    """Probe points far from the surface after registration; ``numbers`` (0-based) are their rows in the input."""
    limit = max(OUTLIER_LIMIT_MM, 3.0 * float(np.median(residuals)))
    far = np.flatnonzero(residuals > limit)
    if not far.size:
        return []
    listed = ", ".join(f"{numbers[i] + 1} ({residuals[i]:.2f} mm)" for i in far[:10])
    return [
        f"{far.size} probe point(s) lie far from the bone surface after registration (numbered from 1): {listed}. "
        "Exclude them if they were not touched on bone, and register again."
    ]


def _sweep_warnings(entries, chosen, policy):
    warnings = []
    if policy == "targets":
        warnings.append(
            "L was chosen by the minimum TRE over the sweep (the paper's choice): that uses the target "
            "points and is for evaluation; in surgery use the 'fixed' or 'rms-plateau' policy"
        )
    if chosen.scale == entries[-1].scale and len(entries) > 1 and policy != "fixed":
        warnings.append(
            f"the chosen L = {chosen.scale:g} is the largest of the sweep; the result is close to plain ICP"
        )
    return warnings
