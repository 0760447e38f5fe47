"""Marker-centre files that carry each marker's number and status, from ``ramsicp ipc`` to ``ramsicp register``.

A markers file is an ordinary point file (markups JSON, fcsv, csv, ...) whose labels read ``M<n> <status>``:
``n`` is the reference body's marker number (1-based, in the order of the NDI tool's markers) and ``status``
is how the sphere looked in the CT: ``ok``, ``partial`` or ``deformed`` (``image.marker_spheres``). The labels
show in Slicer's markups table, so the status travels with the points wherever the file goes. A point the
program could not pair with a tool marker is labelled ``M? <status>``. Files without such labels (centres placed
by hand, the tool geometry) have neither: their points pair row by row and count as usable.
"""

import re
from dataclasses import dataclass

import numpy as np

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
    return labelled_markers(point_set.points, point_set.labels, str(path))


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


def flagged_message(marker_set):
    """One sentence naming the flagged markers of a set, e.g. 'marker 2 is partial and marker 4 is deformed'."""
    parts = [f"marker {number} is {status}" for number, status in marker_set.flagged()]
    return " and ".join([", ".join(parts[:-1]), parts[-1]] if len(parts) > 2 else parts)
