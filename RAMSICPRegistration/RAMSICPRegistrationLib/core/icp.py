"""Fine registration: standard point-to-point ICP and the paper's RAMSICP (eqs. 6-9).

Both run the same loop on the CR-aligned patient points ``CR X`` (eq. 5): match every moving point to an IPC
point, solve the rigid fit by SVD, and stop when the RMS objective (eq. 9) changes by less than ``tolerance_mm``.
They differ only in which IPC points a moving point may match:

* ICP: the closest point of the whole IPC.
* RAMSICP: the closest point inside its own matching range ``s_i`` (eq. 6), the IPC points within
  ``k_i = L * D_i`` (eq. 8) of its CR position, where ``D_i`` is its distance to the closest IPC point after CR.

Interpretations of the paper made here (each is tested):

1. The range is inclusive (``|y - CR x_i| <= k_i``; eq. 6 writes ``<``), so that at L = 1 the closest point
   itself is kept and the range is never empty, as eq. 7 requires. L < 1 is rejected for that reason.
2. ``k_i`` is at least ``min_radius_mm`` (default 0.1 mm, a fifth of the paper's 0.5 mm pixel), so that a
   point lying on the IPC after CR (``D_i`` = 0) can still move to its neighbours.
3. The ranges are fixed around the CR positions for the whole run; the moving points travel, the ranges do not.
4. Eq. 9 is a root sum of squares; we report and test the root *mean* square (same minimiser, in mm
   independent of the number of points), and stop when ``|d_h - d_(h-1)| < 1e-5 mm``: the paper's signed
   ``d_(h+1) - d_h < eps`` would stop at once, since ICP's objective decreases.
5. Eq. 10 writes ``T = T_coarse * T_fine``. Our fine transform is an image-space correction ``F`` that maps
   ``CR X`` onto ``Y``, so ``ReferenceToImage = F @ T_coarse``; this equals eq. 10 with the fine transform
   expressed in the reference frame, ``T_coarse^-1 @ F @ T_coarse``.
"""

from dataclasses import dataclass

import numpy as np

from .paired_point import rigid_procrustes
from .transforms import apply_transform

#: Paper: iterations stop when the RMS objective changes by less than 1e-5 mm.
DEFAULT_TOLERANCE_MM = 1e-5
DEFAULT_MAX_ITERATIONS = 200
#: Smallest matching radius k_i (mm), see interpretation 2 in the module docstring.
DEFAULT_MIN_RADIUS_MM = 0.1
#: Largest L accepted: four times the paper's largest. Beyond it RAMSICP is plain ICP in all but memory: the ranges of
#: points a millimetre off the surface already reach 20 mm, and one ball query at L = 10^6 over a 200,000-point IPC
#: takes 1.1 GB (measured).
MAX_SCALE = 20.0
#: The matching ranges keep the IPC points within D_i + this (mm) of a point's CR position (``MatchingRanges``): the
#: best match lies there unless the fine step moves the point over half of it, when it is searched afresh.
STORED_REACH_MM = 20.0
#: Relative slack on the inclusive range test, so that the closest point at exactly D_i stays inside.
_RANGE_SLACK = 1e-9


@dataclass(frozen=True)
class FineResult:
    """Outcome of one ICP or RAMSICP run.

    Attributes:
        fine_transform: (4, 4) image-space correction ``F`` mapping ``CR X`` onto the IPC.
        transform: (4, 4) ``ReferenceToImage = F @ initial`` (eq. 10).
        rms_mm: final value of the RMS objective (eq. 9), mm.
        iterations: number of match-and-fit iterations run.
        converged: False when ``max_iterations`` stopped the run before the RMS settled.
        matched_indices: (N,) IPC index of each point's final correspondence.
        rms_history_mm: the objective after each iteration.
        scale: L for RAMSICP, None for ICP.
    """

    fine_transform: np.ndarray
    transform: np.ndarray
    rms_mm: float
    iterations: int
    converged: bool
    matched_indices: np.ndarray
    rms_history_mm: tuple
    scale: float = None


