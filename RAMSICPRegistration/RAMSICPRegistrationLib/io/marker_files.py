"""Marker-centre files that carry each marker's number and status, from ``ramsicp ipc`` to ``ramsicp register``.

A markers file is an ordinary point file (markups JSON, fcsv, csv, ...) whose labels read ``M<n> <status>``:
``n`` is the reference body's marker number (1-based, in the order of the NDI tool's markers) and ``status``
is how the sphere looked in the CT: ``ok``, ``partial`` or ``deformed`` (``image.marker_spheres``). The labels
show in Slicer's markups table, so the status travels with the points wherever the file goes. A point the
program could not pair with a tool marker is labelled ``M? <status>``. Files without such labels (centres placed
by hand, the tool geometry) have neither: their points pair row by row and count as usable.
"""

import re
from dataclasses import dataclass, replace

import numpy as np

from ..core.marker_geometry import PAIRING_TOLERANCE_MM, check_marker_centres, pair_by_geometry, unit_hint
from ..core.paired_point import rigid_procrustes
from ..core.transforms import apply_transform
from .point_files import read_points, write_points

STATUSES = ("ok", "partial", "deformed")
#: Point files that keep a label per point, so the numbers and statuses survive.
LABELLED_SUFFIXES = (".mrk.json", ".json", ".fcsv")
#: Statuses whose centre may be off: the coarse registration must not use them without the user's word.
FLAGGED = ("partial", "deformed")
_LABEL = re.compile(r"^\s*M(\d+|\?)(?=\s|$)\s*(\w*)")


@dataclass(frozen=True)
class MarkerSet:
    """Marker centres (K, 3) RAS mm with, per point, the marker number (int, or None) and status (str, or None)."""

    points: np.ndarray
    numbers: tuple
    statuses: tuple
    path: str = ""
    stated_space: str = None  # the frame the file stated, or None

    @property
    def numbered(self):
        """True when every point carries a marker number."""
        return len(self.numbers) > 0 and all(number is not None for number in self.numbers)

    def flagged(self):
        """[(number or 1-based row, status)] of the points whose status is partial or deformed."""
        return [
            (number if number is not None else row + 1, status)
            for row, (number, status) in enumerate(zip(self.numbers, self.statuses))
            if status in FLAGGED
        ]


def marker_label(number, status):
    """The label of a marker: ``M<n> <status>``, or ``M? <status>`` when ``number`` is 0 or None."""
    return f"M{number if number else '?'} {status}".strip()


def write_markers(path, centres, numbers, statuses):
    """Write marker centres (K, 3) RAS with their numbers (1-based; 0 = not paired) and statuses as labels.

    Raises:
        ValueError: a file type without labels (csv, txt, npy would lose the numbers and statuses).
    """
    check_markers_path(path)
    labels = [marker_label(number, status) for number, status in zip(numbers, statuses)]
    write_points(path, np.asarray(centres, dtype=np.float64).reshape(-1, 3), labels=labels)


def check_markers_path(path):
    """Raise ValueError unless ``path`` is a point file that keeps labels (LABELLED_SUFFIXES)."""
    if not any(str(path).lower().endswith(suffix) for suffix in LABELLED_SUFFIXES):
        raise ValueError(
            f"{path}: marker centres go in a file that keeps each marker's number and status: "
            f"use {' or '.join(LABELLED_SUFFIXES[::2])}"
        )


def read_markers(path, untagged_space="RAS"):
    """Read a markers file (any point file); numbers and statuses come from ``M<n> <status>`` labels."""
    point_set = read_points(path, untagged_space)
    markers = labelled_markers(point_set.points, point_set.labels, str(path))
    return replace(markers, stated_space=point_set.stated_space)


def labelled_markers(points, labels, source=""):
    """A MarkerSet of (K, 3) points whose numbers and statuses come from their ``M<n> <status>`` labels (a file's
    points, or a markups node's control points); ``source`` names them in messages."""
    numbers, statuses = [], []
    for label in labels:
        match = _LABEL.match(label or "")
        number = int(match.group(1)) if match and match.group(1) != "?" else None
        status = match.group(2).lower() if match and match.group(2).lower() in STATUSES else None
        numbers.append(number)
        statuses.append(status)
    return MarkerSet(points=np.asarray(points), numbers=tuple(numbers), statuses=tuple(statuses), path=source)


def pair_markers(image, patient):
    """Pair image-side markers with patient-side ones: by number when the image file numbers its markers, else
    row by row.

    With numbers, marker ``n`` of the image pairs with the patient point numbered ``n``, or with row ``n`` when
    the patient file has no numbers (the tool geometry in the tool's order). So a flagged marker deleted from
    the image file leaves the other three correctly paired.

    Returns:
        (image_points (K, 3), patient_points (K, 3), numbers (K,) or None).

    Raises:
        ValueError: a number that the patient file does not have, one used twice, or a point without a number.
    """
    if not image.numbered:
        if any(number is not None for number in image.numbers):
            raise ValueError(f"{image.path}: some markers are numbered (M1, M2, ...) and some not; number them all")
        return image.points, patient.points, None
    numbers = list(image.numbers)
    repeated = sorted({n for n in numbers if numbers.count(n) > 1})
    if repeated:
        raise ValueError(f"{image.path}: marker {repeated[0]} appears more than once; keep one centre per marker")
    if patient.numbered:
        rows = {number: row for row, number in enumerate(patient.numbers)}
        missing = [n for n in numbers if n not in rows]
        where = f"{patient.path} has markers {', '.join(str(n) for n in sorted(rows))}"
    else:
        rows = {number: number - 1 for number in range(1, len(patient.points) + 1)}
        missing = [n for n in numbers if n not in rows]
        where = f"{patient.path} has {len(patient.points)} markers"
    if missing:
        raise ValueError(f"{image.path}: marker {missing[0]} has no partner ({where}); check the marker numbers")
    chosen = [rows[number] for number in numbers]
    return image.points, patient.points[chosen], np.array(numbers)


