"""Plateaus of one material: how the reference body is followed into what an opening kept with the bone (issue 27).

An opening cuts a bracket off the bone where the bracket is thinner than the bone (``bone_recognition``). A bracket
nearly as thick as the bone is not cut so: no opening parts them, and the cut keeps the bracket, or the part of the
frame next to it, with the bone. The IPC then holds the bracket's surface, with exit 0 (wide family seed 40245: 6,856
IPC points on a 15.8 mm bar of 670 HU resting on a flat bone 17.6 mm thick; 40248: a 17.9 mm rod of 2,096 HU inserted
into a flat bone 19.9 mm thick, the IPC the rod's).

But a bracket, a frame or a post is made of one material: its inside is a **plateau**, cells of one brightness (their
block means within BAND_HU of one level), and the plateau goes on across the cut into the body. A bone's inside is a
plateau too (marrow, cancellous bone), but a brighter cortex surrounds it. So the cells the cut kept near the body are
read for their levels (``levels_among``), and the plateau at a level that reaches the body (``plateau``; from the
cells at the level nearest the body where those nearest it lie in the blur: ``plateau_from_nearest``) is the body's
when the recognition's checks hold (``bone_recognition._ObjectShape._follow_body_material``).

The grid is the recognition's (cells of about 1 mm, block means of the denoised CT). Under a CT's heavier noise the
block means are too noisy for the flat neighbourhoods a level needs (``means_noise_hu``); they are then read from the
means averaged over each cell's neighbours (``averaged_means``).
"""

import numpy as np
from scipy import ndimage

from .morphology import _halves, box_max, box_sum, dilate, erode

#: The cells of a plateau have block means within this (HU) of its level.
BAND_HU = 80.0
#: Block means noisier than this (HU, ``means_noise_hu``) are read for levels from their average: a flat neighbourhood
#: (27 cells spanning at most BAND_HU) needs a noise of about a quarter of the band or less.
NOISY_HU = BAND_HU / 5
#: The median absolute difference of two independent Gaussian samples, in their standard deviations (sqrt(2) x
#: 0.6745).
_MEDIAN_DIFFERENCE_SIGMAS = 0.954
#: A level is read where at least this many flat cells (their 3 x 3 x 3 neighbourhood's means spanning at most
#: BAND_HU: inside a plateau, not in the blur between two) hold it.
MIN_LEVEL_CELLS = 5


def levels_among(mean_hu, cells, neighbours_among_cells=False):
    """The levels (HU) of the plateaus among ``cells`` (booleans over the grid of ``mean_hu``, (I, J, K) block means),
    the most common first, each more than BAND_HU from the others: the flat cells' means, in bins BAND_HU wide, each
    bin read as the median of its cells and its two neighbours' (a level on a bin's edge is read whole). With
    ``neighbours_among_cells``, a cell's neighbourhood is flat when its neighbours among the ``cells`` are (the cells
    deep in an object: the blur at its surface left out)."""
    if neighbours_among_cells:
        brightest = box_max(np.where(cells, mean_hu, -np.inf), 3)
        flat = brightest + box_max(np.where(cells, -mean_hu, -np.inf), 3) <= BAND_HU
    else:
        flat = box_max(mean_hu, 3) + box_max(-mean_hu, 3) <= BAND_HU  # the neighbourhood's maximum less its minimum
    values = mean_hu[cells & flat]
    if values.size < MIN_LEVEL_CELLS:
        return []
    bins = np.round(values / BAND_HU).astype(np.int64)
    found, counts = np.unique(bins, return_counts=True)
    levels = []
    for index in np.argsort(-counts, kind="stable"):
        if counts[index] < MIN_LEVEL_CELLS:
            break
        level = float(np.median(values[np.abs(bins - found[index]) <= 1]))
        if all(abs(level - other) > BAND_HU for other in levels):
            levels.append(level)
    return levels


def plateau(mean_hu, among, level, seeds):
    """(I, J, K) booleans: the plateau at ``level`` (HU) within ``among`` (cells) that reaches ``seeds`` (cells).

    The cells within BAND_HU of the level are eroded by a cell along the grid's axes (the blur between two materials,
    a shell a cell or two thick, drops out: a bone's cortex does not join a bracket's plateau to the bone's inside);
    the pieces of what is left that touch the seeds are grown back by a cell within the band.
    """
    band = among & (np.abs(mean_hu - level) <= BAND_HU)
    pieces, count = ndimage.label(erode(band))
    if count == 0:
        return np.zeros(band.shape, dtype=bool)
    reached = np.unique(pieces[dilate(seeds) & (pieces > 0)])
    return dilate(np.isin(pieces, reached), within=band) if reached.size else np.zeros(band.shape, dtype=bool)


def plateau_from_nearest(mean_hu, among, level, seeds, candidates, distance_mm, cell_mm):
    """``plateau`` from the ``seeds``; where it reaches none, the plateau that reaches the ``candidates`` (cells)
    within BAND_HU of the level nearest the body (within ``cell_mm`` of the nearest; ``distance_mm``: (I, J, K) the
    cells' distances to the body, mm), or an empty one when no candidate is at the level.

    The level was read among the candidates, so a plateau holds it there; the seeds (the cells nearest the body) may
    all lie in the blur and the margin a cut leaves (held-out wide CT 3112: a 12 mm square bar of 1,096 HU resting on a
    long bone whose cortex is 831 HU, its nearest cell at its level 3.6 mm from the body's side, beyond the seeds'
    3 mm: nothing followed, 907 IPC points on the bar)."""
    found = plateau(mean_hu, among, level, seeds)
    if found.any():
        return found
    at_level = candidates & (np.abs(mean_hu - level) <= BAND_HU)
    if not at_level.any():
        return found
    nearest = float(distance_mm[at_level].min())
    return plateau(mean_hu, among, level, candidates & (distance_mm <= nearest + cell_mm))


def means_noise_hu(mean_hu, cells):
    """The noise (HU, a standard deviation) of ``mean_hu`` ((I, J, K) block means) among ``cells`` (booleans): the
    median absolute difference between neighbours along the grid's axes that are both among the cells, over that of
    two Gaussian samples' difference (0.954 of their standard deviation); 0.0 where no two such cells meet. The steps
    between materials move the median little where the cells are mostly inside plateaus (a bone's deep cells)."""
    differences = []
    for axis in range(3):
        low, high = _halves(mean_hu.shape, axis, 1)
        both = cells[low] & cells[high]
        differences.append(np.abs(mean_hu[high][both].astype(np.float64) - mean_hu[low][both]))
    differences = np.concatenate(differences)
    return float(np.median(differences) / _MEDIAN_DIFFERENCE_SIGMAS) if differences.size else 0.0


def averaged_means(mean_hu, cells):
    """(I, J, K) float64: ``mean_hu`` with each of ``cells`` (booleans, an object's) given the mean over the cells of
    its 3 x 3 x 3 neighbourhood among ``cells`` (what lies outside the object, air, is not mixed in; the noise falls by
    up to about 5 times), the other cells as they are."""
    inside = cells.astype(np.float64)
    averaged = box_sum(mean_hu * inside) / np.maximum(box_sum(inside), 1.0)
    return np.where(cells, averaged, mean_hu)
