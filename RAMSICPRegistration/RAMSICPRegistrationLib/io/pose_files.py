"""Tracked poses on disk: a folder of 4x4 text matrices, or a CSV table of them (a PLUS sequence file is read by
``OpenIGTLinkBridgeLib.pose_recordings``, which also picks among the three by the path).

- **Folder**: one pose per file, a 4 x 4 matrix as text (4 lines of 4 numbers; spaces, tabs or commas), as
  scikit-surgery records them (``tests/data/PivotCalibration/1378476416922755200.txt``): a file named by an integer
  is timed by it in nanoseconds, and the poses are ordered by name (numerically for numeric names). Hidden files
  (``.``) are skipped.
- **CSV** (``.csv``, ``.txt``, ``.tsv``): one pose per line, the 16 numbers of its row-major 4 x 4 matrix, or a time
  (s) and those 16 numbers; commas, semicolons, tabs or spaces; a first line of column names is allowed
  (a column named ``time``, ``timestamp``, ``time_s`` or ``t`` is the time) and lines starting with ``#`` are
  comments.

Every matrix must be rigid (``check_rigid``: its rotation orthonormal to 1e-3 with determinant +1, its last row
0 0 0 1) and finite; a mistake is one ``ValueError`` line naming the file (and line) and what to give.
"""

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .point_files import is_number

#: How far (max element of R^T R - I) a rotation may be from orthonormal: trackers write 4 to 10 decimals.
RIGID_TOLERANCE = 1e-3
TABLE_SUFFIXES = (".csv", ".txt", ".tsv")
_TIME_COLUMNS = ("time", "timestamp", "time_s", "t", "seconds")
_SEPARATORS = re.compile(r"[,;\s]+")


@dataclass(frozen=True)
class PoseRecording:
    """Poses (N, 4, 4) (mm), their times (N,) s or None when the source has none, where they came from, and one
    label per pose (a file name, a line number)."""

    poses: np.ndarray
    times_s: object
    source: str
    labels: tuple = field(default=())
    warnings: tuple = field(default=())

    def __len__(self):
        return len(self.poses)


def check_rigid(matrix, where):
    """Raise ValueError unless ``matrix`` (4, 4) is a finite rigid transform; ``where`` starts the message."""
    matrix = np.asarray(matrix, dtype=np.float64)
    if not np.isfinite(matrix).all():
        raise ValueError(f"{where}: holds NaN or infinity; give finite numbers")
    if np.abs(matrix[3] - (0.0, 0.0, 0.0, 1.0)).max() > 1e-6:
        row = " ".join(f"{value:g}" for value in matrix[3])
        raise ValueError(f"{where}: last row is '{row}', expected '0 0 0 1' (a rigid 4x4 transform)")
    rotation = matrix[:3, :3]
    off = float(np.abs(rotation.T @ rotation - np.eye(3)).max())
    if off > RIGID_TOLERANCE or np.linalg.det(rotation) <= 0:
        problem = (
            "a reflection" if np.linalg.det(rotation) <= 0 else f"off orthonormal by {off:.2g} (scaled or sheared)"
        )
        raise ValueError(f"{where}: not a rigid transform, its rotation is {problem}; give rigid poses (mm)")
    return matrix


def read_pose_folder(folder):
    """Poses from a folder of 4x4 text matrices, one per file (the module's docstring)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"{folder}: no such folder")
    files = [path for path in folder.iterdir() if path.is_file() and not path.name.startswith(".")]
    if not files:
        raise ValueError(f"{folder}: holds no pose files; give a folder of 4x4 matrices as text, one per file")
    numeric = all(path.stem.isdigit() for path in files)
    files.sort(key=(lambda path: int(path.stem)) if numeric else (lambda path: path.name))
    poses = np.array([_matrix_file(path) for path in files])
    times = np.array([int(path.stem) for path in files], dtype=np.float64) * 1e-9 if numeric else None
    return PoseRecording(poses, times, str(folder), tuple(path.name for path in files))


def _matrix_file(path):
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise ValueError(f"{path}: cannot be read as text ({getattr(error, 'strerror', None) or error})") from None
    numbers = _numbers(text, path)
    if len(numbers) != 16:
        raise ValueError(f"{path}: {len(numbers)} numbers, expected 16 (a 4x4 matrix, 4 rows of 4)")
    return check_rigid(np.array(numbers).reshape(4, 4), path)


def read_pose_table(path):
    """Poses from a CSV table, one per line (the module's docstring)."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{path}: is a folder; give the CSV file itself (or the folder as a folder of matrices)")
    if not path.is_file():
        raise ValueError(f"{path}: no such file")
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as error:
        raise ValueError(f"{path}: cannot be read as text ({getattr(error, 'strerror', None) or error})") from None
    rows, labels, time_column = [], [], None
    for number, line in enumerate(lines, start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        fields = [value for value in _SEPARATORS.split(text) if value]
        if not rows and time_column is None and not is_number(fields[0]):
            names = [name.strip().strip('"').lower() for name in fields]
            time_column = next((names.index(name) for name in _TIME_COLUMNS if name in names), -1)
            continue
        values = _numbers(text, f"{path}, line {number}")
        if len(values) not in (16, 17):
            raise ValueError(
                f"{path}, line {number}: {len(values)} numbers, expected 16 (a row-major 4x4 matrix) or a time and 16"
            )
        if rows and len(values) != len(rows[0]):
            raise ValueError(f"{path}, line {number}: {len(values)} numbers where the lines before have {len(rows[0])}")
        rows.append(values)
        labels.append(f"line {number}")
    if not rows:
        raise ValueError(f"{path}: holds no poses; give one row-major 4x4 matrix (16 numbers) per line")
    table = np.array(rows)
    times = None
    if table.shape[1] == 17:
        column = time_column if time_column not in (None, -1) else 0
        times = table[:, column]
        table = np.delete(table, column, axis=1)
    poses = table.reshape(-1, 4, 4)
    for pose, label in zip(poses, labels):
        check_rigid(pose, f"{path}, {label}")
    if times is not None and not np.isfinite(times).all():
        raise ValueError(f"{path}: a time is NaN or infinite; give finite times (s)")
    return PoseRecording(poses, times, str(path), tuple(labels))


def _numbers(text, where):
    values = []
    for value in _SEPARATORS.split(text.strip()):
        if not value:
            continue
        try:
            values.append(float(value))
        except ValueError:
            raise ValueError(f"{where}: {value[:30]!r} is not a number") from None
    return values
