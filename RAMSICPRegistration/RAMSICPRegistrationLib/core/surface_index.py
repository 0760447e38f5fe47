"""The image point cloud (IPC) with its KD-tree, built once and shared by every method and every scale L."""

import logging
from functools import cached_property

import numpy as np

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
        from scipy.spatial import cKDTree  # here, not at the top: the command line's --help must not wait for scipy

        self.name = name
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

    def check_covers(self, points, name="probe points"):
        """Raise ValueError unless the IPC samples the surface finely enough for the (N, 3) ``points`` (mm).

        An IPC must be a surface: to fit the surface under the probe points (their normals, eq. 9's closest
        points) the patch the points span must hold at least ``NORMAL_NEIGHBOURS`` IPC points, the neighbourhood
        one surface normal is estimated from. The patch is the points' extent along their two principal axes,
        ``a x b`` mm; an IPC whose median nearest-neighbour spacing is ``h`` holds about
        ``a b ln 2 / (pi h^2)`` points there (randomly placed surface points, for which that median spacing means a
        density of ``ln 2 / (pi h^2)``; a regular grid holds up to 4.5 times more, so the bound is on the safe
        side). The test needs no pose, so it runs before any registration.
        """
        points = np.asarray(points, dtype=np.float64)
        centred = points - points.mean(axis=0)
        axes = np.linalg.svd(centred, full_matrices=False)[2][:2]
        along, across = np.ptp(centred @ axes.T, axis=0)
        needed = NORMAL_NEIGHBOURS
        expected = along * across * np.log(2.0) / (np.pi * self.spacing_mm**2) if len(self) > 1 else 0.0
        if len(self) >= needed and expected >= needed:
            return
        widest = np.sqrt(along * across * np.log(2.0) / (np.pi * needed))
        raise ValueError(
            f"{self.name}: {len(self):,} points "
            + (f"{self.spacing_mm:.1f} mm apart (median) " if len(self) > 1 else "")
            + f"cannot be the surface under the {len(points)} {name}, which span {along:.0f} x {across:.0f} mm: "
            f"about {expected:.0f} IPC points lie there, and fitting the surface needs at least {needed} (the "
            f"neighbourhood of one surface normal). Give the bone's surface (ramsicp ipc writes it), with points "
            f"at most {widest:.1f} mm apart"
        )

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