class MatchingRanges:
    """The matching ranges of eqs. 6-8 for one set of CR-aligned points, for every L up to ``max_scale``.

    One KD-tree ball query serves a whole sweep: the candidates of each point are kept sorted by their distance from
    its CR position, so the range for any smaller L is a prefix of that list. The best match of a moving point ``m``
    lies within ``D_i + 2 |m - CR x_i|`` of its CR position (the closest IPC point to ``CR x_i``, always in range, is
    within ``D_i + |m - CR x_i|`` of ``m``), so only that prefix is searched, and the lists stop at
    ``D_i + STORED_REACH_MM``: a point touched 60 mm off the bone (D_i = 60, k_i = 300 mm at L = 5) keeps the IPC
    points 60-80 mm away, not the whole IPC. A point the fine step moves farther than the stored list reaches is
    searched afresh. The matches are those of the whole range (``Testing/test_icp.py`` checks by brute force).
    """

    def __init__(self, index, cr_points, max_scale, min_radius_mm=DEFAULT_MIN_RADIUS_MM):
        _check_scale(max_scale)
        self.index = index
        self.centres = cr_points
        self.min_radius_mm = float(min_radius_mm)
        self.closest_distance_mm, self.closest_indices = index.nearest(cr_points)  # D_i (eq. 8)
        self._largest = self.radii(max_scale)
        self._stored = np.minimum(self._largest, self.closest_distance_mm + STORED_REACH_MM)
        self._wider, self._wider_radius = {}, {}  # point: its candidates farther than stored (``_search_afresh``)
        neighbour_lists = index.tree.query_ball_point(cr_points, self._stored)
        counts = np.array([len(neighbours) for neighbours in neighbour_lists])
        candidates = np.fromiter((i for n in neighbour_lists for i in n), dtype=np.intp, count=counts.sum())
        owner = np.repeat(np.arange(len(cr_points)), counts)
        distances = np.linalg.norm(index.points[candidates] - cr_points[owner], axis=1)
        order = np.lexsort((distances, owner))
        self._candidates = candidates[order]
        self._distances = distances[order]
        self._owner = owner[order]
        self._counts = counts
        self._starts = np.concatenate(([0], np.cumsum(counts)[:-1]))
        if (counts == 0).any():  # cannot happen: the closest point is always inside the largest ball
            raise RuntimeError("a matching range came out empty; please report this with the input points")
        self.max_scale = float(max_scale)

    def radii(self, scale):
        """``k_i = max(L * D_i, min_radius)`` (eq. 8) with the inclusive slack, (N,) mm."""
        radii = np.maximum(scale * self.closest_distance_mm, self.min_radius_mm)
        return radii * (1.0 + _RANGE_SLACK) + 1e-12

    def counts(self, radii):
        """Number of candidates of each point inside ``radii`` (N,), up to the ``D_i + STORED_REACH_MM`` stored;
        each list is sorted, so this is a prefix."""
        inside = self._distances <= radii[self._owner]
        return np.add.reduceat(inside, self._starts)

    def matcher(self, scale):
        """A function mapping moving points (N, 3) to their matched IPC indices (N,) for this L."""
        _check_scale(scale)
        if scale > self.max_scale * (1.0 + _RANGE_SLACK):
            raise ValueError(f"scale {scale} is above the {self.max_scale} these ranges were built for")
        radii = self.radii(scale)
        points = self.index.points

        def match(moving):
            _, nearest = self.index.nearest(moving)
            inside = np.linalg.norm(points[nearest] - self.centres, axis=1) <= radii
            if inside.all():
                return nearest
            # The globally closest point lies outside this point's range: search its own range instead, as far
            # as the best match can lie (the class docstring).
            outside = np.flatnonzero(~inside)
            shift = np.linalg.norm(moving[outside] - self.centres[outside], axis=1)
            reach = np.minimum(radii[outside], (self.closest_distance_mm[outside] + 2.0 * shift) * (1.0 + 1e-9) + 1e-9)
            nearest = nearest.copy()
            fresh = reach > self._stored[outside]
            for point, radius in zip(outside[fresh], reach[fresh]):
                nearest[point] = self._search_afresh(moving[point], point, radius)
            outside, reach = outside[~fresh], reach[~fresh]
            if not outside.size:
                return nearest
            lengths = np.array(
                [
                    np.searchsorted(self._distances[start : start + count], radius, side="right")
                    for start, count, radius in zip(self._starts[outside], self._counts[outside], reach)
                ]
            )
            owner_local = np.repeat(np.arange(outside.size), lengths)
            first_local = np.concatenate(([0], np.cumsum(lengths)[:-1]))
            flat = np.repeat(self._starts[outside] - first_local, lengths) + np.arange(lengths.sum())
            candidate_ids = self._candidates[flat]
            offsets = points[candidate_ids] - moving[outside][owner_local]
            squared = np.einsum("ij,ij->i", offsets, offsets)
            # The first (closest to the CR position, as the lists are sorted) of each point's nearest candidates;
            # every list holds at least the point's closest IPC point, at D_i.
            smallest = np.minimum.reduceat(squared, first_local)
            at_smallest = np.flatnonzero(squared == smallest[owner_local])
            _, first = np.unique(owner_local[at_smallest], return_index=True)
            nearest[outside] = candidate_ids[at_smallest[first]]
            return nearest

        return match

    def _search_afresh(self, moving_point, point, radius):
        """The IPC point closest to ``moving_point`` (3,) within ``radius`` mm of point ``point``'s CR position,
        from a longer list of its candidates, kept for the next iterations and scales (grown by half as needed)."""
        if self._wider_radius.get(point, 0.0) < radius:
            wider = min(1.5 * radius, self._largest[point])
            ids = np.asarray(self.index.tree.query_ball_point(self.centres[point], wider), dtype=np.intp)
            distances = np.linalg.norm(self.index.points[ids] - self.centres[point], axis=1)
            order = np.argsort(distances, kind="stable")
            ids, distances = ids[order], distances[order]
            self._wider[point] = (ids, distances, np.ascontiguousarray(self.index.points[ids]))
            self._wider_radius[point] = wider
        ids, distances, candidates = self._wider[point]
        count = np.searchsorted(distances, radius, side="right")
        offsets = candidates[:count] - moving_point
        return int(ids[np.argmin(np.einsum("ij,ij->i", offsets, offsets))])


