"""The stub of a bracket the cut left on the bone (``image.bracket_stub``), on shapes whose geometry is known."""

import numpy as np

from RAMSICPRegistrationLib.image.bracket_stub import (
    LINE_LENGTH_MM,
    LINE_MARGIN_MM,
    MAX_LINE_MM,
    bracket_line,
    bracket_line_beyond,
    bracket_stub,
)

SPACING = np.array([0.5, 0.5, 0.5])


def _grid(shape):
    return np.stack(np.meshgrid(*[np.arange(n) * s for n, s in zip(shape, SPACING)], indexing="ij"), axis=-1)


def _bone_and_rod(bone_radius, rod_radius, stub_mm):
    """A bone along axis 0 (a filled cylinder of ``bone_radius`` mm round (*, 20, 20)) and a rod of ``rod_radius``
    along axis 2 standing on it at x = 30 mm: its first ``stub_mm`` past the bone's surface are the bone's voxels
    (the stub), the rest the body's. Returns (mask, body, stub truth, distance past the bone's surface)."""
    points = _grid((120, 80, 100))
    bone = np.hypot(points[..., 1] - 20.0, points[..., 2] - 20.0) <= bone_radius
    rod = (np.hypot(points[..., 0] - 30.0, points[..., 1] - 20.0) <= rod_radius) & (points[..., 2] >= 20.0)
    past = points[..., 2] - 20.0 - np.sqrt(np.maximum(bone_radius**2 - (points[..., 1] - 20.0) ** 2, 0.0))
    stub = rod & ~bone & (past <= stub_mm)
    return bone | stub, rod & ~bone & ~stub, stub, past


def _assert_down_the_rod(line, radius_mm, end_z, atol):
    """The line runs down the rod's axis (x = 30, y = 20 mm, towards -z) from the body's end at ``end_z`` (mm, within
    1 mm), with the rod's radius within 0.5 mm."""
    assert line is not None
    np.testing.assert_allclose(line.direction, [0.0, 0.0, -1.0], atol=atol)
    assert abs(line.radius_mm - radius_mm) <= 0.5
    end = line.point_mm + line.tip * line.direction
    assert abs(end[2] - end_z) <= 1.0 and np.hypot(end[0] - 30.0, end[1] - 20.0) <= 0.2


def test_the_stub_of_a_rod_on_a_thick_bone_is_found_and_nothing_of_the_bone():
    mask, body, stub, past = _bone_and_rod(bone_radius=10.0, rod_radius=3.0, stub_mm=5.0)
    found = bracket_stub(mask, body, SPACING)
    assert found[stub & (past >= 1.5)].all()  # the stub but for its foot, in the corner the opening keeps
    assert not found[mask & ~stub].any()


def test_a_bone_thinner_than_the_bracket_is_not_taken_for_its_stub():
    """A bone 2.5 mm in radius under a rod of 3 mm: the whole bone is thinner than the opening; the piece the
    opening takes reaches farther than a stub from the body, so none is taken."""
    mask, body, stub, _ = _bone_and_rod(bone_radius=2.5, rod_radius=3.0, stub_mm=5.0)
    assert not bracket_stub(mask, body, SPACING).any()


def test_no_body_no_stub():
    mask, body, _, _ = _bone_and_rod(bone_radius=10.0, rod_radius=3.0, stub_mm=5.0)
    assert not bracket_stub(mask, np.zeros_like(body), SPACING).any()


def test_the_line_of_a_bracket_meeting_the_bone_head_on_holds_its_stub_and_the_ring_round_it():
    """The rod of 3 mm standing on a bone of 10 mm (its top at z = 30 mm), its first 5 mm the bone's: the line runs
    down the rod's axis (x = 30, y = 20) from the body's end (z = 35 mm) into the bone; points on the stub and the
    ring round its foot are on it, the bone's surface away from the rod and the bone's far side are not."""
    mask, body, _, _ = _bone_and_rod(bone_radius=10.0, rod_radius=3.0, stub_mm=5.0)
    line = bracket_line(mask, body, SPACING)
    _assert_down_the_rod(line, radius_mm=3.0, end_z=35.0, atol=0.02)
    radius = line.radius_mm + LINE_MARGIN_MM
    inside = np.array([[30.0, 20.0, 32.0], [30.0, 20.0 + 3.2, 33.0], [30.0 + radius - 0.2, 20.0, 30.0]])
    outside = np.array(
        [
            [60.0, 20.0, 30.0],  # the bone's top 30 mm from the rod
            [30.0 + radius + 0.3, 20.0, 30.0],  # just beyond the ring
            [30.0, 20.0, 35.0 - LINE_LENGTH_MM - 1.0],  # on the line, past its length: the bone's far side
            [30.0, 20.0, 40.0],  # up the rod, past the 2 mm before the body's end
        ]
    )
    assert line.contains(inside).all() and not line.contains(outside).any()


