"""The stub of a bracket that the cut between the bone and the reference body left on the bone.

``bone_recognition`` cuts the body off the bone on cells of about a millimetre, where a rod leaves the bone: the
bracket's first millimetres, up to the opening that cut it and a cell or two, stay with the bone, and more where the
bracket is as bright as the cortex. Their surface is the bracket's: IPC points 1-6 mm off the bone (family seeds
11019, 11075, 12023, 12064: 150-300 points each).

The stub is the bone's part thinner than the bracket next to the body: what an opening by a ball a little wider
than the bracket's end (its radius, read off the body's voxels where they meet the bone) takes off the bone, in the
pieces that touch the body. A bone thinner than the bracket is not taken: such a piece is larger than a stub.
"""

import copy

import numpy as np
from scipy import ndimage

from .morphology import VoxelGraph, bounding_box, dilate, largest_piece

#: The bracket's end is read off the body's voxels within this far (mm) of the bone.
END_MM = 8.0
#: The opening's ball is this much (mm) wider than the bracket's radius there, and at most MAX_RADIUS_MM.
MARGIN_MM = 1.0
MAX_RADIUS_MM = 6.5
#: A stub is at most this long (mm) from the body: a longer thin piece is the bone's own.
MAX_LENGTH_MM = 12.0


#: The bracket's line is followed this far (mm) past the body's end, and IPC points within its radius and this
#: margin (mm) of it are the bracket's (``BracketLine``)...
LINE_LENGTH_MM = 20.0
LINE_MARGIN_MM = 2.0
#: ... when the bracket meets the bone head-on: along its end the distance to the bone falls steadily (the
#: correlation of the two over the end's voxels at least this; a bracket resting along the bone has none).
HEAD_ON = 0.9
#: A bracket whose axis stays at its own HU (within THROUGH_BAND of it, at least THROUGH_BAND_HU) past LINE_LENGTH_MM
#: goes on through the bone: the line then runs to where the axis turns dimmer (for a millimetre), and LINE_MARGIN_MM
#: past it for the tip's blur, at most MAX_LINE_MM, when it goes through the bone and out (a ring TIP_RING_MM round
#: it lies in the bone over THROUGH_BONE of it somewhere, over at most OUT_OF_BONE along its last TIP_FREE_MM:
#: ``_through_length``).
THROUGH_BAND = 0.25
THROUGH_BAND_HU = 100.0
MAX_LINE_MM = 60.0
TIP_RING_MM = 0.5
TIP_FREE_MM = 1.5
THROUGH_BONE = 0.75
OUT_OF_BONE = 0.5
#: ... or the axis leaves the bone within TIP_PAST_MM past the run's end (a round tip out by less than the bracket's
#: radius, and its blur).
TIP_PAST_MM = 2.5
#: A bracket's run into the bone longer than INSIDE_RUN_MM turns its line, REFITS times, through the centroid of the
#: run's voxels (``_inside_run``).
INSIDE_RUN_MM = 3.0
REFITS = 3
#: The line is read from at most this many of the pieces where the body meets the bone, the largest first.
JUNCTIONS = 3
#: Going away from the bone, the bracket's depth grows with the distance up to its radius: it has reached it where
#: it lags the distance by PLATEAU_LAG_MM; a part of its end deeper than that by FRAME_DEEPER_MM is a frame's or a
#: plate's (mm).
PLATEAU_LAG_MM = 1.0
FRAME_DEEPER_MM = 1.0


