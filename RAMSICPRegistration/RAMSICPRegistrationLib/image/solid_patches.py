"""Patches of the IPC over a solid part dimmer than the cortex: a rod resting on the bone, kept with it.

A rod or bar nearly as thick as the bone, resting on it, is not parted from it by any opening, and under heavy noise
no level is read to follow it (``body_material``): its surface stays in the IPC (fresh wide seed 57010 at 62 HU of
noise: a 9 mm round rod of 875 HU resting on a fibula whose cortex is 1,543 HU, 2,241 of the 7,042 IPC points on the
rod, exit 0). Across such a surface the CT has no cortex: its brightest value 0.5-2.5 mm in (``PEAK_MM``) is the
rod's own, dimmer than the bone's cortex, and 3-6 mm in (``INSIDE_MM``) the rod goes on as bright (solid). A bone's
surface has its cortex under it, the brightest layer: its peak is the cortex's, and 3-6 mm in lies marrow or
cancellous bone, or the bone's far side; a cortex thicker than 6 mm (a real shaft's) is solid there but as bright as
the cortex, so it is kept. Points with both, in patches of at least ``MIN_PATCH_POINTS`` on the mesh (a speck is
noise), are left out. Measured before it was built: 1,706-1,898 of 57010's 2,241 points on the rod for a peak share
of 0.6-0.7, none of 1.17 million points on the bone in 59 other family CTs.
"""

import logging
from dataclasses import replace

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from .ct_segmentation import along_gradient, downhill, without_vertices
from .ipc_self_check import bone_verdict_in_fine_voxels

logger = logging.getLogger(__name__)

#: The peak under a point: the CT's brightest value this far in (mm, from and to) along its gradient ...
PEAK_MM = (0.5, 2.5)
#: ... and the inside: its dimmest value this far in (mm).
INSIDE_MM = (3.0, 6.0)
#: ... read every this many mm.
STEP_MM = 0.5
#: Solid under a point: the peak less the inside below this (HU).
SOLID_UNDER_HU = 150.0
#: Dimmer than the cortex: the peak below the level plus this share of the cortex's rise above it (the level and the
#: cortex read as the medians over the IPC of the CT at its points and of their peaks).
DIMMER_SHARE = 0.65
#: Patches of fewer points on the mesh are kept.
MIN_PATCH_POINTS = 30
#: The IPC is looked at whole only when some of up to this many of its points, spread over it, are such points.
SAMPLES = 4000


def without_solid_patches(volume, segmentation, surface):
    """``surface`` (a ``ct_segmentation.BoneSurface``) without its patches over a solid part dimmer than the cortex
    (the module docstring), read in the segmentation's denoised CT. Unchanged in voxels coarser than
    ``bone_recognition.SOLID_MAX_VOXEL_MM`` (they blur a cortex away), when the object taken for bone has no cortex,
    and when no sampled point is such a point."""
    points = surface.points
    verdict = bone_verdict_in_fine_voxels(volume, segmentation)
    if verdict is None or verdict.verdict != "bone" or len(points) < MIN_PATCH_POINTS:
        return surface
    every = max(1, len(points) // SAMPLES)
    level, peak, inside = _across(volume, segmentation, points[::every])
    level, cortex = float(np.median(level)), float(np.median(peak))
    if not _solid_and_dimmer(peak, inside, level, cortex).any():
        return surface
    _, peak, inside = _across(volume, segmentation, points)
    flagged = _solid_and_dimmer(peak, inside, level, cortex)
    drop = _in_patches(surface.triangles, flagged, MIN_PATCH_POINTS)
    if not drop.any():
        return surface
    logger.info(
        "%d IPC points over a solid part dimmer than the cortex (%.0f HU, the level %.0f HU) left out",
        drop.sum(),
        cortex,
        level,
    )
    points, triangles = without_vertices(points, surface.triangles, drop)
    return replace(surface, points=points, triangles=triangles)


def _across(volume, segmentation, points):
    """(M,) each, HU: the denoised CT at RAS ``points`` (M, 3), its brightest value PEAK_MM in along the gradient, and
    its dimmest INSIDE_MM in."""
    vertices = volume.ras_to_ijk_points(points) - segmentation.origin
    image = segmentation.smoothed
    inward = -downhill(image, vertices, volume.spacing)
    depths = np.arange(0.0, INSIDE_MM[1] + 1e-6, STEP_MM)
    profile = along_gradient(image, vertices, inward, volume.spacing, depths)  # (D, M)
    peak = profile[(depths >= PEAK_MM[0]) & (depths <= PEAK_MM[1])].max(axis=0)
    inside = profile[(depths >= INSIDE_MM[0]) & (depths <= INSIDE_MM[1])].min(axis=0)
    return profile[0], peak, inside


def _solid_and_dimmer(peak, inside, level, cortex):
    """(M,) booleans: solid under the point (SOLID_UNDER_HU) and a peak dimmer than the cortex (DIMMER_SHARE)."""
    return (peak - inside < SOLID_UNDER_HU) & (peak < level + DIMMER_SHARE * (cortex - level))


def _in_patches(triangles, flagged, min_points):
    """(M,) booleans: the ``flagged`` vertices in connected patches (edges of ``triangles`` (K, 3) between flagged
    vertices) of at least ``min_points``."""
    inner = triangles[flagged[triangles].all(axis=1)]
    if not len(inner):
        return np.zeros_like(flagged)
    edges = np.concatenate([inner[:, [0, 1]], inner[:, [1, 2]], inner[:, [0, 2]]])
    graph = sparse.coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(len(flagged),) * 2)
    _, patch = csgraph.connected_components(graph, directed=False)
    sizes = np.bincount(patch[flagged], minlength=patch.max() + 1)
    return flagged & (sizes[patch] >= min_points)