def test_a_plate_within_the_end_of_the_bracket_leaves_its_line_and_radius():
    """A rod of 1.5 mm on the same bone, its first 3 mm the bone's, its body's part ending 5 mm past that (z = 38 mm)
    in a plate 11 mm thick and 40 mm wide: within the 8 mm the bracket's end is read over, the plate is deeper (3 mm)
    than the rod, and gave the end its radius and its axis (across the plate). The rod's radius is read where its
    depth stops growing away from the bone, the plate is opened off the end, and the line runs down the rod
    (family seed 18070: 490 IPC points on a bracket's stub before)."""
    mask, body, _, _ = _bone_and_rod(bone_radius=10.0, rod_radius=1.5, stub_mm=3.0)
    points = _grid(mask.shape)
    plate = (np.abs(points[..., 0] - 30.0) <= 20.0) & (np.abs(points[..., 1] - 20.0) <= 20.0)
    body = (body & (points[..., 2] <= 38.0)) | (plate & (points[..., 2] >= 38.0) & (points[..., 2] <= 49.0))
    _assert_down_the_rod(bracket_line(mask, body, SPACING), radius_mm=1.5, end_z=33.0, atol=0.05)


def test_a_bracket_resting_along_the_bone_has_no_line():
    """A rod of 3 mm lying along the top of the same bone: its distance to the bone does not fall along it."""
    points = _grid((120, 80, 100))
    bone = np.hypot(points[..., 1] - 20.0, points[..., 2] - 20.0) <= 10.0
    rod = np.hypot(points[..., 1] - 20.0, points[..., 2] - 33.5) <= 3.0
    assert bracket_line(bone, rod & ~bone, SPACING) is None
    assert bracket_line(bone, np.zeros_like(bone), SPACING) is None


def test_a_thick_bracket_cut_short_by_the_bone_box_is_read_beyond_it():
    """A rod of 5.5 mm on a bone of 9 mm (family seed 15028's sizes), its first 3 mm the bone's. Over the bone's box
    (4 voxels round it) the body is a disc 3 mm long, wider than long: no line. Read beyond the box, the line runs
    down the rod's axis, in the box's frame, and holds the stub's side."""
    mask, body, stub, _ = _bone_and_rod(bone_radius=9.0, rod_radius=5.5, stub_mm=3.0)
    where = np.argwhere(mask)
    low, high = np.maximum(where.min(axis=0) - 4, 0), where.max(axis=0) + 5
    box = tuple(slice(a, b) for a, b in zip(low, high))
    assert bracket_line(mask[box], body[box], SPACING) is None
    line = bracket_line_beyond(mask[box], body, low, SPACING)
    assert line is not None
    np.testing.assert_allclose(line.direction, [0.0, 0.0, -1.0], atol=0.02)
    end = line.point_mm + line.tip * line.direction + low * SPACING  # back in the whole grid's frame
    rim = 20.0 + np.sqrt(9.0**2 - 5.5**2) + 3.0  # the body's end: its rim, where the stub's side ends (30.1 mm)
    assert abs(end[2] - rim) <= 1.0 and np.hypot(end[0] - 30.0, end[1] - 20.0) <= 0.3
    side = np.array([[30.0 + 5.5, 20.0, 30.0], [30.0, 20.0 - 5.5, 31.0]]) - low * SPACING  # the stub's side
    far = np.array([[60.0, 20.0, 29.0], [30.0, 20.0, 2.0]]) - low * SPACING  # the bone's top away, its far side
    assert line.contains(side).all() and not line.contains(far).any()


def test_a_bracket_through_a_flat_bone_is_read_on_its_side_and_its_tip_beyond_is_on_the_line():
    """A rod of 3 mm through a flat bone 10 mm thick (z 15-25 mm), its tip 3 mm out of the far side (family seed
    12023). The tip is the body's too and lies next to the bone, but on the far side: the line is read on the
    piece the rod comes from (falling towards the bone), and holds the tip's side."""
    points = _grid((120, 80, 100))
    bone = (points[..., 2] >= 15.0) & (points[..., 2] <= 25.0)
    rod = (np.hypot(points[..., 0] - 30.0, points[..., 1] - 20.0) <= 3.0) & (points[..., 2] >= 12.0)
    line = bracket_line(bone, rod & ~bone, SPACING)
    assert line is not None
    np.testing.assert_allclose(line.direction, [0.0, 0.0, -1.0], atol=0.02)
    end = line.point_mm + line.tip * line.direction
    assert abs(end[2] - 25.5) <= 1.0 and np.hypot(end[0] - 30.0, end[1] - 20.0) <= 0.2
    tip_side = np.array([[33.0, 20.0, 13.0], [30.0, 17.0, 12.5]])
    assert line.contains(tip_side).all() and not line.contains(np.array([[60.0, 20.0, 14.9]])).any()