class _BracketEnd:
    """The body's voxels within END_MM of the bone, over a box round where the two meet: ``box`` (3 slices of the
    arrays given), ``bone`` and ``rest`` (the body) cut to it, ``to_bone`` (mm), ``depth`` (the body's, mm),
    ``end`` (booleans); ``junctions()`` reads it from each piece where the two meet."""

    def __init__(self, mask, body, spacing):
        self.end = None
        if not body.any() or not mask.any():
            return
        reach = np.ceil((MAX_LENGTH_MM + MAX_RADIUS_MM) / spacing).astype(int) + 2
        joined = body & dilate(mask, iterations=2)  # where the body meets the bone (two voxels)
        if not joined.any():
            return
        where = np.argwhere(joined)
        low = np.maximum(where.min(axis=0) - reach, 0)
        high = np.minimum(where.max(axis=0) + reach + 1, mask.shape)
        self.box = tuple(slice(a, b) for a, b in zip(low, high))
        self.low = low
        self.bone, self.rest = mask[self.box], body[self.box]
        self.to_bone = ndimage.distance_transform_edt(~self.bone, sampling=spacing)
        self.depth = ndimage.distance_transform_edt(self.rest, sampling=spacing)
        end = self.rest & (self.to_bone <= END_MM)
        self.end = end if end.any() else None
        self.joined, self.spacing = joined[self.box], spacing

    def junctions(self):
        """The bracket's end read from each of the largest JUNCTIONS pieces where the body meets the bone, largest
        first: views of this end whose ``from_bone`` (mm) is the distance from that piece through the body (inf past
        3 * MAX_RADIUS_MM), and whose ``end`` holds the body's voxels within END_MM of it (None when none). A frame or
        plate that comes near the bone beside the bracket meets it in a piece of its own, or is far from the
        bracket's along it (family seeds 15093, 19041: a plate as thin as the bracket within 9-12 mm of the bone,
        its axis read across the plate and no line; 247 and 37 IPC points on the bracket's tip out of the bone's
        far side)."""
        pieces, _ = ndimage.label(self.joined, structure=np.ones((3, 3, 3), dtype=bool))
        sizes = np.bincount(pieces.ravel())[1:]
        reach_mm = max(END_MM, 3.0 * MAX_RADIUS_MM)
        graph = VoxelGraph(self.rest & (self.to_bone <= reach_mm + 2.0 * self.spacing.max()), self.spacing)
        for label in np.argsort(sizes, kind="stable")[::-1][:JUNCTIONS] + 1:
            view = copy.copy(self)
            view.from_bone = graph.distance(pieces == label, reach_mm)
            end = self.rest & (view.from_bone <= END_MM)
            view.end = end if end.any() else None
            yield view

    def radius(self):
        """The bracket's radius (mm): its end's depth, at most MAX_RADIUS_MM. A frame or plate within END_MM of the bone
        is deeper: where the end holds a part deeper by FRAME_DEEPER_MM than the depth at which, going away from the
        bone, the depth stops growing with the distance (lags it by PLATEAU_LAG_MM), that depth is the bracket's
        (family seed 18070: a 7.5 mm bracket inserted into a tibia from an 11.4 mm plate, its end's depth 6.0 mm,
        the plateau 3.5 mm)."""
        to_bone, depth = self.to_bone[self.end], self.depth[self.end]
        order = np.argsort(to_bone, kind="stable")
        deepest = np.maximum.accumulate(depth[order])
        plateau = np.nonzero(deepest <= to_bone[order] - PLATEAU_LAG_MM)[0]
        radius = deepest[-1]
        if len(plateau) and radius > deepest[plateau[0]] + FRAME_DEEPER_MM:
            radius = deepest[plateau[0]]
        return min(float(radius), MAX_RADIUS_MM)


def bracket_stub(mask, body, spacing):
    """(I, J, K) booleans over a box: the voxels of the bone (``mask``) that are the stub of the bracket whose rest
    is ``body`` (the body's voxels cut off the bone, same box); ``spacing`` (3,) mm. All False when there is none."""
    stub = np.zeros(mask.shape, dtype=bool)
    spacing = np.asarray(spacing, float)
    meeting = _BracketEnd(mask, body, spacing)
    if meeting.end is None:
        return stub
    box, bone, rest = meeting.box, meeting.bone, meeting.rest
    radius = min(meeting.radius() + MARGIN_MM, MAX_RADIUS_MM)
    # An opening by a ball of that radius: the bone's parts thinner than it go.
    opened = _opened(ndimage.distance_transform_edt(bone, sampling=spacing), radius, spacing)
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


