"""What metal joins to the bone: the parts of the bone's object that meet the rest of it only through metal.

A metal bracket (a pin, a Schanz screw) inserted into the bone makes one object with whatever its other end touches
and lifts above the threshold: the blur and the streaks of 3,000 HU raise a plastic frame's hub (133 HU) to
250-500 HU round the bracket's end. The metal zone (``metal.py``) leaves out the surface within 3 mm of the metal and
in its own slices, but the hub reaches past both: family seed 18015, 31 IPC points on the reference body 30-34 mm
off the bone, 3.0-5.6 mm from the metal and a slice past its last.

Bone has no such part. Without the metal and its blurred edge (``METAL_EDGE_MM`` round every voxel brighter than
``METAL_HU``), the bone's object falls apart into the bone and what the metal joined to it; each piece that was
joined to the rest through the metal, and is smaller than ``SHARE`` of the largest piece, is not the bone's. A nail
or a screw through a bone leaves it whole round the metal's edge; a plate across a fracture joins two large pieces,
both of which stay.
"""

import logging

import numpy as np
from scipy import ndimage

from .hounsfield import METAL_HU
from .metal import METAL_EDGE_MM
from .morphology import bounding_box, dilate, labelled

logger = logging.getLogger(__name__)

#: A piece the metal joins to the rest of the bone's object is not the bone's when it is smaller than this share of
#: the largest piece (a bone fragment across a plate is about as large as the other).
SHARE = 0.25


def beyond_metal(mask, image, spacing):
    """(I, J, K) booleans: the voxels of ``mask`` (the bone's object) that the metal in ``image`` (denoised HU, the
    same grid) joins to the rest of it (the module docstring); ``spacing`` (3,) mm. None are when there is no metal,
    or when the object does not fall apart without it."""
    none = np.zeros(mask.shape, dtype=bool)
    metal = image >= METAL_HU
    if not metal.any():
        return none
    spacing = np.asarray(spacing, dtype=float)
    low, high = bounding_box(metal, pad=np.ceil(METAL_EDGE_MM / spacing).astype(int) + 1)
    box = tuple(slice(a, b) for a, b in zip(low, high))
    edge = np.zeros(mask.shape, dtype=bool)
    edge[box] = ndimage.distance_transform_edt(~metal[box], sampling=spacing) <= METAL_EDGE_MM
    pieces, count = ndimage.label(mask & ~edge)
    if count < 2:
        return none
    sizes = np.bincount(pieces.ravel(), minlength=count + 1)
    sizes[0] = 0
    largest = int(np.argmax(sizes))
    # The pieces that touch the object's voxels in the metal's edge: the metal joined them to it.
    joined = np.unique(pieces[dilate(mask & edge) & (pieces > 0)])
    chosen = [int(label) for label in joined if label != largest and sizes[label] < SHARE * sizes[largest]]
    if not chosen:
        return none
    beyond = labelled(pieces, chosen)
    logger.info(
        "%d part(s) joined to the bone only through metal (%.0f mm^3) left out",
        len(chosen),
        beyond.sum() * np.prod(spacing),
    )
    return beyond
