"""Wires and thin rods joined to the bone: narrow, straight things that stick out of it (a K-wire, a lead, a thin
bracket with nothing to say it is the reference body's).

A wire bright enough to pass the threshold that touches the bone, or runs through it, is one object with it, and its
surface went into the IPC: 400-1,100 points 13-32 mm off the bone on average (up to 72 mm) in family seeds 14062,
15014, 15094 and 16088, wires 0.6-2.4 mm wide. Bone has no such part. What an opening by a cube ``2 * RADIUS_MM``
wide takes off the bone (on a grid of about GRID_MM), a cell or more away from what the opening keeps, is a wire
when it is a line (across its principal axis at most LINE_WIDTH_MM wide and about as wide one way as the other;
along it at least LINE_RATIO times that) and sticks out of what is kept by PROTRUDES_MM or more. A thin flat bone
the opening takes whole is a plate, a ribbon off a flat bone's edge is flat across (16009), and the slivers an
opening takes off a bone's edges lie within a cell of what is left: none of them is touched. A rod up to about 7 mm
wide at a slant to the grid does not hold the cube either (14020: a 715 HU bracket resting on a tibia, the rest of the
body out of view or below the threshold).
"""

import logging

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from .morphology import block_any, dilate, erode, labelled, open_by_cube, unblock

logger = logging.getLogger(__name__)

#: The opening's half width (mm): parts thinner than twice this are looked at.
RADIUS_MM = 2.0
#: A wire sticks out of the rest of the bone by at least this (mm) ...
PROTRUDES_MM = 4.0
#: ... is at most this wide (the square root of its second principal variance, mm) ...
LINE_WIDTH_MM = 1.5
#: ... and its length (the same of its first) is at least this many times its width.
LINE_RATIO = 3.0
#: The grid the opening works on is about this coarse (mm): each axis a whole number of the CT's voxels.
GRID_MM = 1.0


def wires_on_bone(mask, spacing, own=None):
    """(I, J, K) booleans: the voxels of ``mask`` (the bone's object, its inside filled) that belong to a wire
    joined to it (the module docstring); ``spacing`` (3,) mm; ``own`` (booleans like ``mask``, optional): the
    object's own voxels, above the threshold: a wire is made of them, never of the inside filled. The wire's first
    voxels next to the bone stay the bone's (within a grid cell of what the opening keeps)."""
    spacing = np.asarray(spacing, dtype=float)
    block = np.maximum(1, np.floor(GRID_MM / spacing + 1e-6)).astype(int)
    cell = spacing * block
    coarse = block_any(mask, block)
    size = 2 * int(np.ceil(RADIUS_MM / cell.min())) + 1
    kept = open_by_cube(coarse, size)
    if not kept.any():  # the bone is thinner than a wire everywhere: nothing to tell a wire from
        return np.zeros(mask.shape, dtype=bool)
    taken = coarse & ~dilate(kept)  # a cell off what is kept: the slivers off the bone's edges stay with it
    if own is not None:
        taken &= block_any(own, block)
    labels, count = ndimage.label(taken, structure=np.ones((3, 3, 3), dtype=bool))
    if count == 0:
        return np.zeros(mask.shape, dtype=bool)
    # Candidates stick out that far in the city-block metric (short of it along the diagonals); then measured.
    reach = dilate(kept, iterations=int(np.ceil(PROTRUDES_MM / cell.min())))
    candidates = {label: np.argwhere(labels == label) * cell for label in np.unique(labels[taken & ~reach]) if label}
    lines = {label: where for label, where in candidates.items() if _line_like(where, cell)}
    if lines:
        surface = cKDTree(np.argwhere(kept & ~erode(kept)) * cell)
        lines = {label: where for label, where in lines.items() if surface.query(where)[0].max() >= PROTRUDES_MM}
    if not lines:
        return np.zeros(mask.shape, dtype=bool)
    wire = labelled(labels, list(lines))
    logger.info("%d wire(s) joined to the bone left out (%.0f mm^3)", len(lines), wire.sum() * np.prod(cell))
    wire = mask & unblock(wire, block, mask.shape)
    return wire if own is None else wire & own


def _line_like(where, cell):
    """Whether a component, its cells' positions ``where`` (N, 3) mm on cells of ``cell`` (3,) mm, is a line: narrow
    across its principal axis, long along it."""
    if len(where) < 4:
        return False
    spread = np.sqrt(np.maximum(np.linalg.eigvalsh(np.cov(where.T)), 0.0))  # ascending
    round_across = spread[1] <= 2.0 * spread[0] + 0.25 * cell.min()  # not a ribbon off a flat bone's edge
    return spread[1] <= LINE_WIDTH_MM and spread[2] >= LINE_RATIO * spread[1] and round_across