def icp(
    index, moving_points, initial_transform, max_iterations=DEFAULT_MAX_ITERATIONS, tolerance_mm=DEFAULT_TOLERANCE_MM
):
    """Standard point-to-point ICP (Besl and McKay 1992) of patient points onto the whole IPC.

    Args:
        index: SurfaceIndex of the IPC (image coordinates, mm).
        moving_points: (N, 3) patient points X in reference coordinates (mm), validated.
        initial_transform: (4, 4) ReferenceToImage start, e.g. the CR result (CR-ICP).

    Returns:
        FineResult; ``transform`` is the registered ReferenceToImage.
    """
    cr_points = apply_transform(initial_transform, moving_points)

    def match(moving):
        return index.nearest(moving)[1]

    return _iterate(index, cr_points, match, initial_transform, max_iterations, tolerance_mm, scale=None)


def ramsicp(
    index,
    moving_points,
    coarse_transform,
    scale,
    min_radius_mm=DEFAULT_MIN_RADIUS_MM,
    max_iterations=DEFAULT_MAX_ITERATIONS,
    tolerance_mm=DEFAULT_TOLERANCE_MM,
    ranges=None,
):
    """RAMSICP fine registration (eqs. 6-9) after CR, for one scale factor L (eq. 8).

    Args:
        index: SurfaceIndex of the IPC.
        moving_points: (N, 3) patient points X in reference coordinates (mm), validated.
        coarse_transform: (4, 4) CR ReferenceToImage (eq. 5).
        scale: L >= 1.
        ranges: MatchingRanges built for these points and a max_scale >= ``scale`` (a sweep passes one).

    Returns:
        FineResult; ``transform`` = F @ coarse (eq. 10).
    """
    cr_points = apply_transform(coarse_transform, moving_points)
    if ranges is None:
        ranges = MatchingRanges(index, cr_points, scale, min_radius_mm)
    return _iterate(
        index, cr_points, ranges.matcher(scale), coarse_transform, max_iterations, tolerance_mm, scale=float(scale)
    )


def _iterate(index, cr_points, match, initial_transform, max_iterations, tolerance_mm, scale):
    fine = np.eye(4)
    history = []
    converged = False
    for _ in range(max_iterations):
        matched_indices = match(apply_transform(fine, cr_points))
        matched = index.points[matched_indices]
        fine = rigid_procrustes(cr_points, matched)
        residual = apply_transform(fine, cr_points) - matched
        history.append(float(np.sqrt(np.mean(np.sum(residual * residual, axis=1)))))
        if len(history) > 1 and abs(history[-2] - history[-1]) < tolerance_mm:
            converged = True
            break
    return FineResult(
        fine_transform=fine,
        transform=fine @ initial_transform,
        rms_mm=history[-1],
        iterations=len(history),
        converged=converged,
        matched_indices=matched_indices,
        rms_history_mm=tuple(history),
        scale=scale,
    )


def _check_scale(scale):
    if not (np.isfinite(scale) and 1.0 <= scale <= MAX_SCALE):
        raise ValueError(
            f"scale factor L = {scale:g}: give a number from 1 to {MAX_SCALE:g} (below 1 the matching range would "
            "exclude the closest IPC point, eq. 7; far above 5 RAMSICP is plain ICP, --method cr-icp); the paper "
            "sweeps 1 to 5"
        )
