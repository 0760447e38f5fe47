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

Where the bone is thin, the opening takes it with the wire (family wide seed 40258: a fibula 8 mm thick in air, 770
IPC points on a 750 HU wire from it to the field of view's edge): a narrower opening (``THIN_RADIUS_MM``) is tried as
well, and where only what sticks out past ``PROTRUDES_MM`` is a line, its foot among the bone's slivers, that line is
taken if it leaves the bone (``LEAVES``); its foot stays, and the IPC points round it go with the base of what was
cut off (``ct_segmentation.CUT_BASE_MM``). Taken back to the bone along its axis, it took the fibula's slivers there
too (drawn seed 19027: a 6 mm bracket of 271 HU resting on a fibula in air, 96.3 -> 94.8 % of the bone covered).
"""

import logging

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from .morphology import block_any, dilate, erode, open_by_cube, unblock

logger = logging.getLogger(__name__)

#: The opening's half width (mm): parts thinner than twice this are looked at ...
RADIUS_MM = 2.0
#: ... and again with this one (mm) where the first keeps less than THIN_BONE_KEPT of the object: it took a thin bone
#: whole with the wire (family wide seed 40258: a fibula 8 mm thick in air, a 750 HU wire from it to the field of
#: view's edge; the first kept 3 % of it). Not elsewhere: on a flat bone 19 mm thick (40099), the narrower opening
#: took a wedge of it between the round field of view's edge and the last slice for a wire (1.5 % of it covered).
THIN_RADIUS_MM = 1.25
THIN_BONE_KEPT = 0.5
#: A wire sticks out of the rest of the bone by at least this (mm) ...
PROTRUDES_MM = 4.0
#: ... is at most this wide (the square root of its second principal variance, mm) ...
LINE_WIDTH_MM = 1.5
#: ... and its length (the same of its first) is at least this many times its width.
LINE_RATIO = 3.0
#: Where only what sticks out past PROTRUDES_MM is a line (its foot among slivers of a thin bone the opening took),
#: it leaves the bone: along its length its distance from what the opening keeps grows by at least this share of it
#: (30 degrees or more; a ribbon along a flat bone's edge, cut level by the reach, does not).
LEAVES = 0.5
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
    own_cells = None if own is None else block_any(own, block)
    size, thin = (2 * int(np.ceil(radius / cell.min())) + 1 for radius in (RADIUS_MM, THIN_RADIUS_MM))
    wire, kept = _wires_opened_by(coarse, own_cells, cell, size)
    if thin < size and kept < THIN_BONE_KEPT * coarse.sum():
        wire |= _wires_opened_by(coarse, own_cells, cell, thin)[0]
    if not wire.any():
        return np.zeros(mask.shape, dtype=bool)
    count = ndimage.label(wire, structure=np.ones((3, 3, 3), dtype=bool))[1]
    logger.info("%d wire(s) joined to the bone left out (%.0f mm^3)", count, wire.sum() * np.prod(cell))
    wire = mask & unblock(wire, block, mask.shape)
    return wire if own is None else wire & own


def _wires_opened_by(coarse, own_cells, cell, size):
    """(booleans like ``coarse``, the number of cells the opening keeps): the wires among what an opening by a cube
    ``size`` cells wide takes off ``coarse`` (the object on cells of ``cell`` (3,) mm; ``own_cells`` its own cells
    above the threshold, or None)."""
    wire = np.zeros(coarse.shape, dtype=bool)
    kept = open_by_cube(coarse, size)
    kept_cells = int(kept.sum())
    if not kept_cells:  # the bone is thinner than a wire everywhere: nothing to tell a wire from
        return wire, 0
    taken = coarse & ~dilate(kept)  # a cell off what is kept: the slivers off the bone's edges stay with it
    if own_cells is not None:
        taken &= own_cells
    labels, count = ndimage.label(taken, structure=np.ones((3, 3, 3), dtype=bool))
    if count == 0:
        return wire, kept_cells
    # Candidates stick out that far in the city-block metric (short of it along the diagonals); then measured.
    beyond = taken & ~dilate(kept, iterations=int(np.ceil(PROTRUDES_MM / cell.min())))
    boxes = ndimage.find_objects(labels)
    pieces = surface = None
    for label in np.unique(labels[beyond]):
        if not label:
            continue
        box = boxes[label - 1]
        corner = np.array([side.start for side in box])
        part = labels[box] == label
        where = (np.argwhere(part) + corner) * cell
        lines = [where] if _line_like(where, cell) else None  # the whole part taken is a line ...
        if lines is None:  # ... or what sticks out of it is, its foot among the bone's slivers (each piece in one part)
            if pieces is None:
                pieces, _ = ndimage.label(beyond, structure=np.ones((3, 3, 3), dtype=bool))
            in_box = pieces[box]
            lines = [(np.argwhere(in_box == piece) + corner) * cell for piece in np.unique(in_box[part]) if piece]
            lines = [line for line in lines if _line_like(line, cell)]
        for line in lines:
            if surface is None:
                surface = cKDTree(np.argwhere(kept & ~erode(kept)) * cell)
            out = surface.query(line)[0]
            if out.max() < PROTRUDES_MM:
                continue
            if line is where:
                wire[box] |= part
            elif np.ptp(out) >= LEAVES * np.ptp((line - line.mean(axis=0)) @ _principal_axis(line)):
                wire[tuple(np.round(line / cell).astype(int).T)] = True
    return wire, kept_cells


def _principal_axis(where):
    """(3,) the unit direction along which the points ``where`` (N, 3) spread most."""
    return np.linalg.eigh(np.cov(where.T))[1][:, -1]


def _line_like(where, cell):
    """Whether a component, its cells' positions ``where`` (N, 3) mm on cells of ``cell`` (3,) mm, is a line: narrow
    across its principal axis, long along it."""
    if len(where) < 4:
        return False
    spread = np.sqrt(np.maximum(np.linalg.eigvalsh(np.cov(where.T)), 0.0))  # ascending
    round_across = spread[1] <= 2.0 * spread[0] + 0.25 * cell.min()  # not a ribbon off a flat bone's edge
    return spread[1] <= LINE_WIDTH_MM and spread[2] >= LINE_RATIO * spread[1] and round_across
