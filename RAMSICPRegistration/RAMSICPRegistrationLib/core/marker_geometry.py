"""Markers paired by their geometry: which measured centre is which marker of a tool.

NDI designs the marker layout of each passive tool so that its inter-marker distances differ (8700339: 50.0, 88.0,
60.0, 55.0, 72.91 and 65.0 mm; on every shipped tool any two differ by 5 mm or more), so the distances between
measured centres say which centre is which marker, whatever order a file lists them in and whatever frame they are
in. The same holds between the image side and the patient side: both are the same rigid layout.

This module finds that pairing (an exhaustive search pruned by the distances, so every consistent pairing is
seen and an ambiguous one is known to be ambiguous), and refuses marker sets that cannot be paired safely:
duplicated or collinear centres, or centres whose distances match no arrangement of the reference within the
tolerance (with the likely cause when the scale is off by a unit: metres, centimetres, inches).
"""

from dataclasses import dataclass
from typing import Optional

import numpy as np

from .paired_point import rigid_procrustes
from .transforms import apply_transform
from .validation import as_points

#: Largest difference (mm) between a measured inter-marker distance and the reference's, and largest residual of a
#: paired marker after the rigid fit, for a pairing to count: a marker centre placed by hand in a CT is off by up
#: to about 1 mm, a tracked one by 0.25 mm, so 2 mm keeps every honest pairing and no shipped tool's other ones.
PAIRING_TOLERANCE_MM = 2.0

#: Two centres closer than this (mm) are the same marker twice: spheres of 11.5 mm cannot be closer than 11.5 mm.
MIN_MARKER_SEPARATION_MM = 5.0

#: No reference body's markers span less than this (mm): NDI's passive tools span 50-135 mm.
MIN_TOOL_SPAN_MM = 30.0

#: Unit mistakes recognised by their scale (measured distances / reference distances), with what to say.
_UNIT_SCALES = ((1e-3, "in metres"), (0.1, "in centimetres"), (1 / 25.4, "in inches"), (1e3, "in micrometres"))


@dataclass(frozen=True)
class GeometricPairing:
    """How measured marker centres pair with a reference layout (a tool's design, or the same markers elsewhere).

    Attributes:
        indices: (K,) for reference marker k, the row of the measured points paired with it; -1 where none is.
        transform: (4, 4) rigid ``ReferenceToMeasured`` fitted to the paired markers.
        fre_mm: RMS distance of the paired measured centres from the fitted reference markers (mm).
        residuals_mm: (K,) that distance per reference marker (NaN where unpaired).
        expected: (K, 3) where each reference marker lies among the measured points under ``transform`` (mm): the
            place to look for a marker that was not found.
        runner_up_fre_mm: FRE of the best other pairing with as many markers that also fits within the tolerance,
            or None when the pairing is unique.
    """

    indices: np.ndarray
    transform: np.ndarray
    fre_mm: float
    residuals_mm: np.ndarray
    expected: np.ndarray
    runner_up_fre_mm: Optional[float] = None

    @property
    def paired(self):
        """(K,) booleans: reference marker k has a measured partner."""
        return self.indices >= 0

    @property
    def count(self):
        return int(self.paired.sum())

    @property
    def ambiguous(self):
        return self.runner_up_fre_mm is not None

    @property
    def in_given_order(self):
        """True when measured row k is reference marker k for every k (nothing was reordered)."""
        return bool(np.array_equal(self.indices, np.arange(len(self.indices))))

    def to_dict(self):
        return {
            "indices": self.indices.tolist(),
            "fre_mm": self.fre_mm,
            "residuals_mm": [None if np.isnan(r) else float(r) for r in self.residuals_mm],
            "expected": self.expected.tolist(),
            "runner_up_fre_mm": self.runner_up_fre_mm,
        }


