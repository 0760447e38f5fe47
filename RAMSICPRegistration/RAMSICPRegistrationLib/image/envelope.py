"""The bone's envelope: the bone with every cavity it encloses once holes a bracket made in its cortex are plugged.

A bracket inserted into the bone (the paper's set-up) makes a hole through the cortex. When the bracket is dimmer
than the surface level (plastic, 100-200 HU), the marrow behind the hole is joined to the outside through it: the
3-D fill of ``ct_segmentation._enclosed`` finds no inside, and a cavity wider than ``MAX_CAVITY_MM`` (a tibia's
metaphysis) is not enclosed along the grid's lines either, so the marrow's wall stays in the IPC (6,000-10,000 points
2-2.6 mm inside the bone in the family CTs 12042 and 12190, the bracket 4.8 and 9 mm wide at 140-170 HU).

Closed by a cube ``HOLE_MM`` wide, the bone's mask has no such hole; what it then encloses (the dark regions that
reach none of the box's open sides) is its inside, and the envelope is the closed mask with it. It is made on cells of
about ``CELL_MM`` (a closing that wide is cheap there) and is used to tell an inner wall (``_facing_inward``: its dimmer
side lies in the envelope), never to move the surface: where the closing also fills a notch of the outer surface
narrower than ``HOLE_MM``, the notch's surface is left out of the IPC (up to its mouth where the notch is thicker
than 3 cells, as a hole's plug is kept: 0.01 % of the IPC points on the bone in the family CTs), and no point is
added.
"""

import numpy as np
from scipy import ndimage

from .morphology import block_any, dilate_by_cube, labelled, open_by_cube, unblock

#: Holes in the cortex narrower than this (mm) are plugged (the family's brackets are 4-12 mm wide).
HOLE_MM = 14.0
#: The envelope is made on cells about this wide (mm).
CELL_MM = 1.0


def bone_envelope(mask, open_sides, spacing, padding=None):
    """(I, J, K) booleans over a box: the bone (``mask``) and all it encloses once holes up to HOLE_MM wide are
    plugged. None when the box has no side off the CT's edge (nothing can be told outside).

    Args:
        mask: (I, J, K) booleans, the bone's voxels (and its inside found so far) in a box round it.
        open_sides: [(axis, 0 or -1)], the box's sides that are not the CT's edge (the bone does not reach them).
        spacing: (3,) voxel size (mm).
        padding: (I, J) booleans, outside a round field of view (where the bone is cut, no outside either), or None.
    """
    if not open_sides:
        return None
    block = np.maximum(1, np.rint(CELL_MM / np.asarray(spacing, float))).astype(int)
    cells = block_any(mask, block)
    width = int(np.rint(HOLE_MM / CELL_MM)) | 1
    # Beyond the box the bone goes on as it crosses the box's side (where the field of view cuts it; elsewhere the
    # box's margin is empty): a closing of the box alone would fill a band along the cut.
    grown = np.pad(cells, width, mode="edge")
    inner = (slice(width, -width),) * 3
    closed = ~dilate_by_cube(~dilate_by_cube(grown, width), width)[inner]
    dark = ~closed
    if padding is not None:
        dark &= ~block_any(padding[:, :, None], np.array([block[0], block[1], 1]))
    labels, count = ndimage.label(dark)
    outside = np.concatenate([np.unique(np.take(labels, side, axis=axis)) for axis, side in open_sides])
    enclosed = closed | labelled(labels, np.setdiff1d(np.arange(1, count + 1), outside))
    # The cells reach up to one cell past the bone: one cell less all round, and the bone's own voxels. A plug the
    # closing put in a hole (its part thicker than 3 cells) keeps that cell: it reaches the hole's mouth, so the
    # wall there faces into it (family seeds 14026, 20099: 58 and 49 IPC points on the walls of a dim bracket's
    # hole, 0.5-2 mm under the bone's surface, where the trimmed plug did not reach).
    enclosed = ~dilate_by_cube(~enclosed, 3) | open_by_cube(closed & ~cells, 3)
    return mask | unblock(enclosed, block, mask.shape)
