"""The surface a point cloud samples, where a plane or a line crosses it: local quadrics fitted to its points.

A point-cloud IPC has no triangles, so where a cut plane (or the side line of a cut) crosses the bone is not one of
its points. Around each cloud point ``p`` the surface is fitted, in ``p``'s principal frame (``u``, ``v`` along the
surface, ``w`` along its normal: the eigenvectors of its ``QUADRIC_NEIGHBOURS`` nearest points' scatter), by the
least-squares quadric

    w = a u^2 + b u v + c v^2 + d u + e v + f ............................................................ (Q1)

Along any line of the frame, ``w`` minus (Q1) is quadratic in the line's parameter, so the crossing of the local
surface with a line, or with a plane along the surface's steepest way to it, is the root of a quadratic nearest to
``p``. The quadric's own error over a move ``d`` grows as ``d^4 / 8 R^3`` on a surface of radius ``R`` (0.2 micron
at 1.5 mm on a 15 mm cylinder); noise in the cloud enters through the fit, about as much as it is in the points.
"""

import numpy as np

from .surface_index import SurfaceIndex

#: Neighbours each local quadric (Q1) is fitted to.
QUADRIC_NEIGHBOURS = 24


class CloudSurface:
    """A point cloud (N, 3) in mm with its KD-tree (``SurfaceIndex``), answering where planes and lines cross it."""

    def __init__(self, points):
        self.index = SurfaceIndex(points)
        self.points = self.index.points

    @property
    def spacing_mm(self):
        """The cloud's median nearest-neighbour distance, mm."""
        return self.index.spacing_mm

    def quadrics(self, indices):
        """Frames (M, 3, 3), columns (w, v, u), and coefficients (M, 6) ``a..f`` of (Q1) about points ``indices``."""
        count = min(QUADRIC_NEIGHBOURS, len(self.points))
        _, neighbours = self.index.tree.query(self.points[indices], k=count)
        offsets = self.points[neighbours] - self.points[indices][:, None, :]  # (M, k, 3)
        centred = offsets - offsets.mean(axis=1, keepdims=True)
        _, frames = np.linalg.eigh(np.einsum("mki,mkj->mij", centred, centred))  # ascending: w, v, u
        w, v, u = (np.einsum("mki,mi->mk", offsets, frames[:, :, axis]) for axis in range(3))
        design = np.stack((u * u, u * v, v * v, u, v, np.ones_like(u)), axis=2)  # (M, k, 6)
        normal_matrix = np.einsum("mki,mkj->mij", design, design) + 1e-12 * np.eye(6)
        coefficients = np.linalg.solve(normal_matrix, np.einsum("mki,mk->mi", design, w)[..., None])[..., 0]
        return frames, coefficients

    def plane_crossing(self, origin, normal, half_thickness_mm, min_sine=0.3):
        """(K, 3) points where the local surfaces of the cloud points within ``half_thickness_mm`` of the plane
        through ``origin`` (3,) with unit ``normal`` (3,) cross it, each along its surface's steepest way to the
        plane; on the plane to rounding. Points whose surface is within asin(``min_sine``) of parallel to the plane
        are left out: there the surface runs along the plane rather than across it."""
        heights = (self.points - origin) @ normal
        near = np.flatnonzero(np.abs(heights) < half_thickness_mm)
        if len(near) == 0 or len(self.points) < 6:
            return self.points[near]
        frames, (a, b, c, d, e, f) = self._frames_and_coefficients(near)
        slant = [frames[:, :, axis] @ normal for axis in range(3)]  # the plane's normal in each frame: w, v, u
        # The height's gradient along the surface at p, and its steepest line (u, v) = t (g_u, g_v).
        g_u, g_v = slant[2] + d * slant[0], slant[1] + e * slant[0]
        climb = g_u**2 + g_v**2
        # height(t) = h + f n_w + t climb + t^2 n_w (a g_u^2 + b g_u g_v + c g_v^2) on the quadric.
        curve = slant[0] * (a * g_u**2 + b * g_u * g_v + c * g_v**2)
        roots, valid = _nearest_roots(curve, climb, heights[near] + f * slant[0])
        keep = valid & (climb > min_sine**2)
        tu, tv = roots * g_u, roots * g_v
        lift = a * tu**2 + b * tu * tv + c * tv**2 + d * tu + e * tv + f
        moved = self.points[near] + tu[:, None] * frames[:, :, 2] + tv[:, None] * frames[:, :, 1]
        return (moved + lift[:, None] * frames[:, :, 0])[keep]

    def line_crossings(self, start, direction, radius_mm):
        """(K,) parameters ``t`` (mm) where the line ``start + t direction`` (unit ``direction``) crosses the local
        surfaces of the cloud points within ``radius_mm`` of it: one per point whose surface it crosses, nearest to
        that point's foot on the line."""
        offsets = self.points - start
        along = offsets @ direction
        near = np.flatnonzero(np.linalg.norm(offsets - along[:, None] * direction, axis=1) < radius_mm)
        if len(near) == 0 or len(self.points) < 6:
            return np.zeros(0)
        frames, (a, b, c, d, e, f) = self._frames_and_coefficients(near)
        # The line in each point's frame: (w, v, u) = origin + t slope, with t measured from the point's foot.
        foot = start + along[near, None] * direction
        w0, v0, u0 = (np.einsum("mi,mi->m", foot - self.points[near], frames[:, :, axis]) for axis in range(3))
        gw, gv, gu = (frames[:, :, axis] @ direction for axis in range(3))
        quadratic = -(a * gu**2 + b * gu * gv + c * gv**2)
        linear = gw - (2.0 * a * u0 * gu + b * (u0 * gv + v0 * gu) + 2.0 * c * v0 * gv + d * gu + e * gv)
        constant = w0 - (a * u0**2 + b * u0 * v0 + c * v0**2 + d * u0 + e * v0 + f)
        roots, valid = _nearest_roots(quadratic, linear, constant)
        keep = valid & (np.abs(roots) < 3.0 * radius_mm)
        return (along[near] + roots)[keep]

    def _frames_and_coefficients(self, indices):
        frames, coefficients = self.quadrics(indices)
        return frames, tuple(coefficients.T)


def _nearest_roots(quadratic, linear, constant):
    """The root nearest 0 of ``quadratic t^2 + linear t + constant`` for each row (M,), and whether it exists."""
    discriminant = linear**2 - 4.0 * quadratic * constant
    valid = (discriminant >= 0.0) & (np.abs(linear) > 1e-12)
    sign = np.where(linear >= 0.0, 1.0, -1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        # The smaller root in the stable form, -2c / (b + sign(b) sqrt(b^2 - 4ac)).
        roots = -2.0 * constant / (linear + sign * np.sqrt(np.maximum(discriminant, 0.0)))
    return np.where(valid, roots, 0.0), valid