def check_marker_centres(points, name, min_count=3, min_separation_mm=MIN_MARKER_SEPARATION_MM):
    """Marker centres (N, 3) in mm that can fix a pose: finite, at least ``min_count``, none duplicated, not in a line.

    Raises:
        ValueError: naming ``name``, the markers (numbered from 1) and what to do.
    """
    points = as_points(points, name, min_count=min_count)
    distances = _distances(points)
    span = float(distances.max())
    if span < MIN_TOOL_SPAN_MM:  # the whole layout too small: a unit, not a duplicate
        unit = "in metres" if span < 1.0 else "in centimetres or inches"
        raise ValueError(
            f"{name}: the {len(points)} markers span only {span:.3g} mm, where a reference body's span "
            f"{MIN_TOOL_SPAN_MM:g} mm or more; the centres look to be {unit}, give them in mm"
        )
    np.fill_diagonal(distances, np.inf)
    first, second = np.unravel_index(np.argmin(distances), distances.shape)
    if distances[first, second] < min_separation_mm:
        first, second = sorted((int(first), int(second)))
        raise ValueError(
            f"{name}: markers {first + 1} and {second + 1} are {distances[first, second]:.2f} mm apart, the same "
            f"sphere twice (marker spheres cannot be closer than {min_separation_mm:g} mm); remove the duplicate"
        )
    centred = points - points.mean(axis=0)
    direction = np.linalg.svd(centred)[2][0]
    off_line = np.linalg.norm(centred - np.outer(centred @ direction, direction), axis=1)
    if off_line.max() < PAIRING_TOLERANCE_MM:
        raise ValueError(
            f"{name}: the {len(points)} markers lie within {off_line.max():.2f} mm of one straight line, so they "
            "cannot fix the rotation about it; check that the centres are those of the reference body's spheres"
        )
    return points


def pair_by_geometry(
    points,
    reference,
    tolerance_mm=PAIRING_TOLERANCE_MM,
    min_pairs=3,
    points_name="measured markers",
    reference_name="the tool",
):
    """Pair measured marker centres with a reference layout by their inter-marker distances.

    Every assignment of reference markers to distinct measured points (or to none, while at least ``min_pairs``
    stay paired) whose pairwise distances all agree within ``tolerance_mm`` is fitted rigidly (SVD, no reflection);
    those with every paired residual within ``tolerance_mm`` count. The one pairing the most markers wins, then
    the one with the smallest FRE; another that pairs as many and also counts is reported as the runner-up.

    Args:
        points: (N, 3) measured centres (mm), in any order and any frame; N may exceed the reference's count
            (candidates among which the markers are) or fall short of it (a marker not found).
        reference: (K, 3) the layout to pair with (mm): a tool's marker geometry, or the other side's centres.
        tolerance_mm: see ``PAIRING_TOLERANCE_MM``.
        min_pairs: fewest markers a pairing may have (3 fix a pose).

    Returns:
        GeometricPairing.

    Raises:
        ValueError: no pairing within the tolerance, saying how far off the best one is and, when the scale is off
            by a unit (metres, centimetres, inches), that the file is likely in that unit.
    """
    points = as_points(points, points_name)
    reference = as_points(reference, reference_name, min_count=3)
    count = len(reference)
    min_pairs = min(min_pairs, count)
    if len(points) < min_pairs:
        raise ValueError(
            f"{points_name}: {len(points)} centre(s), at least {min_pairs} of the {count} markers of "
            f"{reference_name} are needed"
        )
    measured, designed = _distances(points), _distances(reference)
    # compatible[k, l][i, j]: measured points i, j may be reference markers k, l.
    compatible = np.abs(measured[None, None] - designed[:, :, None, None]) <= tolerance_mm
    found = []

    def extend(assignment):
        k = len(assignment)
        paired = [(marker, row) for marker, row in enumerate(assignment) if row >= 0]
        if k == count:
            if len(paired) >= min_pairs:
                found.append(_fitted(np.array(assignment), points, reference))
            return
        candidates = np.ones(len(points), dtype=bool)
        for marker, row in paired:
            candidates &= compatible[k, marker][:, row]
        candidates[[row for _, row in paired]] = False
        for row in np.flatnonzero(candidates):
            extend(assignment + [int(row)])
        if count - k - 1 + len(paired) >= min_pairs:  # leave marker k unpaired only while enough can still pair
            extend(assignment + [-1])

    extend([])
    good = [fit for fit in found if np.nanmax(fit.residuals_mm) <= tolerance_mm]
    if not good:
        raise ValueError(_no_pairing_message(points, reference, found, tolerance_mm, points_name, reference_name))
    most = max(fit.count for fit in good)
    ranked = sorted((fit for fit in good if fit.count == most), key=lambda fit: fit.fre_mm)
    best = ranked[0]
    if len(ranked) > 1:
        best = GeometricPairing(**{**best.__dict__, "runner_up_fre_mm": ranked[1].fre_mm})
    return best