@dataclass(frozen=True)
class MarkerPairing:
    """Image and patient marker centres paired for the coarse registration.

    ``image`` and ``patient`` are (K, 3) mm, row k of one the same marker as row k of the other; ``image_rows`` and
    ``patient_rows`` (K,) say which row of each file (0-based) they are; ``warnings`` says when the pairing is not
    the one the files' numbers or order gave (re-paired by the markers' distances).
    """

    image: np.ndarray
    patient: np.ndarray
    image_rows: tuple
    patient_rows: tuple
    warnings: tuple = ()


def pair_marker_sets(image, patient, tolerance_mm=PAIRING_TOLERANCE_MM):
    """Pair image and patient marker centres, checked by the tool's geometry (``core.marker_geometry``).

    Both sides are the same rigid layout, whose inter-marker distances NDI designs to differ, so the distances say
    which centre is which. The pairing the files give (``pair_markers``: numbers, else rows) is kept when it fits
    rigidly within ``tolerance_mm``; otherwise the centres are paired by their distances and the user told so. Both
    sides are first checked: at least 3 centres, none duplicated, not in a line.

    Raises:
        ValueError: duplicated or collinear centres; no pairing within the tolerance (naming a unit mistake when the
            distances are those of metres, centimetres or inches); two pairings fit equally (cannot tell which).
    """
    image_name, patient_name = image.path or "marker centres (image)", patient.path or "marker centres (patient)"
    if len(image.points) >= 2 and len(patient.points) >= 2:
        hint = unit_hint(patient.points, image.points)  # the CT is in mm: a unit off shows on the patient side
        if hint:
            raise ValueError(f"{patient_name}: the markers do not pair with {image_name}{hint}")
    check_marker_centres(image.points, image_name)
    check_marker_centres(patient.points, patient_name)
    try:
        given_image, given_patient, _ = pair_markers(image, patient)
        given_rows = _rows_of(image, patient, given_patient)
    except ValueError:
        given_rows = None
    if given_rows is not None and len(given_image) >= 3 and _fits(given_image, given_patient, tolerance_mm):
        image_rows = tuple(range(len(image.points)))
        return MarkerPairing(given_image, given_patient, image_rows, given_rows)
    geometric = pair_by_geometry(
        patient.points,
        image.points,
        tolerance_mm,
        points_name=patient_name,
        reference_name=f"the image's marker centres ({image_name})",
    )
    if geometric.ambiguous:
        raise ValueError(
            f"{patient_name}: the order does not pair with {image_name} and two pairings by the markers' distances "
            f"fit within {tolerance_mm:g} mm (FRE {geometric.fre_mm:.2f} and {geometric.runner_up_fre_mm:.2f} mm); "
            "check the centres and give the patient markers in the order of the image's (M1, M2, ...)"
        )
    image_rows = tuple(int(row) for row in np.flatnonzero(geometric.paired))
    if len(image_rows) < min(len(image.points), len(patient.points)):
        unpaired = [_marker_name(image, row) for row in np.flatnonzero(~geometric.paired)]
        raise ValueError(
            f"{image_name} and {patient_name}: only {len(image_rows)} of the markers pair within {tolerance_mm:g} mm "
            f"by their distances; {', '.join(unpaired)} fits none of the patient's (a misplaced centre, or a "
            "marker moved since the CT): correct it, or delete it from the file (three markers are enough)"
        )
    patient_rows = tuple(int(geometric.indices[row]) for row in image_rows)
    names = [_marker_name(image, row) for row in image_rows]
    pairs = ", ".join(f"{name} = row {patient_row + 1}" for name, patient_row in zip(names, patient_rows))
    warning = (
        f"the patient marker centres ({patient_name}) are not in the image's order ({image_name}): paired by the "
        f"markers' distances instead ({pairs}; FRE {geometric.fre_mm:.2f} mm)"
    )
    return MarkerPairing(
        image.points[list(image_rows)], patient.points[list(patient_rows)], image_rows, patient_rows, (warning,)
    )


def _rows_of(image, patient, paired_patient):
    """The patient rows (0-based) of ``pair_markers``'s patient points, or None when a row cannot be found."""
    rows = []
    for point in paired_patient:
        matches = np.flatnonzero((patient.points == point).all(axis=1))
        if not matches.size:
            return None
        rows.append(int(matches[0]))
    return tuple(rows)


def _fits(image_points, patient_points, tolerance_mm):
    """True when ``patient_points`` map rigidly onto ``image_points`` with every residual within the tolerance."""
    transform = rigid_procrustes(patient_points, image_points)
    residuals = np.linalg.norm(apply_transform(transform, patient_points) - image_points, axis=1)
    return bool(residuals.max() <= tolerance_mm)


def _marker_name(marker_set, row):
    number = marker_set.numbers[row] if row < len(marker_set.numbers) else None
    return f"image M{number}" if number is not None else f"image row {row + 1}"


def flagged_message(marker_set):
    """One sentence naming the flagged markers of a set, e.g. 'marker 2 is partial and marker 4 is deformed'."""
    parts = [f"marker {number} is {status}" for number, status in marker_set.flagged()]
    return " and ".join([", ".join(parts[:-1]), parts[-1]] if len(parts) > 2 else parts)
