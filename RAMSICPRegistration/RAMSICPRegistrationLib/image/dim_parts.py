"""Where a part dimmer than the bone threshold meets the bone (issue 27).

A bracket, a frame or a post below the threshold (plastic, 100-200 HU) is none of the CT's objects, yet where one
rests on the bone or enters it, its blur and the bone's add up in the corner they make, and the bone's surface there
is lifted 0.5-2 mm off the bone into the part, with a cortex under it (family seed 19050: a 117 HU bracket resting
on a flat bone in 45 HU tissue, 5 IPC points 0.50-0.53 mm off it; 23093, 24058, 25047, 26070 alike).

Such parts are found on a grid of CELL_MM cells, each as bright as its mean (the noise averages out): outside the
bone's blur (HALO_CELLS round the bone and all it encloses), the cells brighter than what the bone touches (the median
of the cells next to that blur) by BRIGHTER_HU, or by NOISE_SIGMAS times those cells' spread when the CT is noisier.
A group of them next to the blur that sticks out of it (STICKS_OUT_CELLS) is a part meeting the bone, unless it meets
it over more than MAX_CONTACT_MM2 (soft tissue round the bone, not a bracket's end). Within MARGIN_MM of where it
meets the blur, the bone's surface points that touch something brighter than the rest of the surface touches are
left out (``ct_segmentation.bone_surface``, with the corner's). Over the 1,300 family CTs: 60 IPC points on the body
in 25 CTs -> 17 in 8, none gained; 10,982 of the 27.25 million on the bone left out in 295 CTs, at most 498 in one
(18079: a metal frame's streaks in the air round the bone taken for a part).
"""

import logging

import numpy as np
from scipy import ndimage

from .morphology import block_max, block_mean

logger = logging.getLogger(__name__)

#: The grid (mm).
CELL_MM = 1.5
#: The bone's blur (cells brighter than what it touches, round any bone) reaches this many cells beyond its voxels.
HALO_CELLS = 1
#: A part is brighter than what the bone touches by at least this (HU): the dimmest brackets of the family are 50-70
#: HU above their tissue (18026: 123 against 69 HU; 26070: 101 against 44 HU) ...
BRIGHTER_HU = 30.0
#: ... and by this many times the spread of the cells next to the blur (1.4826 times their median absolute deviation).
NOISE_SIGMAS = 4.0
#: ... the spread of the cells next to the blur within this (HU) of their median (tissue, not air beyond a thin layer).
ALIKE_HU = 200.0
#: A part reaches at least this many cells beyond the cells next to the blur.
STICKS_OUT_CELLS = 1
#: ... and meets the blur over at most this (mm^2, its cells there times a cell's face): a dim bracket 16-18 mm wide
#: inserted into a bone in air meets it over 713-1,159 mm^2 (wide seeds 40138, 40272: at 400, the walls of its hole in
#: the cortex stayed in the IPC, 58 and 154 points on the body; 43049, a 14 mm bar resting on a bone: 44).
MAX_CONTACT_MM2 = 1600.0
#: IPC points within this (mm) of a part's cells next to the blur are looked at (the corner's, when they touch it:
#: ``ct_segmentation.bone_surface``).
MARGIN_MM = 6.0

_CUBE = np.ones((3, 3, 3), dtype=bool)


def dim_parts_at_bone(smoothed, bone, bone_low, spacing):
    """(N, 3) indices in ``smoothed`` (cell centres, fractional) where parts dimmer than the bone meet its blur, or an
    empty array.

    Args:
        smoothed: (I, J, K) denoised HU.
        bone: (I', J', K') booleans, the bone and all it encloses, over a box at ``bone_low`` (3,) in ``smoothed``.
        spacing: (3,) voxel size (mm).
    """
    if not bone.any():
        return np.empty((0, 3))
    spacing = np.asarray(spacing, float)
    block = np.maximum(1, np.rint(CELL_MM / spacing)).astype(int)
    # The bone's box and the cells round it, on whole cells.
    around = (HALO_CELLS + STICKS_OUT_CELLS + 4) * block
    low = np.maximum(np.asarray(bone_low) - around, 0)
    high = np.minimum(np.asarray(bone_low) + bone.shape + around, smoothed.shape)
    high = low + (high - low) // block * block
    if (high <= low).any():
        return np.empty((0, 3))
    means = block_mean(smoothed[tuple(slice(a, b) for a, b in zip(low, high))], block)
    placed = np.zeros(tuple(high - low), dtype=bool)
    start = np.asarray(bone_low) - low
    end = np.minimum(start + bone.shape, placed.shape)
    placed[tuple(slice(a, b) for a, b in zip(start, end))] = bone[tuple(slice(0, b - a) for a, b in zip(start, end))]
    bone_cells = block_max(placed, block)
    halo = ndimage.binary_dilation(bone_cells, _CUBE, iterations=HALO_CELLS)
    next_to = ndimage.binary_dilation(halo, _CUBE) & ~halo
    if not next_to.any():
        return np.empty((0, 3))
    touches = float(np.median(means[next_to]))
    alike = means[next_to][np.abs(means[next_to] - touches) <= ALIKE_HU]
    spread = 1.4826 * float(np.median(np.abs(alike - np.median(alike)))) if len(alike) else 0.0
    passable = (means > touches + max(BRIGHTER_HU, NOISE_SIGMAS * spread)) & ~halo
    regions, count = ndimage.label(passable, structure=_CUBE)
    if count == 0:
        return np.empty((0, 3))
    contact = passable & next_to
    out = passable & ~ndimage.binary_dilation(halo, _CUBE, iterations=1 + STICKS_OUT_CELLS)
    face_mm2 = float(np.prod(np.sort(spacing * block)[:2]))
    contacts = np.bincount(regions[contact], minlength=count + 1)
    outs = np.bincount(regions[out], minlength=count + 1)
    parts = np.nonzero((contacts > 0) & (outs > 0) & (contacts * face_mm2 <= MAX_CONTACT_MM2))[0]
    parts = parts[parts > 0]
    if len(parts) == 0:
        return np.empty((0, 3))
    cells = np.argwhere(contact & np.isin(regions, parts))
    logger.info(
        "%d part(s) brighter than what the bone touches (%.0f HU) by %.0f HU meet it over %d cells",
        len(parts),
        touches,
        max(BRIGHTER_HU, NOISE_SIGMAS * spread),
        len(cells),
    )
    return cells * block + (block - 1) / 2.0 + low
