"""Point-to-plane ICP from the CR (``cr-icp-plane``): the baseline a user would pick today, beside the paper's CR-ICP.

Chen and Medioni's point-to-plane ICP ("Object modelling by registration of multiple range images", Image and
Vision Computing 10(3), 1992), as Open3D's ``registration_icp`` computes it with
``TransformationEstimationPointToPlane`` (open3d/pipelines/registration/TransformationEstimation.cpp): every
iteration matches each moving point ``x_i = T p_i`` to its closest IPC point ``c_i``, whose surface normal is
``n_i``, and solves the linearised least squares

    min over (w, t) of  sum_i ( n_i . (x_i - c_i) + [(x_i - c) x n_i, n_i] . (w, t) )^2 ............ (P1)

for a small rotation ``w`` and translation ``t`` (``core.small_motion``), applied as ``T <- (R(w), t) T``, until
no point moves more than ``tolerance_mm`` in an iteration. Unlike the paper's point-to-point ICP (eq. 9) a point
may slide along the surface at no cost, so the fit is not pinned where the CR's closest points happen to lie.
Differences from Open3D, none of which changes the fixed point: the rotation is about the moving points' centroid
``c`` (Open3D: the origin, its XYZ Euler angles), every closest point counts (Open3D drops pairs beyond
``max_correspondence_distance``), the normals are the IPC's own (``SurfaceIndex.normals``: PCA of 16 neighbours,
as Open3D's ``estimate_normals`` with a 16-nearest search), and it stops on the step, not on relative changes of
its fitness and RMSE (Open3D: 1e-6 each, at most 30 iterations). ``benchmarks/bench_point_to_plane.py`` runs both
on the same data.

As in cr-fused, a point flipping between two IPC points can make the steps cycle; once a step is as large as half
the one before after ``FREEZE_AFTER`` iterations, the matches are kept and the fit settles at once. A motion the
points do not constrain at all (for exact planes: the slide along a cylinder, the spin about its axis) is not moved:
each step is the smallest-norm solution of P1.
"""

import numpy as np

from .icp import DEFAULT_MAX_ITERATIONS, DEFAULT_TOLERANCE_MM, FineResult
from .small_motion import least_norm_solve, motion, surface_rows
from .transforms import apply_transform, invert_transform

#: Iterations before a step that stopped shrinking keeps the matches (see the module docstring). Gauss-Newton has
#: settled long before (4 to 7 iterations on the demo's trials); until then the closest points are found again at
#: every iteration, as Open3D does.
FREEZE_AFTER = 10


def icp_point_to_plane(
    index, moving_points, initial_transform, max_iterations=DEFAULT_MAX_ITERATIONS, tolerance_mm=DEFAULT_TOLERANCE_MM
):
    """Point-to-plane ICP (P1) of patient points onto the IPC, from ``initial_transform`` (the CR: cr-icp-plane).

    Args:
        index: SurfaceIndex of the IPC (image coordinates, mm).
        moving_points: (N, 3) patient points in reference coordinates (mm), validated, N >= 3.
        initial_transform: (4, 4) ReferenceToImage start.
        tolerance_mm: stop when no point moves by more than this in an iteration.

    Returns:
        FineResult: ``transform`` the registered ReferenceToImage, ``fine_transform`` the image-space correction
        (``transform @ inv(initial)``), ``rms_mm`` the RMS point-to-plane distance at the end,
        ``rms_history_mm`` after each iteration.
    """
    initial = np.array(initial_transform, dtype=np.float64)
    transform = initial.copy()
    history, frozen, last_move, converged = [], None, np.inf, False
    for iteration in range(1, max_iterations + 1):
        moved = apply_transform(transform, moving_points)
        matched = index.nearest(moved)[1] if frozen is None else frozen
        normals = index.normals(matched)
        residuals = np.einsum("ij,ij->i", moved - index.points[matched], normals)
        history.append(float(np.sqrt(np.mean(residuals**2))))
        centre = moved.mean(axis=0)
        rows = surface_rows(moved, normals, centre)
        delta = least_norm_solve(rows.T @ rows, -rows.T @ residuals)
        transform = motion(delta, centre) @ transform
        radius = float(np.sqrt(np.max(np.sum((moved - centre) ** 2, axis=1))))
        move = float(np.linalg.norm(delta[3:]) + np.linalg.norm(delta[:3]) * radius)
        if iteration > FREEZE_AFTER and move > 0.5 * last_move and frozen is None:
            frozen = matched  # steps that stopped shrinking: a point flips between two IPC points
        last_move = move
        if move < tolerance_mm:
            converged = True
            break
    moved = apply_transform(transform, moving_points)
    matched = index.nearest(moved)[1] if frozen is None else frozen
    residuals = np.einsum("ij,ij->i", moved - index.points[matched], index.normals(matched))
    history.append(float(np.sqrt(np.mean(residuals**2))))
    return FineResult(
        fine_transform=transform @ invert_transform(initial),
        transform=transform,
        rms_mm=history[-1],
        iterations=iteration,
        converged=converged,
        matched_indices=matched,
        rms_history_mm=tuple(history),
    )