class BracketLine:
    """The line of a bracket that meets the bone head-on, fitted to the body's end (its voxels within END_MM of
    where it meets the bone, through the body, or three of the bracket's radii if more; their principal axis, turned
    through the centroid of the bracket's run into the bone where the CT shows one): the stub the cut left on the
    bone lies along it, as far as the bracket reaches into the bone. ``contains(positions_mm)`` tells the IPC points
    on it: within the bracket's radius and LINE_MARGIN_MM of the line, from 2 mm before the body's end to
    LINE_LENGTH_MM past it (a disc round where the bracket enters the bone goes with them: the ring the bracket
    hides), or ``length_mm`` past it for a bracket that goes through the bone (``_through_length``). Family seeds
    14013, 15072: 439 and 185 IPC points on stubs 6-17 mm long that a thin bone's own thin parts joined (longer than
    a stub may be)."""

    def __init__(self, point_mm, direction, radius_mm, tip, length_mm=LINE_LENGTH_MM):
        self.point_mm, self.direction, self.radius_mm, self.tip = point_mm, direction, radius_mm, tip
        self.length_mm = length_mm

    def contains(self, positions_mm):
        """(M,) booleans for (M, 3) positions in mm (index times spacing, the frame of the arrays fitted)."""
        along, across = along_and_across(positions_mm, self.point_mm, self.direction)
        return (
            (across <= self.radius_mm + LINE_MARGIN_MM)
            & (along >= self.tip - 2.0)
            & (along <= self.tip + self.length_mm)
        )


def along_and_across(positions_mm, point_mm, direction):
    """(M,) distances (mm) of positions (M, 3) along the unit ``direction`` from ``point_mm`` (3,), and (M,) their
    distances from the line through it."""
    offsets = positions_mm - point_mm
    along = offsets @ direction
    return along, np.linalg.norm(offsets - along[:, None] * direction, axis=1)


def _opened(depth, radius, spacing):
    """What an opening by a ball of ``radius`` (mm) keeps of a set whose distance transform (mm) is ``depth``: its
    parts thicker than the ball (none when no voxel is deeper than the radius)."""
    core = depth > radius
    if not core.any():
        return core
    return ndimage.distance_transform_edt(~core, sampling=spacing) <= radius


def bracket_line_beyond(mask, body, low, spacing, image=None):
    """``bracket_line`` read on the body beyond the bone's box too: ``mask`` the bone over its box, which starts
    at voxel ``low`` (3,) of ``body`` (the reference body's booleans over a larger box; ``image`` the CT over that
    box, or None). The box round a bone leaves a thick bracket within a few mm of it, where its end is wider than
    long and gives no line (family seed 15028: a 10.9 mm bracket inserted into an 18 mm tibia, 354 IPC points on the
    stub). Returns the BracketLine in the frame index times spacing of ``mask``, or None."""
    spacing = np.asarray(spacing, float)
    low = np.asarray(low, int)
    reach = np.ceil(max(END_MM, 3.0 * MAX_RADIUS_MM) / spacing).astype(int) + 1
    wide_low = np.maximum(low - reach, 0)
    wide_high = np.minimum(low + np.array(mask.shape) + reach, body.shape)
    wide = np.zeros(wide_high - wide_low, dtype=bool)
    wide[tuple(slice(a, a + n) for a, n in zip(low - wide_low, mask.shape))] = mask
    crop = tuple(slice(a, b) for a, b in zip(wide_low, wide_high))
    line = bracket_line(wide, body[crop], spacing, None if image is None else image[crop])
    if line is not None:
        line.point_mm = line.point_mm - (low - wide_low) * spacing
    return line


def bracket_line(mask, body, spacing, image=None):
    """The BracketLine of the ``body`` (the body's voxels cut off the bone ``mask``, same box; ``spacing`` (3,) mm)
    in the frame index times spacing of these arrays, or None when the bracket does not meet the bone head-on.
    With ``image`` (the CT, HU, same box) the line joins the centroid of the body's end to that of the bracket's run
    on into the bone (``_inside_run``), and a bracket that goes through the bone is followed to its tip."""
    spacing = np.asarray(spacing, float)
    meeting = _BracketEnd(mask, body, spacing)
    if meeting.end is None:
        return None
    for junction in meeting.junctions():
        line = _line_from(junction, mask, spacing, image)
        if line is not None:
            return line
    return None