def _rod_through_a_slab(rod_from_z, cortex_hu, bottom_z=10.0):
    """A rod of 3 mm (1500 HU) from z = ``rod_from_z`` up through a flat bone (z ``bottom_z``-30 mm: 2 mm cortices
    of ``cortex_hu``, 300 HU between) in air. Returns (bone mask, body mask, CT image)."""
    points = _grid((120, 80, 100))
    z = points[..., 2]
    bone = (z >= bottom_z) & (z <= 30.0)
    rod = (np.hypot(points[..., 0] - 30.0, points[..., 1] - 20.0) <= 3.0) & (z >= rod_from_z)
    image = np.full(bone.shape, -1000.0)
    image[bone] = 300.0
    image[bone & ((z <= bottom_z + 2.0) | (z >= 28.0))] = cortex_hu
    image[rod] = 1500.0
    return bone, rod & ~bone, image


def test_a_bracket_through_the_bone_is_followed_to_its_tip():
    """The rod goes through the 20 mm bone and 3 mm out of its far side (its tip at z = 7 mm, 23.5 mm past the body's
    end at z = 30.5): with the CT the line runs along the rod's axis to the tip and LINE_MARGIN_MM past it, and holds
    the tip's side; without the CT it stops at LINE_LENGTH_MM (family seeds 16094, 13085, 21083: 59-148 IPC points on
    a 1300-1600 HU bracket's tip 20-25 mm past the body's end)."""
    bone, body, image = _rod_through_a_slab(rod_from_z=7.0, cortex_hu=1000.0)
    line = bracket_line(bone, body, SPACING, image)
    _assert_down_the_rod(line, radius_mm=3.0, end_z=30.5, atol=0.02)
    end = (line.point_mm + line.tip * line.direction)[2]
    assert abs(line.length_mm - (end - 7.0 + LINE_MARGIN_MM)) <= 0.6
    tip_side = np.array([[33.0, 20.0, 7.5], [30.0, 17.0, 8.0]])  # the tip's side, out of the far side
    beyond = np.array([[30.0, 20.0, 7.0 - LINE_MARGIN_MM - 1.0], [60.0, 20.0, 9.5]])  # past it; the far side away
    assert line.contains(tip_side).all() and not line.contains(beyond).any()
    assert bracket_line(bone, body, SPACING).length_mm == LINE_LENGTH_MM
    assert not bracket_line(bone, body, SPACING).contains(tip_side).any()


def test_a_bracket_ending_on_a_brighter_cortex_or_within_the_bone_keeps_the_lines_length():
    """The rod ending on the far cortex (z = 12 mm), brighter than it (2500 HU): its axis turns brighter, not dimmer,
    and the far side's surface under it stays out of the line. Ending in the bone 10 mm in (z = 20 mm), or 25 mm in
    (a slab 30 mm thick, the rod's tip at z = 5 mm, in its 300 HU inside): its axis turns dimmer, but inside the
    bone, not out of it; the line keeps LINE_LENGTH_MM. Nowhere longer than MAX_LINE_MM."""
    bone, body, image = _rod_through_a_slab(rod_from_z=12.0, cortex_hu=2500.0)
    line = bracket_line(bone, body, SPACING, image)
    assert line.length_mm == LINE_LENGTH_MM
    assert not line.contains(np.array([[30.0, 20.0, 9.5]])).any()  # the far side's surface under the rod
    bone, body, image = _rod_through_a_slab(rod_from_z=20.0, cortex_hu=1000.0)
    assert bracket_line(bone, body, SPACING, image).length_mm == LINE_LENGTH_MM
    bone, body, image = _rod_through_a_slab(rod_from_z=5.0, cortex_hu=1000.0, bottom_z=0.5)
    assert bracket_line(bone, body, SPACING, image).length_mm == LINE_LENGTH_MM
    assert LINE_LENGTH_MM < MAX_LINE_MM


