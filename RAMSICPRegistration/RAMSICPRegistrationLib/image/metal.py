"""Metal in the CT (an implant, a nail, a pin) and the part of the image its artefacts spoil for the IPC.

Metal is whatever is brighter than any bone after the denoising (``METAL_HU``). Next to it the CT cannot be
trusted, for two reasons, so the IPC leaves out the bone surface in a **metal zone** made of:

* the metal itself and ``METAL_MARGIN_MM`` around it (at least 2 voxels): the metal's own surface and its
  blooming, which would put the implant into the IPC;
* in the slices that hold metal (and one slice either side), everything within ``STREAK_REACH_MM`` of the metal
  in the slice: streaks (photon starvation and beam hardening) lie in the scan planes, and they raise soft tissue
  above the bone threshold (false surface) or lower cortex below it (holes and false inner walls).

``STREAK_REACH_MM`` was measured on the TotalSegmentator example CT (its left femur holds metal, by its shape a
nail with a screw into the femoral head): in the slices through the metal, the soft tissue's spread around its
local median is 34-95 HU at 10-20 mm from the metal and 22-55 HU at 20-30 mm, against 15-27 HU in slices
without metal; beyond 30 mm it stays under 40 HU, a quarter of the 160 HU between soft tissue and the 200 HU bone
threshold (``Documentation/metal_streak_reach.py``). The slices are the volume's k axis (the scanner's axial
planes for a CT stored as it was acquired).
"""

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .hounsfield import METAL_HU

#: The metal's blooming and edge: surface within this of it (mm, and at least 2 voxels) is left out.
METAL_MARGIN_MM = 3.0
#: In the metal's own slices, surface within this of it (mm) is left out (streaks).
STREAK_REACH_MM = 30.0
#: The blurred edge of metal reaches this far (mm) into what is round it.
METAL_EDGE_MM = 2.5


@dataclass(frozen=True)
class MetalZone:
    """The metal in a CT and the zone around it where the IPC is left out (see the module docstring).

    Attributes:
        metal_mm3: volume of the metal (mm^3); 0 when there is none.
        centre: (3,) RAS centre of the metal (mm), or None.
        margin_mm, reach_mm: the 3-D margin and the in-slice streak reach used.
        metal_ijk: (M, 3) voxel indices of the metal.
        spacing: (3,) voxel size (mm) of the grid they index.
    """

    metal_mm3: float
    centre: np.ndarray
    margin_mm: float
    reach_mm: float
    metal_ijk: np.ndarray
    spacing: np.ndarray

    @property
    def found(self):
        return self.metal_mm3 > 0

    def contains_ijk(self, ijk):
        """(N,) booleans: which points given by (N, 3) voxel indices (may be fractional) lie in the zone."""
        ijk = np.asarray(ijk, dtype=np.float64).reshape(-1, 3)
        inside = np.zeros(len(ijk), dtype=bool)
        if not self.found or len(ijk) == 0:
            return inside
        # The grid's axes are orthogonal, so index times spacing is a distance-preserving frame (mm).
        metal_mm = self.metal_ijk * self.spacing
        points_mm = ijk * self.spacing
        distance, _ = cKDTree(metal_mm).query(points_mm, distance_upper_bound=self.margin_mm)
        inside |= np.isfinite(distance)
        slices = np.rint(ijk[:, 2]).astype(np.int64)
        metal_slices = self.metal_ijk[:, 2]
        for k in np.intersect1d(np.unique(slices), np.unique(np.concatenate([metal_slices + d for d in (-1, 0, 1)]))):
            near = np.abs(metal_slices - k) <= 1
            here = np.flatnonzero(slices == k)
            distance, _ = cKDTree(metal_mm[near, :2]).query(points_mm[here, :2], distance_upper_bound=self.reach_mm)
            inside[here[np.isfinite(distance)]] = True
        return inside

    def contains(self, volume, points):
        """(N,) booleans: which (N, 3) RAS points lie in the zone."""
        return self.contains_ijk(volume.ras_to_ijk_points(points))


def find_metal_zone(volume, smoothed, metal_hu=METAL_HU, reach_mm=STREAK_REACH_MM, near=None, origin=(0, 0, 0)):
    """The metal in a denoised CT and its zone.

    Args:
        smoothed: denoised HU over a box of ``volume``'s grid whose first voxel is ``origin`` (3,) (the whole
            grid by default).
        near: optional (low, high) corners, in ``smoothed``'s indices, of the region the zone will be asked about
            (the bone's box); metal is then looked for there and as far around it as the zone reaches, not
            everywhere.

    The zone's ``metal_ijk`` are indices in the whole CT.
    """
    spacing = volume.spacing
    margin = max(METAL_MARGIN_MM, 2.0 * float(spacing.max()))
    low, high = np.zeros(3, dtype=int), np.array(smoothed.shape)
    if near is not None:
        reach = np.ceil(np.array([max(reach_mm, margin)] * 2 + [margin]) / spacing).astype(int) + 1
        low = np.maximum(np.asarray(near[0]) - reach, 0)
        high = np.minimum(np.asarray(near[1]) + reach, high)
    metal_ijk = np.argwhere(smoothed[tuple(slice(a, b) for a, b in zip(low, high))] >= metal_hu) + low
    metal_ijk = metal_ijk + np.asarray(origin, dtype=int)
    return MetalZone(
        metal_mm3=float(len(metal_ijk) * np.prod(spacing)),
        centre=volume.ijk_to_ras_points(metal_ijk.mean(axis=0)[None])[0] if len(metal_ijk) else None,
        margin_mm=margin,
        reach_mm=reach_mm,
        metal_ijk=metal_ijk,
        spacing=np.asarray(spacing, dtype=np.float64),
    )
