"""What metal joins to the bone: the parts of the bone's object that meet the rest of it only through metal.

A metal bracket (a pin, a Schanz screw) inserted into the bone makes one object with whatever its other end touches
and lifts above the threshold: the blur and the streaks of 3,000 HU raise a plastic frame's hub (133 HU) to
250-500 HU round the bracket's end. The metal zone (``metal.py``) leaves out the surface within 3 mm of the metal and
in its own slices, but the hub reaches past both: family seed 18015, 31 IPC points on the reference body 30-34 mm
off the bone, 3.0-5.6 mm from the metal and a slice past its last.

Bone has no such part. Without the metal and its blurred edge (``METAL_EDGE_MM`` round every voxel brighter than
``METAL_HU``), the bone's object falls apart into the bone and what the metal joined to it; each piece within
``REACH_MM`` of the metal that was joined to the rest through it, and is smaller than ``SHARE`` of the rest of the
object, is not the bone's: its surface goes from the IPC with the metal zone's (``ct_segmentation.bone_surface``). A
nail or a screw through a bone leaves it whole round the metal's edge; a nail across a fracture joins two large
pieces, both of which stay. The pieces stay in the bone's mask: a piece of a bone's inside that a pin's edge cuts off
has no surface of its own, and taken out of the mask it would leave walls inside the bone.
"""

import logging

import numpy as np
from scipy import ndimage

from .hounsfield import METAL_HU
from .metal import METAL_EDGE_MM
from .morphology import bounding_box, dilate, labelled

logger = logging.getLogger(__name__)

#: A piece the metal joins to the rest of the bone's object is not the bone's when it is smaller than this share of
#: the rest of the object (a bone fragment across a nail is about as large as the other).
SHARE = 0.25
#: Pieces are looked for within this (mm) of the metal: one reaching farther goes on into the rest of the object, or
#: is too large to be a clamp or a hub (the bone's box of a C-arm CT, 6 million voxels, is labelled in 0.2-0.3 s).
REACH_MM = 20.0


def beyond_metal(mask, image, spacing):
    """(I, J, K) booleans: the voxels of ``mask`` (the bone's object) that the metal in ``image`` (denoised HU, the
    same grid) joins to the rest of it (the module docstring); ``spacing`` (3,) mm. None are when there is no metal,
    or when the object does not fall apart without it."""
    none = np.zeros(mask.shape, dtype=bool)
    metal = image >= METAL_HU
    if not metal.any():
        return none
    spacing = np.asarray(spacing, dtype=float)
    # The region looked at: within REACH_MM of the metal's box; and in it the metal's edge.
    low, high = bounding_box(metal, pad=np.ceil(REACH_MM / spacing).astype(int) + 1)
    region = tuple(slice(a, b) for a, b in zip(low, high))
    near_metal = metal[region]
    edge_low, edge_high = bounding_box(near_metal, pad=np.ceil(METAL_EDGE_MM / spacing).astype(int) + 1)
    edge_box = tuple(slice(a, b) for a, b in zip(edge_low, edge_high))
    edge = np.zeros(near_metal.shape, dtype=bool)
    edge[edge_box] = ndimage.distance_transform_edt(~near_metal[edge_box], sampling=spacing) <= METAL_EDGE_MM
    object_here = mask[region]
    pieces, count = ndimage.label(object_here & ~edge)
    if count < 2:
        return none
    sizes = np.bincount(pieces.ravel(), minlength=count + 1)
    # Pieces that reach a side of the region inside the object's box go on beyond it: not looked at.
    going_on = np.zeros(count + 1, dtype=bool)
    for axis in range(3):
        for side, inside in ((0, low[axis] > 0), (-1, high[axis] < mask.shape[axis])):
            if inside:
                going_on[np.unique(np.take(pieces, side, axis=axis))] = True
    # The pieces that touch the object's voxels in the metal's edge: the metal joined them to it.
    joined = np.zeros(count + 1, dtype=bool)
    joined[np.unique(pieces[dilate(object_here & edge) & (pieces > 0)])] = True
    small = sizes < SHARE * (int(mask.sum()) - sizes)
    chosen = np.flatnonzero(joined & ~going_on & small)  # never the background: it touches no voxel of the edge
    if len(chosen) == 0:
        return none
    beyond = none
    beyond[region] = labelled(pieces, chosen)
    logger.info(
        "%d part(s) joined to the bone only through metal (%.0f mm^3): their surface left out",
        len(chosen),
        beyond.sum() * np.prod(spacing),
    )
    return beyond
