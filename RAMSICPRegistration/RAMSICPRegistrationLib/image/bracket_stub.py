"""The stub of a bracket that the cut between the bone and the reference body left on the bone.

``bone_recognition`` cuts the body off the bone on cells of about a millimetre, where a rod leaves the bone: the
bracket's first millimetres, up to the opening that cut it and a cell or two, stay with the bone, and more where the
bracket is as bright as the cortex. Their surface is the bracket's: IPC points 1-6 mm off the bone (family seeds
11019, 11075, 12023, 12064: 150-300 points each).

The stub is the bone's part thinner than the bracket next to the body: what an opening by a ball a little wider
than the bracket's end (its radius, read off the body's voxels where they meet the bone) takes off the bone, in the
pieces that touch the body. A bone thinner than the bracket is not taken: such a piece is larger than a stub.
"""

import numpy as np
from scipy import ndimage

from .morphology import dilate

#: The bracket's end is read off the body's voxels within this far (mm) of the bone.
END_MM = 8.0
#: The opening's ball is this much (mm) wider than the bracket's radius there, and at most MAX_RADIUS_MM.
MARGIN_MM = 1.0
MAX_RADIUS_MM = 6.5
#: A stub is at most this long (mm) from the body: a longer thin piece is the bone's own.
MAX_LENGTH_MM = 12.0


def bracket_stub(mask, body, spacing):
    """(I, J, K) booleans over a box: the voxels of the bone (``mask``) that are the stub of the bracket whose rest
    is ``body`` (the body's voxels cut off the bone, same box); ``spacing`` (3,) mm. All False when there is none."""
    stub = np.zeros(mask.shape, dtype=bool)
    if not body.any() or not mask.any():
        return stub
    spacing = np.asarray(spacing, float)
    reach = np.ceil((MAX_LENGTH_MM + MAX_RADIUS_MM) / spacing).astype(int) + 2
    joined = body & dilate(mask, iterations=2)  # where the body meets the bone (two voxels)
    if not joined.any():
        return stub
    where = np.argwhere(joined)
    low = np.maximum(where.min(axis=0) - reach, 0)
    high = np.minimum(where.max(axis=0) + reach + 1, mask.shape)
    box = tuple(slice(a, b) for a, b in zip(low, high))
    bone, rest = mask[box], body[box]
    # The bracket's radius where it meets the bone: the depth of the body's voxels near the bone.
    to_bone = ndimage.distance_transform_edt(~bone, sampling=spacing)
    depth = ndimage.distance_transform_edt(rest, sampling=spacing)
    end = rest & (to_bone <= END_MM)
    if not end.any():
        return stub
    radius = min(float(depth[end].max()) + MARGIN_MM, MAX_RADIUS_MM)
    # An opening by a ball of that radius (two distance transforms): the bone's parts thinner than it go.
    core = ndimage.distance_transform_edt(bone, sampling=spacing) > radius
    opened = ndimage.distance_transform_edt(~core, sampling=spacing) <= radius
    thin, count = ndimage.label(bone & ~opened)
    if count == 0:
        return stub
    touching = np.unique(thin[dilate(rest) & (thin > 0)])
    from_body = ndimage.distance_transform_edt(~rest, sampling=spacing)
    for label in touching:
        piece = thin == label
        if from_body[piece].max() <= MAX_LENGTH_MM:
            stub[box] |= piece
    return stub
