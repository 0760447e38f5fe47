"""What a plug over a hole in a bone's wall encloses (issue 27).

A bracket dimmer than the threshold (plastic, 100-200 HU) inserted into a bone makes a hole in its cortex, and
through it the marrow is one dark region with the outside: no fill finds the bone's inside. Plugged (the voxels
near the hole taken for walls), what the bone then encloses is its inside, in pieces large enough (``MIN_PLUGGED_MM3``)
that lie between the bone's sides (``PLUGGED_BETWEEN_SHARE``, ``between_sides``): not a pocket of air or tissue a
plug closes against the bone's outer surface. Two steps plug so: the IPC's inner walls (``ct_segmentation``,
plugged where a dim part meets the bone's blur) and the bone's recognition (``bone_recognition``, holes closed by
``PLUG_MM`` wherever they are, when the object has no cortex without it).
"""

import numpy as np
from scipy import ndimage

from .morphology import labelled

#: A hole in the cortex is plugged by the voxels within this (mm) of where a dim part meets the bone's blur
#: (``dim_parts``: cells of 1.5 mm, one cell past the blur round the bone's voxels, so up to 4.5 mm from them), and
#: the bone's recognition closes holes up to twice this wide.
PLUG_MM = 5.0
#: What a plug encloses is the bone's inside when at least this share of it has the bone (or the CT's edge, or the
#: padding) on both sides along two of the grid's axes at least: 1.00 for a tibia's marrow (35065), a flat bone's
#: inside (43004) and a long bone's (40088). Pockets of air the plugs closed against a flat bone's outer surface by a
#: metal bracket resting on it (family seed 12066: 47-97 mm^3, 0.00) took its surface there as inner walls: 648 IPC
#: points on the bone, 0.8 % of its coverage.
PLUGGED_BETWEEN_SHARE = 0.9
#: ... and at least this large (mm^3): the marrow behind a hole in a thin shaft is larger; a pocket of tissue closed
#: in a groove of a fibula's surface is not (35098: 36 mm^3, 1.00; grown into the plug, 226 IPC points on the bone
#: went with it, 2.2 % of its coverage).
MIN_PLUGGED_MM3 = 250.0


def inside_pieces(enclosed, between, voxel_mm3):
    """(I, J, K) booleans: the pieces of ``enclosed`` (booleans: what the bone encloses once plugged, less what it
    enclosed before) of at least MIN_PLUGGED_MM3 (``voxel_mm3``: the volume of a voxel or cell) with at least
    PLUGGED_BETWEEN_SHARE of their voxels ``between`` the bone's sides (booleans: on two axes, ``between_sides``)."""
    pieces, count = ndimage.label(enclosed)
    if count == 0:
        return enclosed
    sizes = np.bincount(pieces.ravel(), minlength=count + 1)
    large = sizes * float(voxel_mm3) >= MIN_PLUGGED_MM3
    kept = np.flatnonzero(large & (np.bincount(pieces[between], minlength=count + 1) >= PLUGGED_BETWEEN_SHARE * sizes))
    return labelled(pieces, kept[kept > 0])


def between_sides(mask, on_edge, padding, around=None):
    """(I, J, K) uint8 (or over the sub-box ``around``, 3 slices, the lines through it read whole): along how many of
    the grid's axes each voxel has ``mask`` on both sides (at any distance), or the CT's edge (``on_edge``: per axis,
    whether the box's low and high sides are the CT's) or the ``padding`` ((I, J) booleans, outside a round field of
    view, or None) where the bone is cut."""
    around = around or (slice(None),) * 3
    count = None
    for axis in range(3):
        lines = tuple(slice(None) if a == axis else around[a] for a in range(3))
        part = tuple(around[axis] if a == axis else slice(None) for a in range(3))
        line = mask[lines]
        before = np.logical_or.accumulate(line, axis=axis)[part]
        after = np.flip(np.logical_or.accumulate(np.flip(line, axis), axis=axis), axis)[part]
        if padding is not None and axis < 2:
            rows = padding[lines[:2]]
            before |= np.logical_or.accumulate(rows, axis=axis)[part[:2]][:, :, None]
            after |= np.flip(np.logical_or.accumulate(np.flip(rows, axis), axis=axis), axis)[part[:2]][:, :, None]
        both = (before | on_edge[axis][0]) & (after | on_edge[axis][1])
        count = both.astype(np.uint8) if count is None else count + both
    return count


def closed_holes(mask, spacing, reach_mm=PLUG_MM):
    """(I, J, K) booleans: what closing ``mask`` by a ball of ``reach_mm`` adds to it (``spacing`` (3,) mm per voxel
    or cell): holes and gaps in its walls up to twice that wide, and the grooves and corners of its outside as
    narrow. The volume's sides do not close anything: it is padded by the reach first."""
    spacing = np.asarray(spacing, dtype=float)
    pad = np.ceil(reach_mm / spacing).astype(int) + 1
    padded = np.pad(np.asarray(mask, dtype=bool), [(p, p) for p in pad])
    grown = ndimage.distance_transform_edt(~padded, sampling=spacing) <= reach_mm
    closed = ndimage.distance_transform_edt(grown, sampling=spacing) > reach_mm
    return closed[tuple(slice(p, -p) for p in pad)] & ~mask
