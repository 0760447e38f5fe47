"""Point sets on disk: Slicer markups JSON (``.mrk.json``), ``.fcsv``, ``.csv``/``.txt`` and ``.npy``.

Inside the program every point is RAS (Slicer's world frame). Files that state their frame (markups JSON's
``coordinateSystem``, the ``.fcsv`` header, a ``# SPACE=LPS`` comment in a text file) are converted on reading;
files that cannot state it (``.npy``, text files without the comment) are taken to be in ``untagged_space``
(RAS unless told). Markups are written in LPS, as Slicer writes them; text files carry a ``# SPACE=RAS`` line.
"""

import csv
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.validation import as_points
from .atomic_files import atomic_path
from .file_checks import PointFileError, check_input_file

SPACES = ("RAS", "LPS")
_RAS_FROM_LPS = np.array([-1.0, -1.0, 1.0])
MARKUPS_SCHEMA = (
    "https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/Markups/Resources/Schema/"
    "markups-schema-v1.0.3.json#"
)
POINT_SUFFIXES = (".mrk.json", ".json", ".fcsv", ".csv", ".txt", ".npy")


@dataclass(frozen=True)
class PointSet:
    """Points read from a file: ``points`` (N, 3) RAS mm, one label per point (may be empty strings), and the frame
    the file stated (``stated_space``: 'RAS' or 'LPS', None when it stated none and ``untagged_space`` was used)."""

    points: np.ndarray
    labels: tuple = field(default=())
    stated_space: str = None

    def __len__(self):
        return len(self.points)


def to_ras(points, space):
    """Convert (N, 3) points given in ``space`` ('RAS' or 'LPS') to RAS. The conversion is its own inverse."""
    space = _check_space(space)
    return points * _RAS_FROM_LPS if space == "LPS" else points.copy()


def read_points(path, untagged_space="RAS"):
    """Read a point set, returning a PointSet in RAS.

    Raises:
        PointFileError: the file is missing, a folder, empty, of an unknown type, malformed, or holds no points.
    """
    untagged_space = _check_space(untagged_space)
    path = check_input_file(path, "point file")
    suffix = _suffix(path)
    readers = {
        ".mrk.json": _read_markups_json,
        ".json": _read_markups_json,
        ".fcsv": _read_fcsv,
        ".csv": _read_text,
        ".txt": _read_text,
        ".npy": _read_npy,
    }
    if suffix not in readers:
        raise PointFileError(path, f"unknown point file type; use one of {', '.join(POINT_SUFFIXES)}")
    try:
        points, labels, space = readers[suffix](path)
    except PointFileError:
        raise
    except (OSError, UnicodeDecodeError) as error:
        raise PointFileError(path, f"cannot read ({error})") from None
    stated = space
    if space is None:
        space = untagged_space
    try:
        points = as_points(points, "points", min_count=1)
    except ValueError as error:
        raise PointFileError(path, str(error)) from None
    labels = tuple(labels) if labels else ("",) * len(points)
    return PointSet(points=to_ras(points, space), labels=labels, stated_space=stated)


def write_points(path, points, labels=None, durable=False):
    """Write (N, 3) RAS points to ``path``; the file type follows the suffix (LPS for markups, as Slicer).

    Written whole or not at all (``io.atomic_files``); ``durable`` also flushes it to the disk.
    """
    path = Path(path)
    points = as_points(points, "points", min_count=0)
    labels = list(labels) if labels is not None else [f"F-{i + 1}" for i in range(len(points))]
    if len(labels) != len(points):
        raise ValueError(f"labels: {len(labels)} given for {len(points)} points")
    suffix = _suffix(path)
    if suffix not in POINT_SUFFIXES:
        raise PointFileError(path, f"unknown point file type; use one of {', '.join(POINT_SUFFIXES)}")
    with atomic_path(path, durable=durable) as temporary:
        _write_points_as(temporary, suffix, points, labels)


def _write_points_as(path, suffix, points, labels):
    if suffix in (".mrk.json", ".json"):
        _write_markups_json(path, points, labels)
    elif suffix == ".fcsv":
        _write_fcsv(path, points, labels)
    elif suffix in (".csv", ".txt"):
        delimiter = "," if suffix == ".csv" else " "
        header = "# SPACE=RAS units=mm x y z"
        np.savetxt(path, points, fmt="%.17g", delimiter=delimiter, header=header[2:], comments="# ")
    elif suffix == ".npy":
        np.save(path, points)


