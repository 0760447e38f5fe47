"""Checks at the public edges of the core: point sets and transforms.

Every check raises ``ValueError`` (or ``TypeError``) with a message that names the argument, what was wrong
with it and what to do. Code behind these checks trusts its input.
"""

import numpy as np

#: Two points closer than this (mm) are the same point: far below any tracker's or CT's resolution.
DUPLICATE_DISTANCE_MM = 1e-3

#: A point set whose second principal extent is below this fraction of its first is treated as collinear:
#: the rotation about the line through it is then undetermined.
COLLINEARITY_RATIO = 1e-3


def as_points(values, name, min_count=1):
    """Return ``values`` as a float64 ``(N, 3)`` array of finite coordinates (mm).

    Raises ``ValueError`` naming ``name`` when the shape is wrong, when fewer than ``min_count`` points are
    given, or when a coordinate is NaN or infinite.
    """
    try:
        points = np.array(values, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name}: cannot read as numbers ({error}); pass an (N, 3) array of mm") from None
    if points.ndim == 1 and points.size in (0, 3):
        points = points.reshape(-1, 3)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name}: expected an (N, 3) array of x, y, z in mm, got shape {points.shape}")
    if points.shape[0] < min_count:
        raise ValueError(f"{name}: {points.shape[0]} point(s) given, at least {min_count} needed; collect more points")
    bad_rows = np.flatnonzero(~np.isfinite(points).all(axis=1))
    if bad_rows.size:
        raise ValueError(
            f"{name}: point(s) {_row_list(bad_rows + 1)} (counted from 1) contain NaN or infinity; remove or "
            "re-collect them"
        )
    return points


def check_distinct(points, name):
    """Raise ``ValueError`` if two points of ``points`` (N, 3) coincide (closer than 1 µm)."""
    differences = points[:, None, :] - points[None, :, :]
    distances = np.sqrt(np.einsum("ijk,ijk->ij", differences, differences))
    np.fill_diagonal(distances, np.inf)
    first, second = np.unravel_index(np.argmin(distances), distances.shape)
    if distances[first, second] < DUPLICATE_DISTANCE_MM:
        first, second = sorted((int(first), int(second)))
        raise ValueError(
            f"{name}: points {first + 1} and {second + 1} (counted from 1) are the same point "
            f"({distances[first, second]:.2g} mm apart); each fiducial must be a distinct location"
        )


def check_not_collinear(points, name):
    """Raise ``ValueError`` if ``points`` (N, 3) lie on (or very near) one straight line.

    The test is scale-free: the second singular value of the centred points divided by the first must be at
    least ``COLLINEARITY_RATIO``.
    """
    centred = points - points.mean(axis=0)
    singular_values = np.linalg.svd(centred, compute_uv=False)
    if singular_values[0] == 0.0 or singular_values[1] < COLLINEARITY_RATIO * singular_values[0]:
        raise ValueError(
            f"{name}: the points are (nearly) collinear, so the rotation about their line is undetermined; "
            "use at least 3 points that span a triangle"
        )


def as_transform(values, name):
    """Return ``values`` as a float64 ``(4, 4)`` rigid homogeneous transform.

    Raises ``ValueError`` if the shape is not 4x4, an entry is not finite, the last row is not (0, 0, 0, 1)
    or the upper-left 3x3 block is not a rotation (orthonormal with determinant +1, tolerance 1e-6).
    """
    try:
        matrix = np.array(values, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{name}: cannot read as numbers ({error}); pass a 4x4 matrix") from None
    if matrix.shape != (4, 4):
        raise ValueError(f"{name}: expected a 4x4 homogeneous matrix, got shape {matrix.shape}")
    if not np.isfinite(matrix).all():
        raise ValueError(f"{name}: contains NaN or infinity")
    if not np.allclose(matrix[3], (0.0, 0.0, 0.0, 1.0), atol=1e-9):
        raise ValueError(f"{name}: last row must be 0 0 0 1, got {matrix[3].tolist()}")
    rotation = matrix[:3, :3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6) or np.linalg.det(rotation) < 0:
        raise ValueError(f"{name}: the 3x3 block is not a rotation (it scales, shears or mirrors)")
    return matrix


def _row_list(rows, limit=8):
    shown = ", ".join(str(int(row)) for row in rows[:limit])
    return shown + (f" and {rows.size - limit} more" if rows.size > limit else "")
