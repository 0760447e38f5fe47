"""Where to touch next, and when the registration is good enough: from cr-fused's own uncertainty at the plan.

Beyond the paper, which collects 40 points by hand in 8 sub-areas. After a registration by cr-fused, its pose
covariance ``C`` (F4 of ``core.fused``) predicts the error at the plan's targets (the cut's endpoints, image
coordinates). One more probe touch at a surface point ``y`` with unit normal ``n`` adds one row
``j = [(y - c) x n, n]`` of weight ``1 / s^2`` (``s``: one touch's noise along the normal, F3) to the information,
so by Sherman and Morrison

    C' = C - C j j^T C / (s^2 + j^T C j) ............................................................. (G1)

and the sum of the targets' predicted squared errors, ``trace(G C)`` with ``G = sum_t A_t^T A_t`` over the T targets
(``A_t = [-[y_t - c]_x, I]``), falls by

    gain(y) = (C j)^T G (C j) / (s^2 + j^T C j) ....................................................... (G2)

The **next touch** is the reachable surface point of largest gain: the registration's own uncertainty, projected
onto the planned cut, decides where a touch helps most. Every candidate is scored at once (a few thousand in a
millisecond): the reachable points (by default the whole IPC) are thinned to at most ``MAX_CANDIDATES``, and the
best of them is refined among all reachable points within ``REFINE_RADIUS_MM``. Several touches are planned
greedily, each scored after the ones before it (G1 applied in turn).

**Enough** when every target's predicted error stays below the limit with 95 % confidence: its 95th percentile,
the markers' FLE estimate's own uncertainty included (E2 of ``core.error_prediction``), is below the limit.
"""

from dataclasses import dataclass

import numpy as np

from .small_motion import point_jacobians, surface_rows
from .validation import as_points

#: Candidates scored at once before the best is refined among its neighbours.
MAX_CANDIDATES = 20_000
#: The best thinned candidate is refined among the reachable points this close to it (mm).
REFINE_RADIUS_MM = 5.0
#: Reachable points farther than this from the IPC (mm), or than 5 times its point spacing, are refused: they are
#: not on this bone's surface in image coordinates.
REACHABLE_LIMIT_MM = 2.0
#: Confidence of ``enough``.
CONFIDENCE = 0.95


@dataclass(frozen=True)
class TouchSuggestion:
    """One suggested probe touch: the surface point ``position_image`` (3,) and its unit ``normal_image`` (3,), in
    image coordinates (mm), with the predicted error at the targets once it is touched (F4 after G1):
    ``predicted_tre_mm`` (T,) per target and ``predicted_tre_rms_mm`` their RMS."""

    position_image: np.ndarray
    normal_image: np.ndarray
    predicted_tre_mm: np.ndarray
    predicted_tre_rms_mm: float

    def to_dict(self):
        return {
            "position_image": self.position_image.tolist(),
            "normal_image": self.normal_image.tolist(),
            "predicted_tre_rms_mm": self.predicted_tre_rms_mm,
            "predicted_tre_mm": self.predicted_tre_mm.tolist(),
        }


@dataclass(frozen=True)
class TouchGuidance:
    """The predicted error at the targets now and where to touch next (``touches``, the first is ``next_touch``);
    with a limit, whether it is ``enough``. Distances in mm, image coordinates.

    Attributes:
        targets_image: (T, 3) the plan's targets.
        predicted_tre_mm: (T,) predicted RMS error at each target now (F4); ``predicted_tre_rms_mm`` their RMS.
        predicted_tre_95_mm: (T,) the error each target stays within with 95 % confidence (E2).
        touches: the suggested touches in order (each scored after the ones before it).
        target_tre_mm: the limit asked for, or None; enough: every target's 95 % bound below it (None without).
    """

    targets_image: np.ndarray
    predicted_tre_mm: np.ndarray
    predicted_tre_95_mm: np.ndarray
    touches: tuple
    target_tre_mm: object = None
    enough: object = None

    @property
    def predicted_tre_rms_mm(self):
        return float(np.sqrt(np.mean(self.predicted_tre_mm**2)))

    @property
    def next_touch(self):
        """The first suggested touch (TouchSuggestion)."""
        return self.touches[0]

    def to_dict(self):
        """JSON-ready: ``next_touch`` (``position_image``, ``predicted_tre_rms_mm`` after it, ...), ``enough`` and
        ``target_tre_mm`` when a limit was given, the predictions now and every planned touch."""
        document = {
            "next_touch": self.next_touch.to_dict(),
            "predicted_tre_mm": self.predicted_tre_mm.tolist(),
            "predicted_tre_rms_mm": self.predicted_tre_rms_mm,
            "predicted_tre_95_mm": self.predicted_tre_95_mm.tolist(),
            "planned_touches": [touch.to_dict() for touch in self.touches],
        }
        if self.target_tre_mm is not None:
            document["target_tre_mm"] = self.target_tre_mm
            document["enough"] = self.enough
        return document


