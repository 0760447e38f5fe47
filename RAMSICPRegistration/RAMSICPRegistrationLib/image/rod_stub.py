"""A long stub of a bracket left on the bone: the cut went through the bracket far from the bone.

``bone_recognition`` cuts the reference body off the bone where the openings first part them. When the bone kept at
the first opening is a small piece of it (a flat bone whose half-thickness is just over an opening's radius) and the
rest of the bone grows back at the next opening together with a bracket about as thick as the bone, the bracket is
kept with the bone up to where its core meets the body's seeds: a rod 10-30 mm long standing on the bone, whose
surface becomes IPC points (held-out draws: a 7 mm square bar inserted into a 9 mm flat bone, 231 points up to 9 mm
above it; a 15 mm square bar resting on a 28 mm tibia, 1,478 points up to 21 mm above it). The stub is too long for
``bracket_stub`` (MAX_LENGTH_MM) and, on a bone no thicker than the bracket, no opening takes it off.

Such a stub is the bracket's prism: where the body meets the bone (the junction, a cross-section of the bracket),
the bone goes on along the junction's normal with the same cross-section and the bracket's brightness on its axis.
It is followed until the bone widens round it (the bone's own surface) or its axis leaves the bracket's brightness
(``rod_stub``). A junction that is no cross-section of a rod (a plate or a bracket resting along the bone: the bone
widens at once) gives no stub.
"""

import numpy as np
from scipy import ndimage

from .bracket_stub import along_and_across, bracket_band
from .morphology import bounding_box, dilate

#: The junction (where the body meets the bone) is read from at most this many of its pieces, the largest first,
#: each of at least MIN_JUNCTION voxels.
JUNCTIONS = 3
MIN_JUNCTION = 10
#: A rod's cross-section is at most this far (mm) from its axis: a 15 mm square bar's corner is 10.6 mm from it.
MAX_FOOTPRINT_MM = 12.0
#: The stub is followed at most this far (mm) from the junction, in steps of STEP_MM (a voxel, if coarser); over the
#: bone's voxels within FIRST_REACH_MM first (most junctions end at once: the cut was at the bone).
MAX_LENGTH_MM = 60.0
FIRST_REACH_MM = 12.0
STEP_MM = 0.5
#: The bone round the rod: its voxels INNER_MM to OUTER_MM beyond the rod's cross-section (mm). The rod has ended
#: where they are at least WIDENS of the rod's voxels in a step (at least MIN_WIDENING voxels).
INNER_MM = 1.0
OUTER_MM = 4.0
WIDENS = 0.25
MIN_WIDENING = 3
#: The rod's axis is fitted again at most this many times to the junction and the rod walked so far.
REFITS = 3
#: ... by at most MAX_LEAN_DEGREES off the junction's normal.
MAX_LEAN_DEGREES = 30.0
#: A rod at least this long (mm) is a stub; a shorter one is the bracket's foot, which ``bracket_stub`` takes.
MIN_STUB_MM = 2.0


def rod_stub(mask, body, spacing, image):
    """(I, J, K) booleans over ``mask``'s box: the bone's voxels (``mask``) that are a long stub of the bracket whose
    rest is ``body`` (the reference body's voxels cut off the bone, same box); ``spacing`` (3,) mm; ``image`` the
    CT (HU) over the same box. All False when there is none."""
    stub = np.zeros(mask.shape, dtype=bool)
    if not body.any() or not mask.any():
        return stub
    spacing = np.asarray(spacing, float)
    # Where the body meets the bone, over the body's box only (a few % of the bone's).
    low, high = bounding_box(body, pad=3)
    near_body = tuple(slice(a, b) for a, b in zip(low, high))
    joined = body[near_body] & dilate(mask[near_body], iterations=2)
    pieces, count = ndimage.label(joined, structure=np.ones((3, 3, 3), dtype=bool))
    if count == 0:
        return stub
    sizes = np.bincount(pieces.ravel())[1:]
    for label in np.argsort(sizes, kind="stable")[::-1][:JUNCTIONS] + 1:
        if sizes[label - 1] < MIN_JUNCTION:
            break
        junction = (np.argwhere(pieces == label) + low) * spacing
        stub |= _stub_from(junction, mask, body, spacing, image)
    return stub


def _stub_from(junction, mask, body, spacing, image):
    """The stub (booleans over the box) that goes on from one ``junction`` piece ((N, 3) positions, mm) into the bone,
    or none. Walked over a box FIRST_REACH_MM round the junction first, and over MAX_LENGTH_MM when it goes that far."""
    stub = np.zeros(mask.shape, dtype=bool)
    centre = junction.mean(axis=0)
    normal = np.linalg.svd(junction - centre, full_matrices=False)[2][2]
    footprint = float(along_and_across(junction, centre, normal)[1].max())
    if footprint > MAX_FOOTPRINT_MM:
        return stub
    for reach in (FIRST_REACH_MM, MAX_LENGTH_MM):
        walked = _walk(junction, centre, normal, footprint, reach, mask, body, spacing, image)
        if walked is None or walked[0] < reach:
            break
    if walked is None or walked[0] < MIN_STUB_MM:
        return stub
    length, bone_voxels, along, across, start, axis = walked
    first = float(((junction - start) @ axis).min()) - spacing.max()  # a leaning cut's high side
    on_rod = (along >= first) & (along <= length) & (across <= footprint + INNER_MM)
    stub[tuple(bone_voxels[on_rod].T)] = True
    return stub