def write_points_atomic(path, points, labels=None):
    """``write_points``, flushed to the disk, its folder created when missing: a crash or a power cut at any moment
    leaves either the previous complete file or the new one. Used for the autosave of every collected point."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_points(path, points, labels, durable=True)


def _suffix(path):
    name = path.name.lower()
    return ".mrk.json" if name.endswith(".mrk.json") else path.suffix.lower()


def _check_space(space):
    space = str(space).upper()
    if space not in SPACES:
        raise ValueError(f"coordinate space {space!r}: use 'RAS' or 'LPS'")
    return space


def _read_markups_json(path):
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as error:
        raise PointFileError(path, f"not valid JSON ({error.msg} at line {error.lineno})") from None
    markups = document.get("markups") if isinstance(document, dict) else None
    if not markups or not isinstance(markups, list):
        raise PointFileError(path, "no 'markups' list; expected a Slicer markups JSON file (.mrk.json)")
    markup = markups[0]
    space = str(markup.get("coordinateSystem", "LPS")).upper()
    if space not in SPACES:
        raise PointFileError(path, f"coordinateSystem {space!r} is neither LPS nor RAS")
    points, labels = [], []
    for number, control_point in enumerate(markup.get("controlPoints", [])):
        if control_point.get("positionStatus", "defined") != "defined":
            continue
        position = control_point.get("position")
        if not isinstance(position, list) or len(position) != 3:
            raise PointFileError(path, f"control point {number + 1} has no 3-number 'position'")
        points.append(position)
        labels.append(str(control_point.get("label", "")))
    if not points:
        raise PointFileError(path, "holds no defined control points")
    return points, labels, space


def _write_markups_json(path, points, labels):
    lps = to_ras(points, "LPS")
    control_points = [
        {"id": str(i + 1), "label": label, "position": [float(v) for v in point], "positionStatus": "defined"}
        for i, (label, point) in enumerate(zip(labels, lps))
    ]
    document = {
        "@schema": MARKUPS_SCHEMA,
        "markups": [
            {"type": "Fiducial", "coordinateSystem": "LPS", "coordinateUnits": "mm", "controlPoints": control_points}
        ],
    }
    path.write_text(json.dumps(document, indent=2), encoding="utf-8")


def _read_fcsv(path):
    space, columns, points, labels = None, None, [], []
    with path.open(newline="", encoding="utf-8") as stream:
        for line_number, row in enumerate(csv.reader(stream), start=1):
            if not row or not "".join(row).strip():
                continue
            if row[0].startswith("#"):
                text = ",".join(row)
                match = re.match(r"#\s*CoordinateSystem\s*=\s*(\w+)", text)
                if match:
                    space = {"0": "RAS", "1": "LPS", "RAS": "RAS", "LPS": "LPS"}.get(match.group(1).upper())
                    if space is None:
                        raise PointFileError(path, f"line {line_number}: unknown CoordinateSystem {match.group(1)}")
                if text.lstrip("# ").lower().startswith("columns"):
                    columns = [name.strip() for name in text.split("=", 1)[1].split(",")]
                continue
            names = columns or ["id", "x", "y", "z", "ow", "ox", "oy", "oz", "vis", "sel", "lock", "label"]
            try:
                record = dict(zip(names, row))
                points.append([float(record["x"]), float(record["y"]), float(record["z"])])
            except (KeyError, ValueError):
                raise PointFileError(path, f"line {line_number}: expected id,x,y,z,... got {','.join(row)!r}") from None
            labels.append(record.get("label", ""))
    if not points:
        raise PointFileError(path, "holds no points")
    # Slicer's fcsv files without a CoordinateSystem line (before 4.11) are RAS.
    return points, labels, space or "RAS"


def _write_fcsv(path, points, labels):
    lps = to_ras(points, "LPS")
    lines = [
        "# Markups fiducial file version = 4.11",
        "# CoordinateSystem = LPS",
        "# columns = id,x,y,z,ow,ox,oy,oz,vis,sel,lock,label,desc,associatedNodeID",
    ]
    for i, (label, (x, y, z)) in enumerate(zip(labels, lps)):
        lines.append(f"{i + 1},{x:.17g},{y:.17g},{z:.17g},0,0,0,1,1,1,0,{label},,")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


#: Column names a text file's header may give its coordinates, with the frame they state (None: not stated). Slicer's
#: markups control points table (``label,l,p,s,defined,...`` or ``label,r,a,s,...``) names them by its frame.
_COORDINATE_COLUMNS = ((("x", "y", "z"), None), (("r", "a", "s"), "RAS"), (("l", "p", "s"), "LPS"))
#: A number written with a decimal comma, as spreadsheets in many locales write them: ``-12,5``.
_DECIMAL_COMMA = re.compile(r"[-+]?\d+,\d+(?:[eE][-+]?\d+)?")


def _read_text(path):
    """Points of a .csv/.txt file: one point per line, x y z separated by commas, semicolons, tabs or spaces.

    A header line of column names picks the coordinates by name in any order (``z,y,x``; Slicer's control points
    table ``label,l,p,s,defined,...``, whose ``l,p,s`` or ``r,a,s`` names also state the frame; rows with
    ``defined`` 0 are skipped). Decimal commas are read when the columns are separated by something else
    (``1,5;2,5;3,5``); separated by commas as well they cannot be told apart from the separators, and the line is
    refused with that cause.
    """
    space, points, labels, columns = None, [], [], None
    for line_number, line in enumerate(path.read_text(encoding="utf-8-sig").splitlines(), start=1):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            match = re.search(r"SPACE\s*=\s*(RAS|LPS)", stripped, re.IGNORECASE)
            space = match.group(1).upper() if match else space
            continue
        separator = next((mark for mark in (";", "\t") if mark in stripped), "," if "," in stripped else None)
        words = stripped.split()
        if separator == "," and len(words) > 1 and all(_DECIMAL_COMMA.fullmatch(w) or is_number(w) for w in words):
            separator = " "  # "1,5 -2,25 3": columns by spaces, decimal commas
        fields = [value.strip() for value in (words if separator in (None, " ") else stripped.split(separator))]
        if separator in (";", "\t", " "):
            fields = [value.replace(",", ".") if _DECIMAL_COMMA.fullmatch(value) else value for value in fields]
        if columns is None and not points and not any(is_number(value) for value in fields if value):
            columns, stated = _header_columns(path, line_number, fields)
            space = stated or space
            continue
        if columns is not None:
            point, label, defined = _named_row(path, line_number, fields, columns, stripped)
            if defined:
                points.append(point)
                labels.append(label)
            continue
        fields = [value for value in fields if value]
        try:
            values = [float(value) for value in fields]
        except ValueError:
            raise PointFileError(path, f"line {line_number}: expected 3 numbers x y z, got {stripped!r}") from None
        if len(values) != 3:
            hint = ""
            if separator == "," and len(values) == 6:
                hint = (
                    " (decimal commas? '1,5,2,5,3,5' cannot be told from six numbers: write decimals with a point, "
                    "or separate the columns by ';' or tabs)"
                )
            raise PointFileError(path, f"line {line_number}: expected 3 numbers x y z, got {len(values)}{hint}")
        points.append(values)
        labels.append("")
    if not points:
        raise PointFileError(path, "holds no points (expected one 'x y z' line per point)")
    return points, labels if any(labels) else None, space


def is_number(text):
    """Whether ``text`` reads as a number (float)."""
    try:
        float(text)
    except ValueError:
        return False
    return True


def _header_columns(path, line_number, fields):
    """{'x': column, 'y': ..., 'z': ..., optionally 'label', 'defined'} from a header line, and the frame its
    coordinate names state (or None)."""
    names = [value.lower() for value in fields]
    for axes, stated in _COORDINATE_COLUMNS:
        if all(axis in names for axis in axes):
            columns = {key: names.index(axis) for key, axis in zip("xyz", axes)}
            columns.update({key: names.index(key) for key in ("label", "defined") if key in names})
            return columns, stated
    raise PointFileError(
        path,
        f"line {line_number}: the header {','.join(fields)!r} names no coordinate columns; name them x,y,z (any "
        "order), r,a,s or l,p,s (as Slicer's control points table)",
    )


def _named_row(path, line_number, fields, columns, text):
    """(point [x, y, z], label, defined) of a data line read by its header's columns."""
    try:
        point = [float(fields[columns[axis]]) for axis in "xyz"]
    except (IndexError, ValueError):
        raise PointFileError(
            path, f"line {line_number}: expected numbers in the header's coordinate columns, got {text!r}"
        ) from None
    label = fields[columns["label"]] if "label" in columns and columns["label"] < len(fields) else ""
    defined = "defined" not in columns or columns["defined"] >= len(fields) or fields[columns["defined"]] != "0"
    return point, label, defined


def _read_npy(path):
    try:
        points = np.load(path, allow_pickle=False)
    except ValueError as error:
        raise PointFileError(path, f"not a numpy array file ({error})") from None
    if points.ndim != 2 or points.shape[1] != 3:
        raise PointFileError(path, f"expected an (N, 3) array, got shape {points.shape}")
    return points, None, None
