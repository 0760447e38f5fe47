"""The image point cloud (IPC) with its KD-tree, built once and shared by every method and every scale L."""

import logging
from functools import cached_property

import numpy as np
from scipy.spatial import cKDTree

from .validation import as_points

logger = logging.getLogger(__name__)

#: Neighbours used to estimate a surface normal at an IPC point (principal component analysis).
NORMAL_NEIGHBOURS = 16


class SurfaceIndex:
    """The IPC ``Y`` of the paper: (M, 3) surface points in image coordinates (mm) and their KD-tree.

    Building the tree is the one expensive step (about 0.05 s for 200,000 points); build one ``SurfaceIndex``
    per IPC and pass it to every registration, every method and every L of a sweep.
    """

    def __init__(self, points, name="IPC"):
        self.points = as_points(points, name, min_count=3)
        # An unbalanced tree without compacted nodes builds about twice as fast and answers as fast here.
        self.tree = cKDTree(self.points, balanced_tree=False, compact_nodes=False)
        self._normals = None  # (M, 3), filled point by point as normals are asked for (``_normal_known``)
        self._normal_known = None
        logger.debug("KD-tree built over %d IPC points", len(self.points))

    def __len__(self):
        return len(self.points)

    @cached_property
    def long_axis(self):
        """Unit direction (3,) of the IPC's largest extent: the long axis of a long bone (computed once)."""
        sample = self.points[:: max(1, len(self.points) // 20000)]
        return np.linalg.svd(sample - self.points.mean(axis=0), full_matrices=False)[2][0]

    @cached_property
    def spacing_mm(self):
        """Median distance (mm) from an IPC point to its nearest neighbour: the IPC's resolution (computed once)."""
        sample = self.points[:: max(1, len(self.points) // 20000)]
        distances, _ = self.tree.query(sample, k=2)
        return float(np.median(distances[:, 1]))

    def nearest(self, query):
        """Closest IPC point to each (N, 3) query point: returns distances (N,) in mm and indices (N,)."""
        distances, indices = self.tree.query(query)
        return distances, indices

    def normals(self, indices):
        """Unit surface normals (N, 3) at IPC points ``indices``, by PCA of their nearest neighbours.

        Each point's normal is computed once, when first asked for, and kept (like the tree, it belongs to the
        IPC): the iterations of a registration and later registrations on the same IPC reuse it.
        The sign of each normal is arbitrary; only the line it spans is meaningful.
        """
        indices = np.asarray(indices, dtype=np.intp)
        if self._normals is None:  # allocated untouched: only the points asked for are ever written or read
            self._normals = np.empty((len(self.points), 3))
            self._normal_known = np.zeros(len(self.points), dtype=bool)
        missing = ~self._normal_known[indices]
        if missing.any():
            new = np.unique(indices[missing])
            self._normals[new] = self._pca_normals(new)
            self._normal_known[new] = True
        return self._normals[indices]

    def _pca_normals(self, indices):
        neighbour_count = min(NORMAL_NEIGHBOURS, len(self.points))
        _, neighbours = self.tree.query(self.points[indices], k=neighbour_count)
        patches = self.points[neighbours]
        centred = patches - patches.mean(axis=1, keepdims=True)
        covariances = np.einsum("nki,nkj->nij", centred, centred)
        _, eigenvectors = np.linalg.eigh(covariances)
        return eigenvectors[:, :, 0]