def _line_from(meeting, mask, spacing, image):
    """``bracket_line`` read on one junction's end (a ``_BracketEnd.junctions()`` view), or None."""
    if meeting.end is None or meeting.end.sum() < 10:
        return None
    radius = meeting.radius()
    # A thick bracket's first END_MM are wider than long: its line is read over three of its radii, on the parts no
    # thicker than the bracket (an opening by a ball MARGIN_MM wider takes a frame or plate off).
    near = meeting.rest & (meeting.from_bone <= max(END_MM, 3.0 * radius))
    # Opened over the box round these voxels alone, with room for the ball: the same, at a fraction of the cost where
    # the body meets the bone over a wide box (a plate near it).
    low, high = bounding_box(near, pad=np.ceil((radius + MARGIN_MM) / spacing).astype(int) + 1)
    crop = tuple(slice(a, b) for a, b in zip(low, high))
    thin = np.zeros_like(near)
    thin[crop] = near[crop] & ~_opened(meeting.depth[crop], radius + MARGIN_MM, spacing)
    # Its largest piece: the bracket's end on the side it comes from, not its tip where it goes through a flat bone
    # and out of its far side (family seed 12023: 149 IPC points on that tip).
    end = largest_piece(thin if thin.any() else near)
    positions = (np.argwhere(end) + meeting.low) * spacing
    to_bone = meeting.to_bone[end]
    centre = positions.mean(axis=0)
    direction = np.linalg.svd(positions - centre, full_matrices=False)[2][0]
    along = (positions - centre) @ direction
    if np.ptp(along) <= 0.0 or np.ptp(to_bone) <= 0.0:
        return None
    correlation = float(np.corrcoef(along, to_bone)[0, 1])
    if abs(correlation) < HEAD_ON:
        return None
    if correlation > 0:  # the line points towards the bone: the distance to it falls along the line
        direction, along = -direction, -along
    tip = float(along.max())
    length = LINE_LENGTH_MM
    if image is not None:
        core = end & (meeting.depth >= 0.5 * meeting.depth[end].max())
        hu = float(np.median(image[meeting.box][core]))
        for _ in range(REFITS):  # the bracket goes on into the bone: the line joins the two parts' centroids
            inside = _inside_run(image, centre + tip * direction, direction, hu, radius, spacing)
            if len(inside) == 0:
                break
            direction = inside.mean(axis=0) - centre
            direction /= np.linalg.norm(direction)
            tip = float(((positions - centre) @ direction).max())
        length = _through_length(image, mask, centre + tip * direction, direction, hu, radius, spacing)
    return BracketLine(centre, direction, radius, tip, length)


def bracket_band(hu):
    """How far (HU) from a bracket's ``hu`` the image along its axis may stray and still be the bracket: THROUGH_BAND
    of it, at least THROUGH_BAND_HU."""
    return max(THROUGH_BAND * abs(hu), THROUGH_BAND_HU)


def _run_end(image, start_mm, direction, hu, spacing):
    """Where (mm past ``start_mm`` along ``direction``) the image along the axis of a bracket of ``hu`` leaves its
    band (THROUGH_BAND of its HU, at least THROUGH_BAND_HU) for a millimetre, the axis' samples (mm), and the image
    there (HU); the end is None when it stays in the band to MAX_LINE_MM."""
    band = bracket_band(hu)
    steps = np.arange(0.0, MAX_LINE_MM + 1e-6, 0.5)
    axis = start_mm + steps[:, None] * direction
    values = ndimage.map_coordinates(image, (axis / spacing).T, order=1, mode="nearest")
    out = np.abs(values - hu) > band
    leaves = np.nonzero(out[:-1] & out[1:])[0]
    return (float(steps[leaves[0]]) if len(leaves) else None), steps, values


