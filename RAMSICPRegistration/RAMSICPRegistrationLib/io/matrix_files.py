"""4 x 4 matrices and lists of poses from text or JSON files (``ramsicp plan --image-to-robot-base``, ``ramsicp tcp
--flange-poses``): every mistake is one line naming the option, the file and what to give."""

import json

import numpy as np

from ..core.validation import as_transform
from .file_checks import check_input_file


def read_matrix(path, option):
    """A rigid (4, 4) matrix from a text file (4 rows of 4 numbers) or JSON (a 4 x 4 list, or an object with
    ``image_to_robot_base``, as ``ramsicp plan`` writes it); ValueError in one line."""
    values = _read_numbers(path, option)
    if isinstance(values, dict):
        values = values.get("image_to_robot_base", values.get("robot_base", {}).get("image_to_robot_base"))
    try:
        matrix = np.array(values, dtype=np.float64)
    except (TypeError, ValueError):
        matrix = np.zeros(0)
    if matrix.shape != (4, 4):
        raise ValueError(f"{option} {path}: expected a 4 x 4 matrix (4 rows of 4 numbers), got shape {matrix.shape}")
    return as_transform(matrix, f"{option} {path}")


def read_poses(path, option):
    """(N, 4, 4) poses from JSON (a list of 4 x 4) or text (16 numbers a line, row by row); ValueError in one line."""
    values = _read_numbers(path, option)
    try:
        poses = np.array(values, dtype=np.float64)
    except (TypeError, ValueError):
        poses = np.zeros(0)
    if poses.ndim == 2 and poses.shape[1] == 16:
        poses = poses.reshape(-1, 4, 4)
    if poses.ndim == 1 and poses.size == 16:
        poses = poses.reshape(1, 4, 4)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise ValueError(f"{option} {path}: expected 4 x 4 poses (16 numbers a line), got shape {poses.shape}")
    return poses


def _read_numbers(path, option):
    check_input_file(path, f"{option} file")
    text = path.read_text(encoding="utf-8", errors="replace")
    if path.suffix.lower() == ".json":
        try:
            return json.loads(text)
        except json.JSONDecodeError as error:
            raise ValueError(f"{option} {path}: not valid JSON ({error.msg}, line {error.lineno})") from None
    rows = [line.replace(",", " ").split() for line in text.splitlines() if line.strip() and not line.startswith("#")]
    try:
        return [[float(value) for value in row] for row in rows]
    except ValueError as error:
        raise ValueError(f"{option} {path}: {error}; give numbers only") from None
