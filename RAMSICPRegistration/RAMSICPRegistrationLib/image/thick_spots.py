"""Where a marker sphere sunk into its frame may be: spots where the objects above the threshold are a ball thick.

A sphere sunk into a plate or frame brighter than itself (family seed 14087: spheres of 690 HU in a 5 mm plate of
1,900 HU) shows little of its edge: the Hough transform of ``sphere_candidates``, which looks for surfaces that get
brighter inward, finds its caps only, and no fit sees enough of it. Its ball still makes the body thicker there than
the frame is: the depth under the surface of what is above the threshold (a distance transform) peaks at its centre
at about its radius and falls off all round it as a ball's does, where a rod's axis or a bone's thick part makes a
ridge or a plateau. Those peaks are places to look for the tool's markers by their distances
(``marker_spheres._candidates_at_tool_distances``), for the bone's recognition only: they are not usable spheres.

The depth is taken on a grid of about ``GRID_MM`` (the fraction of each cell above the threshold, at least half).
"""

import numpy as np
from scipy import ndimage

from .sphere_candidates import block_means

#: The grid the depth is taken on (mm, about).
GRID_MM = 1.5
#: A sphere's peak depth, as a fraction of its radius (the grid and the frame it is sunk into shift it a little).
MIN_DEPTH = 0.7
MAX_DEPTH = 1.15
#: The cells within TOP_MM of the peak's depth make a ball's top: their centres no farther apart than MAX_TOP_MM
#: along any axis. A ball's top is 2 * TOP_MM wide, but on a grid of 1.5 mm and sunk off-centre into a plate the
#: top spreads to 6-7 mm (8 allowed); a rod's ridge or a slab's plateau runs on past the box of the top looked in.
TOP_MM = 1.0
MAX_TOP_MM = 8.0
#: At most this many spots, deepest first.
MAX_SPOTS = 24


def thick_spots(volume, segmentation, radius_mm):
    """(N, 3) RAS mm: the centres of the spots as thick as a ball of ``radius_mm`` (module docstring), deepest
    first; (0, 3) when there is none."""
    spacing = volume.spacing
    block = np.maximum(1, np.rint(GRID_MM / spacing)).astype(int)
    cell = spacing * block
    inside = block_means((segmentation.labels > 0).view(np.uint8), block) >= 0.5
    if not inside.any():
        return np.zeros((0, 3))
    depth = ndimage.distance_transform_edt(np.pad(inside, 1), sampling=cell)[1:-1, 1:-1, 1:-1]
    deepest = ndimage.maximum_filter(depth, size=3)
    peaks = np.argwhere((depth == deepest) & (depth >= MIN_DEPTH * radius_mm) & (depth <= MAX_DEPTH * radius_mm))
    peaks = peaks[np.argsort(-depth[tuple(peaks.T)])]
    peaks = peaks[_falling_off(depth, peaks, cell)]
    reach = np.ceil((MAX_TOP_MM + TOP_MM) / cell).astype(int) + 1
    centres = []
    for peak in peaks:
        low, high = np.maximum(peak - reach, 0), np.minimum(peak + reach + 1, depth.shape)
        local = depth[tuple(slice(a, b) for a, b in zip(low, high))]
        top, _ = ndimage.label(local >= depth[tuple(peak)] - TOP_MM)
        blob = top == top[tuple(peak - low)]
        cells = np.argwhere(blob)
        if ((cells.max(axis=0) - cells.min(axis=0)) * cell > MAX_TOP_MM).any():  # centre to centre
            continue  # a ridge or a plateau: a rod's axis, a thick bone, a frame as thick as a ball
        if (cells.min(axis=0) == 0).any() or (cells.max(axis=0) == np.array(local.shape) - 1).any():
            continue  # the top runs out of the box: wider still
        weights = local[blob]
        centre = (cells * weights[:, None]).sum(axis=0) / weights.sum() + low
        if any(np.linalg.norm((centre - other) * cell) < radius_mm for other in centres):
            continue  # a second peak on the same top
        centres.append(centre)
        if len(centres) == MAX_SPOTS:
            break
    if not centres:
        return np.zeros((0, 3))
    ijk = np.array(centres) * block + (block - 1) / 2.0 + segmentation.origin  # a cell's centre in the CT's voxels
    return volume.ijk_to_ras_points(ijk)


def _falling_off(depth, peaks, cell):
    """(P,) booleans: the ``peaks`` (P, 3) cells whose depth, half of MAX_TOP_MM and a cell away in each of the 26
    directions to the neighbouring cells, is more than TOP_MM below theirs: a quick test that drops the ridges and
    plateaus, which make most peaks, before their tops are measured."""
    keep = np.ones(len(peaks), dtype=bool)
    top = depth[tuple(peaks.T)] - TOP_MM
    for direction in np.ndindex(3, 3, 3):
        step = np.array(direction) - 1
        if not step.any():
            continue
        away = (MAX_TOP_MM / 2.0) / np.linalg.norm(step * cell) + 1.0  # in steps: half the top's width and a cell
        at = np.clip(peaks + np.ceil(away).astype(int) * step, 0, np.array(depth.shape) - 1)
        keep &= depth[tuple(at.T)] < top
    return keep