def _walk(junction, centre, normal, footprint, reach, mask, body, spacing, image):
    """(length mm, bone voxels (M, 3), their along and across (M,) mm, the axis' start and direction): the rod from the
    ``junction`` walked over the bone's voxels within ``reach`` (and the rod's cross-section) of its centre, or None
    when no bone lies next to it."""
    # The bone's voxels near the junction's line: the normal points into the bone.
    bone_voxels = _voxels_round(mask, centre, reach + footprint + OUTER_MM, spacing)
    bone_mm = bone_voxels * spacing
    along, across = along_and_across(bone_mm, centre, normal)
    near = (across <= footprint + INNER_MM) & (np.abs(along) <= 2.0 * STEP_MM + spacing.max())
    if not near.any():
        return None
    if np.median(along[near]) < 0:
        normal, along = -normal, -along
    hu = _bracket_hu(body, image, centre, normal, footprint, spacing)
    length = _rod_length(along, across, footprint, image, centre, normal, hu, spacing)
    # The junction is a cut on cells of a millimetre: its normal may lean off the rod's axis by 15 degrees, and the
    # walk along it leaves the rod's side long before its end (held-out draw 1104: 11 mm of a 17 mm stub). The axis
    # is turned through the centroids of the rod's near and far halves walked so far, as long as the walk grows.
    for _ in range(REFITS):
        on_rod = (along >= 0.0) & (along <= length) & (across <= footprint + INNER_MM)
        near_half, far_half = on_rod & (along < 0.5 * length), on_rod & (along >= 0.5 * length)
        if near_half.sum() < MIN_JUNCTION or far_half.sum() < MIN_JUNCTION:
            break
        axis = bone_mm[far_half].mean(axis=0) - bone_mm[near_half].mean(axis=0)
        axis /= np.linalg.norm(axis)
        if axis @ normal < np.cos(np.radians(MAX_LEAN_DEGREES)):
            break
        middle = bone_mm[on_rod].mean(axis=0)
        start = middle + ((centre - middle) @ axis) * axis  # the point of the new axis next to the junction's centre
        along_new, across_new = along_and_across(bone_mm, start, axis)
        longer = _rod_length(along_new, across_new, footprint, image, start, axis, hu, spacing)
        if longer <= length:
            break
        centre, normal, along, across, length = start, axis, along_new, across_new, longer
    return length, bone_voxels, along, across, centre, normal


def _voxels_round(mask, centre, reach, spacing):
    """(M, 3) indices of ``mask``'s True voxels in the box reaching ``reach`` (mm) round ``centre`` (3,) mm."""
    low = np.maximum(np.floor((centre - reach) / spacing).astype(int), 0)
    high = np.minimum(np.ceil((centre + reach) / spacing).astype(int) + 1, mask.shape)
    return np.argwhere(mask[tuple(slice(a, b) for a, b in zip(low, high))]) + low


def _bracket_hu(body, image, centre, normal, footprint, spacing):
    """The bracket's brightness (HU): the median of the body's voxels within half its cross-section of its axis and
    4 mm back from the junction."""
    voxels = _voxels_round(body, centre, footprint + 4.0, spacing)
    positions = voxels * spacing
    along, across = along_and_across(positions, centre, normal)
    core = (along <= 0.0) & (along >= -4.0) & (across <= 0.5 * footprint + spacing.max())
    if not core.any():
        return None
    return float(np.median(image[tuple(voxels[core].T)]))


def _rod_length(along, across, footprint, image, centre, normal, hu, spacing):
    """How far (mm) from the junction the bone goes on as the rod: until, in a step of STEP_MM, its voxels beyond the
    rod's cross-section (INNER_MM to OUTER_MM) are WIDENS of those on it (the bone's own surface), none is on it any
    more, or the image on the axis leaves the bracket's band round ``hu`` (``bracket_band``) for a millimetre."""
    if hu is None:
        return 0.0
    step = max(STEP_MM, float(spacing.max()))  # a step holds a voxel of the rod whichever way it runs
    steps = np.arange(0.0, MAX_LENGTH_MM + step, step)
    bins = np.digitize(along, steps) - 1
    valid = (along >= 0.0) & (bins < len(steps))
    on = np.bincount(bins[valid & (across <= footprint + INNER_MM)], minlength=len(steps))[: len(steps)]
    ring = (across > footprint + INNER_MM) & (across <= footprint + OUTER_MM)
    round_it = np.bincount(bins[valid & ring], minlength=len(steps))[: len(steps)]
    axis = (centre + steps[:, None] * normal) / spacing
    values = ndimage.map_coordinates(image, axis.T, order=1, mode="nearest")
    out = np.abs(values - hu) > bracket_band(hu)
    out_for_a_mm = out & np.concatenate([out[1:], [True]])
    emptied = (on == 0) & (np.cumsum(on) > 0)  # the junction lies a voxel or so before the rod's first voxels
    ended = (round_it >= np.maximum(WIDENS * on, MIN_WIDENING)) | emptied | out_for_a_mm
    stops = np.flatnonzero(ended)
    return float(steps[stops[0]]) if len(stops) else float(steps[-1])