def _inside_run(image, start_mm, direction, hu, radius, spacing):
    """(M, 3) positions (mm) of the voxels of a bracket's run past the body's end (``start_mm``, along ``direction``;
    ``_run_end``): within its band of ``hu`` and ``radius`` (mm) of its axis, from the body's end to the run's end.
    The line read on the body's end alone tilts off where the bone's surface cuts that end aslant, and misses the tip
    of a bracket that comes out of the far side of the bone by more than LINE_MARGIN_MM (family seed 26033: 6.7
    degrees, 48 IPC points on the tip 10-15 mm past the body's end, 5.8-6.2 mm off the line). Empty when the run is
    shorter than INSIDE_RUN_MM."""
    end, _, _ = _run_end(image, start_mm, direction, hu, spacing)
    if end is None or end < INSIDE_RUN_MM:
        return np.zeros((0, 3))
    stop = start_mm + end * direction
    reach = radius + 1.0
    low = np.maximum(np.floor((np.minimum(start_mm, stop) - reach) / spacing).astype(int), 0)
    high = np.minimum(np.ceil((np.maximum(start_mm, stop) + reach) / spacing).astype(int) + 1, image.shape)
    if np.any(high <= low):
        return np.zeros((0, 3))
    box = tuple(slice(a, b) for a, b in zip(low, high))
    positions = (np.argwhere(np.ones(high - low, dtype=bool)) + low) * spacing
    along, across = along_and_across(positions, start_mm, direction)
    band = bracket_band(hu)
    keep = (along >= 0.0) & (along <= end) & (across <= radius) & (np.abs(image[box].ravel() - hu) <= band)
    return positions[keep]


def _through_length(image, bone, start_mm, direction, hu, radius, spacing):
    """How far (mm) the line runs past the body's end (``start_mm`` (3,), in the frame index times ``spacing`` of
    ``image`` and of the ``bone``'s booleans) along ``direction``, for a bracket of ``hu`` (its end's median) and
    ``radius`` (mm): LINE_LENGTH_MM, or more when the image along the axis stays within its band (THROUGH_BAND of its
    HU, at least THROUGH_BAND_HU) farther and then turns dimmer for a millimetre, having gone through the ``bone``
    and out of it (THROUGH_BONE; OUT_OF_BONE or TIP_PAST_MM): its tip, out of the bone's far side (family seeds
    16094, 13085, 21083: a 6-11 mm bracket of 1300-1600 HU through a bone, 59-148 IPC points on its tip 20-25 mm past
    the body's end). A run that ends brighter (a cortex brighter than the bracket), inside the bone, or along it
    without going through it (a line read along a fibula's cortex: family seed 19020, 304 IPC points on the bone
    lost), or that goes on to MAX_LINE_MM, is not followed."""
    end, steps, values = _run_end(image, start_mm, direction, hu, spacing)
    if end is None or values[steps == end][0] > hu or end + LINE_MARGIN_MM <= LINE_LENGTH_MM:
        return LINE_LENGTH_MM
    axis = start_mm + steps[:, None] * direction
    # The share of a ring TIP_RING_MM round the bracket that lies in the bone, along the run: it goes through the bone
    # (THROUGH_BONE of a ring in it somewhere) and comes out (at most OUT_OF_BONE over its last TIP_FREE_MM).
    across = np.linalg.svd(direction[None, :])[2][1:]  # two unit vectors across the axis
    angles = np.linspace(0.0, 2.0 * np.pi, 12, endpoint=False)
    ring = (radius + TIP_RING_MM) * (np.cos(angles)[:, None] * across[0] + np.sin(angles)[:, None] * across[1])
    run = steps < end
    around = (axis[run][:, None, :] + ring[None, :, :]).reshape(-1, 3) / spacing
    bone = bone.astype(np.uint8)
    in_bone = ndimage.map_coordinates(bone, around.T, order=0, mode="constant")
    share = in_bone.reshape(-1, len(angles)).mean(axis=1)
    tip = steps[run] >= end - TIP_FREE_MM
    # A round tip that comes out by less than the bracket's radius leaves the ring in the bone to the run's end: the
    # axis past the run's end leaves the bone instead (family seed 13086: a 6.5 mm bracket out of a flat bone's far
    # side, 84 IPC points on its tip 0.5-2 mm past LINE_LENGTH_MM).
    past = axis[(steps >= end) & (steps <= end + TIP_PAST_MM)] / spacing
    comes_out = share[tip].mean() <= OUT_OF_BONE or not ndimage.map_coordinates(bone, past.T, order=0).all()
    if share.max() < THROUGH_BONE or not comes_out:
        return LINE_LENGTH_MM
    return float(min(end + LINE_MARGIN_MM, MAX_LINE_MM))