def at_pairwise_distances(points, reference, tolerance_mm=PAIRING_TOLERANCE_MM):
    """Sorted indices of the ``points`` (N, 3) mm that lie within ``tolerance_mm`` of one of the pairwise distances
    of the ``reference`` markers (K, 3) mm from another of the points: two of its markers, even where too few are
    seen to pair them (``pair_by_geometry`` needs 3)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    markers = np.asarray(reference, dtype=np.float64)
    distances = np.linalg.norm(markers[:, None] - markers[None], axis=-1)[np.triu_indices(len(markers), 1)]
    found = set()
    for i in range(len(points)):
        for j in range(i + 1, len(points)):
            if np.abs(distances - float(np.linalg.norm(points[i] - points[j]))).min() <= tolerance_mm:
                found.update((i, j))
    return sorted(found)


def unit_hint(points, reference):
    """' (the file looks to be in metres)' and the like when the measured scale is a unit off the reference's,
    else ''. Compares the median inter-marker distance of each set."""
    measured = np.median(_distances(np.asarray(points, dtype=np.float64))[np.triu_indices(len(points), 1)])
    designed = np.median(_distances(np.asarray(reference, dtype=np.float64))[np.triu_indices(len(reference), 1)])
    if not measured > 0 or not designed > 0:
        return ""
    ratio = measured / designed
    for scale, words in _UNIT_SCALES:
        if abs(np.log(ratio / scale)) < np.log(1.25):
            return (
                f"; the distances are {ratio:.3g} times the reference layout's: the centres look to be {words}, give "
                "them in mm"
            )
    return ""


def _fitted(assignment, points, reference):
    paired = assignment >= 0
    transform = rigid_procrustes(reference[paired], points[assignment[paired]])
    expected = apply_transform(transform, reference)
    residuals = np.full(len(reference), np.nan)
    residuals[paired] = np.linalg.norm(expected[paired] - points[assignment[paired]], axis=1)
    fre = float(np.sqrt(np.mean(residuals[paired] ** 2)))
    return GeometricPairing(assignment, transform, fre, residuals, expected)


def _distances(points):
    differences = points[:, None, :] - points[None, :, :]
    return np.sqrt(np.einsum("ijk,ijk->ij", differences, differences))


def _no_pairing_message(points, reference, found, tolerance_mm, points_name, reference_name):
    hint = unit_hint(points, reference) if len(points) >= 2 else ""
    if found:
        closest = min(found, key=lambda fit: np.nanmax(fit.residuals_mm))
        off = f"the closest is off by {np.nanmax(closest.residuals_mm):.1f} mm"
    else:
        off = "no three of their distances match"
    shown = lambda values: ", ".join(f"{value:.1f}" for value in values)  # noqa: E731
    upper = np.triu_indices(len(points), 1)
    return (
        f"{points_name}: the {len(points)} centres match no arrangement of the markers of {reference_name} within "
        f"{tolerance_mm:g} mm ({off}; distances between the centres {shown(_distances(points)[upper])} mm, "
        f"between the markers {shown(_distances(reference)[np.triu_indices(len(reference), 1)])} mm){hint}; check "
        "that the centres are this tool's, in mm, and that none is misplaced"
    )
