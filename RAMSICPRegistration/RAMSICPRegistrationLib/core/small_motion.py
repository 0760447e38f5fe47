"""Small rigid motions: the 6-vector ``(w, t)`` that Gauss-Newton fits of a pose solve for, and what goes with it.

A motion ``(w, t)`` (rad, mm) about a centre ``c`` moves an image point ``y`` to ``c + R(w) (y - c) + t``; to first
order by ``w x (y - c) + t``, which is ``A (w, t)`` with the (3, 6) Jacobian ``A = [-[y - c]_x, I]``. A surface row
``n . (y - c_i)`` (a point's distance along the normal ``n`` to its match) changes by ``[(y - c) x n, n] . (w, t)``.
cr-fused (``core.fused``), the point-to-plane ICP (``core.plane_icp``), the predicted TRE
(``core.error_prediction``) and the touch guidance (``core.touch_guidance``) share these.
"""

import numpy as np

from .transforms import make_transform, rotation_about_axis


def cross_rows(a, b):
    """Row-wise cross product of (N, 3) arrays (np.cross costs more than the rest of an iteration here)."""
    return np.stack(
        (
            a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
            a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0],
        ),
        axis=1,
    )


def skew(vector):
    """(3, 3) cross-product matrix: ``skew(a) @ b == a x b``."""
    return np.array([[0.0, -vector[2], vector[1]], [vector[2], 0.0, -vector[0]], [-vector[1], vector[0], 0.0]])


def surface_rows(points, normals, centre):
    """(N, 6) rows ``[(y - c) x n, n]`` of N points (N, 3) with unit normals (N, 3) about ``centre`` (3,)."""
    return np.hstack((cross_rows(points - centre, normals), normals))


def point_jacobians(offsets):
    """(T, 3, 6) Jacobian of a point's displacement under (w, t) about the centre: ``[-[y - c]_x, I]``.

    ``offsets`` (T, 3) are the points less the centre, mm.
    """
    jacobians = np.zeros((len(offsets), 3, 6))
    x, y, z = offsets[:, 0], offsets[:, 1], offsets[:, 2]
    jacobians[:, 0, 1], jacobians[:, 0, 2] = z, -y
    jacobians[:, 1, 0], jacobians[:, 1, 2] = -z, x
    jacobians[:, 2, 0], jacobians[:, 2, 1] = y, -x
    jacobians[:, :, 3:] = np.eye(3)
    return jacobians


def motion(delta, centre):
    """The rigid motion (4, 4): rotation by the vector ``delta[:3]`` (rad) about ``centre``, then ``delta[3:]``."""
    angle = float(np.linalg.norm(delta[:3]))
    rotation = rotation_about_axis(delta[:3], angle) if angle > 0 else np.eye(3)
    return make_transform(rotation, centre + delta[3:] - rotation @ centre)


def solve(information, right):
    """``information^-1 right``; least squares when the information is singular (a motion nothing constrains)."""
    try:
        return np.linalg.solve(information, right)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(information, right, rcond=1e-12)[0]


def least_norm_solve(information, right, rcond=1e-10):
    """The smallest-norm ``x`` minimising ``|information x - right|`` (6,): motions whose information is below
    ``rcond`` times the largest (a slide along a cylinder, a spin about its axis) are left where they are."""
    values, vectors = np.linalg.eigh(information)
    kept = values > rcond * max(values[-1], 1e-300)
    return vectors[:, kept] @ ((vectors[:, kept].T @ right) / values[kept])


def invert_information(information):
    """Covariance (6, 6) from an information matrix; a motion nothing constrains makes it all infinite."""
    values, vectors = np.linalg.eigh(information)
    scale = max(values[-1], 1e-300)
    inverse = np.where(values > 1e-12 * scale, 1.0 / np.where(values > 0, values, 1.0), np.inf)
    if np.isinf(inverse).any():
        return np.full((6, 6), np.inf)
    return (vectors * inverse) @ vectors.T