def touch_guidance(result, index, targets_image=None, reachable=None, target_tre_mm=None, count=1):
    """Predicted error at the plan's targets, the next touch(es) and, with a limit, whether it is enough.

    Args:
        result: a cr-fused ``RegistrationResult`` (its ``uncertainty``).
        index: the IPC's ``SurfaceIndex`` (image coordinates, mm): the candidates' normals, and the default
            reachable surface.
        targets_image: (T, 3) the plan's targets (its endpoints); default the result's own image targets.
        reachable: (R, 3) image points of the exposed bone surface the probe can reach; default the whole IPC.
        target_tre_mm: the error the plan needs at every target (mm), for ``enough``.
        count: how many touches to plan (greedily), at least 1.

    Raises:
        ValueError: not a cr-fused result, no targets, reachable points off the IPC, a bad limit or count.
    """
    if result.uncertainty is None:
        raise ValueError(
            f"{result.method} gives no pose covariance: the predicted error and the next touch need cr-fused"
        )
    targets = result.targets_image if targets_image is None else targets_image
    if targets is None:
        raise ValueError("the next touch needs the plan's targets in the image (its endpoints): give targets_image")
    targets = as_points(targets, "targets in the image", min_count=1)
    if target_tre_mm is not None and not (np.isfinite(target_tre_mm) and target_tre_mm > 0):
        raise ValueError(f"target TRE {target_tre_mm} mm: give a positive number of mm")
    if int(count) < 1:
        raise ValueError(f"count {count}: plan at least 1 touch")
    candidates = reachable_surface(index, reachable)
    uncertainty = result.uncertainty
    errors = uncertainty.errors_at(targets)
    bounds = errors.quantile_mm(CONFIDENCE)
    touches = []
    for _ in range(int(count)):
        touch = best_touch(uncertainty, targets, index, candidates)
        touches.append(touch)
        uncertainty = uncertainty.with_touches(touch.position_image, touch.normal_image)
    enough = None if target_tre_mm is None else bool(np.all(bounds < target_tre_mm))
    return TouchGuidance(
        targets_image=targets,
        predicted_tre_mm=errors.rms_mm,
        predicted_tre_95_mm=bounds,
        touches=tuple(touches),
        target_tre_mm=None if target_tre_mm is None else float(target_tre_mm),
        enough=enough,
    )


def reachable_surface(index, reachable=None):
    """Candidate touches (R, 3): the reachable image points, checked to lie on the IPC, or the IPC's points.

    Raises:
        ValueError: reachable points farther from the IPC than ``REACHABLE_LIMIT_MM`` (or 5 spacings).
    """
    if reachable is None:
        return index.points
    points = as_points(reachable, "reachable points", min_count=1)
    distances, _ = index.nearest(points)
    limit = max(REACHABLE_LIMIT_MM, 5.0 * index.spacing_mm)
    if distances.max() > limit:
        worst = int(np.argmax(distances))
        raise ValueError(
            f"reachable point {worst} lies {distances[worst]:.1f} mm from the IPC (limit {limit:.1f} mm): give the "
            "exposed bone surface in image coordinates, on the same bone as the IPC"
        )
    return points


def best_touch(uncertainty, targets_image, index, candidates):
    """The TouchSuggestion of largest gain (G2) among (R, 3) candidate image points, each with the IPC's normal
    at its nearest IPC point (computed only for the candidates scored)."""
    gram = target_gram(targets_image, uncertainty.centre_mm)
    step = int(np.ceil(len(candidates) / MAX_CANDIDATES))
    coarse = np.arange(0, len(candidates), step)
    best = coarse[int(np.argmax(touch_gains(uncertainty, gram, index, candidates[coarse])))]
    if step > 1:
        near = np.flatnonzero(np.linalg.norm(candidates - candidates[best], axis=1) <= REFINE_RADIUS_MM)
        best = near[int(np.argmax(touch_gains(uncertainty, gram, index, candidates[near])))]
    normal = _normals(index, candidates[best][None])[0]
    after = uncertainty.with_touches(candidates[best], normal).errors_at(targets_image).rms_mm
    return TouchSuggestion(
        position_image=np.array(candidates[best], dtype=np.float64),
        normal_image=normal,
        predicted_tre_mm=after,
        predicted_tre_rms_mm=float(np.sqrt(np.mean(after**2))),
    )


def touch_gains(uncertainty, gram, index, candidates):
    """(R,) the fall of the targets' summed predicted squared error (mm^2) that a touch at each (R, 3) candidate
    brings (G2); ``gram`` is G (6, 6) of the targets (``target_gram``)."""
    return _gains(uncertainty, gram, candidates, _normals(index, candidates))


def _normals(index, points):
    """(R, 3) the IPC's unit normals at the IPC points nearest to (R, 3) points."""
    return index.normals(index.nearest(points)[1])


def target_gram(targets_image, centre):
    """``G = sum_t A_t^T A_t`` (6, 6) over the (T, 3) targets, rotations about ``centre`` (G2)."""
    jacobians = point_jacobians(np.asarray(targets_image, dtype=np.float64) - centre)
    return np.einsum("tij,tik->jk", jacobians, jacobians)


def _gains(uncertainty, gram, candidates, normals):
    rows = surface_rows(candidates, normals, uncertainty.centre_mm)  # (R, 6)
    spread = rows @ uncertainty.covariance  # (C j)^T, C symmetric
    numerator = np.einsum("ri,ij,rj->r", spread, gram, spread)
    return numerator / (uncertainty.surface_sigma_mm**2 + np.einsum("ri,ri->r", spread, rows))
