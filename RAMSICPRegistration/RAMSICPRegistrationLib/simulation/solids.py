"""Solids given by their signed distance (mm, negative inside), for painting CT phantoms and for ground truth.

Each solid has ``signed_distance(points)`` for (..., 3) RAS points and ``bounds()``, an RAS box (low (3,),
high (3,)) that holds it. The analytic ones (capsule, ball, rounded slab) are exact everywhere, so the distance of
an IPC point to the true surface is exact; a bone mesh is exact near its surface (point-to-plane distance to dense
surface samples, ``MeshSolid``), where the ground truth needs it.
"""

from dataclasses import dataclass
from functools import lru_cache

import numpy as np


@dataclass(frozen=True)
class Capsule:
    """A cylinder of ``radius`` with round ends, from ``start`` to ``end`` (RAS mm): rods, posts, a long bone."""

    start: np.ndarray
    end: np.ndarray
    radius: float

    def signed_distance(self, points):
        start, end = np.asarray(self.start, float), np.asarray(self.end, float)
        axis = end - start
        length2 = float(axis @ axis)
        t = np.clip(((points - start) @ axis) / length2, 0.0, 1.0) if length2 > 0 else np.zeros(points.shape[:-1])
        return np.linalg.norm(points - (start + t[..., None] * axis), axis=-1) - self.radius

    def bounds(self):
        start, end = np.asarray(self.start, float), np.asarray(self.end, float)
        return np.minimum(start, end) - self.radius, np.maximum(start, end) + self.radius


@dataclass(frozen=True)
class Ball:
    """A ball (a marker sphere, a blob)."""

    centre: np.ndarray
    radius: float

    def signed_distance(self, points):
        return np.linalg.norm(points - np.asarray(self.centre, float), axis=-1) - self.radius

    def bounds(self):
        return np.asarray(self.centre, float) - self.radius, np.asarray(self.centre, float) + self.radius


@dataclass(frozen=True)
class CutBall:
    """A ball with a cap ``depth`` mm deep missing on the side ``away`` (a unit vector): a damaged marker sphere."""

    centre: np.ndarray
    radius: float
    away: np.ndarray
    depth: float

    def signed_distance(self, points):
        offset = points - np.asarray(self.centre, float)
        cap = offset @ np.asarray(self.away, float) - (self.radius - self.depth)
        return np.maximum(np.linalg.norm(offset, axis=-1) - self.radius, cap)

    def bounds(self):
        return np.asarray(self.centre, float) - self.radius, np.asarray(self.centre, float) + self.radius


@dataclass(frozen=True)
class Slab:
    """A box with rounded edges: ``axes`` (3, 3) unit columns, ``half_size`` (3,) along them, edges rounded by
    ``rounding`` (at most the smallest half size). A frame plate, a flat bone, a table top."""

    centre: np.ndarray
    axes: np.ndarray
    half_size: np.ndarray
    rounding: float = 0.0

    def signed_distance(self, points):
        local = np.abs((points - np.asarray(self.centre, float)) @ np.asarray(self.axes, float))
        q = local - (np.asarray(self.half_size, float) - self.rounding)
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
        return outside + np.minimum(q.max(axis=-1), 0.0) - self.rounding

    def bounds(self):
        reach = np.abs(np.asarray(self.axes, float)) @ np.asarray(self.half_size, float)
        return np.asarray(self.centre, float) - reach, np.asarray(self.centre, float) + reach


@dataclass(frozen=True)
class Union:
    """Several solids as one: the smallest signed distance (exact outside all of them)."""

    parts: tuple

    def signed_distance(self, points):
        return np.min([part.signed_distance(points) for part in self.parts], axis=0)

    def bounds(self):
        lows, highs = zip(*(part.bounds() for part in self.parts))
        return np.min(lows, axis=0), np.max(highs, axis=0)


@dataclass(frozen=True)
class MeshSolid:
    """A closed bone mesh (one of ``package_data.BONES``) moved by ``pose`` (4, 4, mesh -> RAS).

    ``signed_distance`` is the point-to-plane distance to the nearest of ``MESH_SAMPLES`` surface samples with
    their outward normals: exact to about 0.01 mm within a few mm of the surface, which is where it is used (the
    partial volume of the voxels at the surface, an IPC point's distance to the true surface). Far from the
    surface the Euclidean distance to the nearest sample is returned, with the sign of that sample's side. The
    inside of the mesh on a whole grid comes from ``inside_on_grid``.
    """

    name: str
    pose: np.ndarray

    def _local(self, points):
        rotation, translation = self.pose[:3, :3], self.pose[:3, 3]
        return (points - translation) @ rotation

    def signed_distance(self, points):
        samples, normals, tree = _mesh_samples(self.name)
        shape = points.shape[:-1]
        local = self._local(np.asarray(points, float).reshape(-1, 3))
        distance, nearest = tree.query(local, workers=-1)  # one query per point: the same answers on any cores
        plane = np.einsum("ij,ij->i", local - samples[nearest], normals[nearest])
        # Beyond a few sample spacings the tangent plane of the nearest sample no longer measures the distance.
        far = distance > 1.0
        plane[far] = np.sign(plane[far]) * distance[far]
        return plane.reshape(shape)

    def bounds(self):
        vertices, _ = mesh_in_ras(self.name, self.pose)
        return vertices.min(axis=0), vertices.max(axis=0)

    def inside_on_grid(self, volume, box):
        """(I, J, K) booleans over an index ``box`` (3 slices) of ``volume``: voxel centres inside the mesh."""
        from ..io.vtk_arrays import mesh_inside_grid

        vertices, triangles = mesh_in_ras(self.name, self.pose)
        low = np.array([s.start for s in box])
        shape = np.array([s.stop - s.start for s in box])
        return mesh_inside_grid(volume.ras_to_ijk_points(vertices) - low, triangles, shape)

    def surface_samples(self):
        """(N, 3) RAS points and (N, 3) outward normals on the surface."""
        samples, normals, _ = _mesh_samples(self.name)
        rotation = self.pose[:3, :3]
        return samples @ rotation.T + self.pose[:3, 3], normals @ rotation.T


#: Surface samples of a mesh for its signed distance: about 0.25 mm apart on a tibia.
MESH_SAMPLES = 500_000


def mesh_in_ras(name, pose):
    """A shipped bone mesh's vertices (V, 3) moved by ``pose`` into RAS, and its triangles (K, 3)."""
    vertices, triangles = _cached_mesh(name)
    return vertices @ pose[:3, :3].T + pose[:3, 3], triangles


@lru_cache(maxsize=4)
def _cached_mesh(name):
    from .package_data import bone_mesh

    return bone_mesh(name)


@lru_cache(maxsize=4)
def _mesh_samples(name):
    from scipy.spatial import cKDTree

    from .virtual_patient import sample_surface

    vertices, triangles = _cached_mesh(name)
    samples, normals = sample_surface(vertices, triangles, MESH_SAMPLES, np.random.default_rng(0))
    return samples, normals, cKDTree(samples)