def _capsule_rod_through_a_slab(tilt_deg, radius_mm, tip_z):
    """A rod of ``radius_mm`` (1500 HU) with a round tip, tilted by ``tilt_deg`` from the normal of a flat bone (z
    10-30 mm: 2 mm cortices of 1000 HU, 300 HU between) in air, from z = 45 mm down through it to its tip at
    ``tip_z`` (the bottom of its round end). As the cut leaves it, the rod's part below the bone's top is the bone's
    (its tip out of the far side included), the rest the body's. Returns (bone mask, body mask, CT image, the rod's
    unit axis pointing down, the tip's bottom point)."""
    points = _grid((140, 80, 100))
    tilt = np.radians(tilt_deg)
    axis = np.array([np.sin(tilt), 0.0, -np.cos(tilt)])
    top = np.array([30.0, 20.0, 45.0])
    tip_centre = top + axis * (45.0 - tip_z - radius_mm) / np.cos(tilt)
    offsets = points - top
    along = offsets @ axis
    across = np.linalg.norm(offsets - along[..., None] * axis, axis=-1)
    length = (tip_centre - top) @ axis
    rod = (across <= radius_mm) & (along >= 0.0) & (along <= length)
    rod |= np.linalg.norm(points - tip_centre, axis=-1) <= radius_mm
    z = points[..., 2]
    slab = (z >= 10.0) & (z <= 30.0)
    image = np.full(slab.shape, -1000.0)
    image[slab] = 300.0
    image[slab & ((z <= 12.0) | (z >= 28.0))] = 1000.0
    image[rod] = 1500.0
    bone = slab | (rod & (z < 30.0))
    return bone, rod & ~bone, image, axis, tip_centre + radius_mm * axis


def test_a_bracket_aslant_to_the_bone_is_read_along_its_run_into_it():
    """A rod of 3 mm tilted 25 degrees from the bone's normal, through it and 2 mm out of its far side. The body's
    end, cut aslant by the bone's surface, tilts its principal axis 9 degrees towards the normal; with the CT the line
    joins the end's centroid to that of the rod's run into the bone, within 2 degrees of its axis, and holds the
    tip's side 2 mm off the rod's axis below the far side (family seed 26033: 6.7 degrees, 48 IPC points on the tip
    of a 7.9 mm bracket, 5.8-6.2 mm off the line read on its end)."""
    bone, body, image, axis, tip = _capsule_rod_through_a_slab(tilt_deg=25.0, radius_mm=3.0, tip_z=8.0)
    line = bracket_line(bone, body, SPACING, image)
    assert np.degrees(np.arccos(line.direction @ axis)) <= 2.0
    assert np.degrees(np.arccos(bracket_line(bone, body, SPACING).direction @ axis)) >= 5.0  # the end alone
    tip_side = tip - axis + np.array([[0.0, 2.0, 0.0], [0.0, -2.0, 0.0], [0.0, 0.0, 0.0]])
    assert (tip_side[:, 2] < 10.0).all() and line.contains(tip_side).all()


def test_a_round_tip_out_of_the_far_side_by_less_than_its_radius_is_on_the_line():
    """A rod of 3 mm tilted 10 degrees, its round tip 1 mm out of the far side (z = 9 mm): aslant, the ring round the
    rod lies in the bone on one side up to where its axis leaves the rod's HU, but the axis leaves the bone within
    TIP_PAST_MM past it; the line runs to the tip and LINE_MARGIN_MM past it (family seed 13086: a 6.5 mm bracket's
    tip out of a flat bone, 84 IPC points on it 0.5-2 mm past LINE_LENGTH_MM)."""
    bone, body, image, axis, tip = _capsule_rod_through_a_slab(tilt_deg=10.0, radius_mm=3.0, tip_z=9.0)
    line = bracket_line(bone, body, SPACING, image)
    assert np.degrees(np.arccos(line.direction @ axis)) <= 2.0
    assert line.length_mm > LINE_LENGTH_MM
    assert line.contains(tip - axis * np.array([[0.2], [0.8]]) + np.array([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]])).all()
    assert not line.contains((tip + (LINE_MARGIN_MM + 1.0) * axis)[None]).any()


def test_a_plate_coming_near_the_bone_beside_the_bracket_leaves_the_brackets_line():
    """A rod of 3 mm standing on a flat bone (z 10-30 mm) up to a plate 4 mm thick that slopes down from its top to
    0.5 mm over the bone 55 mm away. Within END_MM of the bone lie the rod's first 8 mm and a strip of the plate
    larger than them, which tilts the end's axis across the rod (no line before); read from each piece where the
    body meets the bone, through the body, the rod's end is the rod's alone (family seeds 15093, 19041: 247 and 37
    IPC points on the tip of a bracket whose plate comes within 9-12 mm of the bone)."""
    points = _grid((180, 80, 110))
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    bone = (z >= 10.0) & (z <= 30.0)
    rod = (np.hypot(x - 30.0, y - 20.0) <= 3.0) & (z >= 30.0) & (z <= 50.0)
    normal = np.array([19.5, 0.0, 55.0]) / np.hypot(19.5, 55.0)
    height = (points - np.array([30.0, 20.0, 52.0])) @ normal
    plate = (np.abs(height) <= 2.0) & (x >= 25.0) & (x <= 85.0) & (np.abs(y - 20.0) <= 18.0)
    body = (rod | plate) & ~bone
    assert z[plate].min() <= 31.0 and (plate & (z <= 38.0)).sum() > (rod & (z <= 38.0)).sum()
    _assert_down_the_rod(bracket_line(bone, body, SPACING), radius_mm=3.0, end_z=30.5, atol=0.02)
