"""The bone's envelope with the holes in its cortex plugged (``image.envelope``), on shells whose geometry is known."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.image.envelope import HOLE_MM, bone_envelope

ALL_SIDES = [(axis, side) for axis in range(3) for side in (0, -1)]


def _grid(shape, spacing):
    """(I, J, K, 3) voxel centres in mm."""
    return np.stack(np.meshgrid(*[np.arange(n) * s for n, s in zip(shape, spacing)], indexing="ij"), axis=-1)


@pytest.mark.parametrize("hole_mm", [4.0, 9.0, 12.0])
@pytest.mark.parametrize("spacing", [(0.5, 0.5, 0.5), (0.4, 0.4, 1.0)])
def test_a_shell_with_a_hole_encloses_its_cavity_and_nothing_outside(hole_mm, spacing):
    """A spherical shell (outer radius 15 mm, cortex 2.5 mm) with a round hole ``hole_mm`` wide through its cortex:
    the cavity (12.5 mm round the centre) is in the envelope, the outside 1.5 mm beyond the outer surface is not
    anywhere (the inner-wall test looks that far), the hole's channel is plugged (but for a cell, about 1 mm, under
    the outer surface: the envelope ends within a cell of the bone's surface)."""
    spacing = np.array(spacing)
    shape = np.rint(44.0 / spacing).astype(int)
    centre = shape * spacing / 2.0
    points = _grid(shape, spacing) - centre
    radius = np.linalg.norm(points, axis=-1)
    shell = (radius <= 15.0) & (radius >= 12.5)
    hole = (np.hypot(points[..., 0], points[..., 1]) <= hole_mm / 2.0) & (points[..., 2] > 0)
    mask = shell & ~hole
    envelope = bone_envelope(mask, ALL_SIDES, spacing)
    assert envelope[mask].all()
    assert envelope[radius <= 12.0].all()  # the cavity, the hole's mouth into it included
    assert not envelope[radius >= 16.5].any()
    if hole_mm < HOLE_MM - 3.0:  # a plug almost as wide as the cube sags into the hole; the cavity stays closed
        assert envelope[hole & (radius > 12.5) & (radius < 13.5)].all()  # the channel through the cortex


def test_a_tube_cut_by_the_ct_edge_is_filled_and_its_outside_left_alone():
    """A tube (outer radius 10 mm, cortex 2 mm) slanted 30 degrees and cut by two sides of the box that are the CT's
    (axis 2): its marrow is in the envelope up to the cut, and no voxel 1.5 mm or more outside it, by the cut
    included (a closing of the box alone fills a band along it)."""
    spacing = np.array([0.5, 0.5, 0.5])
    shape = (100, 100, 80)
    points = _grid(shape, spacing) - np.array([25.0, 25.0, 20.0])
    axis = np.array([np.sin(np.radians(30.0)), 0.0, np.cos(np.radians(30.0))])
    across = np.linalg.norm(points - (points @ axis)[..., None] * axis, axis=-1)
    mask = (across <= 10.0) & (across >= 8.0)
    open_sides = [(a, side) for a in range(2) for side in (0, -1)]
    envelope = bone_envelope(mask, open_sides, spacing)
    assert envelope[across <= 7.5].all()
    assert not envelope[across >= 11.5].any()


def test_a_notch_narrower_than_the_plug_is_filled_a_wider_one_is_not():
    """A block with two slots cut into its top, 6 mm and 2 * HOLE_MM wide: the narrow one is plugged (its surface
    would be left out of the IPC), the wide one stays outside."""
    spacing = np.array([0.5, 0.5, 0.5])
    shape = (160, 60, 60)
    points = _grid(shape, spacing)
    block = (points[..., 0] > 5) & (points[..., 0] < 75) & (points[..., 1] > 5) & (points[..., 1] < 25)
    block &= (points[..., 2] > 5) & (points[..., 2] < 25)
    narrow = (np.abs(points[..., 0] - 20.0) < 3.0) & (points[..., 2] > 15.0)
    wide = (np.abs(points[..., 0] - 52.0) < HOLE_MM) & (points[..., 2] > 15.0)
    envelope = bone_envelope(block & ~narrow & ~wide, ALL_SIDES, spacing)
    inner = (points[..., 1] > 7.0) & (points[..., 1] < 23.0) & (points[..., 2] < 23.0)  # a cell and more in
    assert envelope[block & narrow & inner].all()
    assert not envelope[wide & (np.abs(points[..., 0] - 52.0) < HOLE_MM - 2.0) & (points[..., 2] > 17.0)].any()


def test_no_open_side_no_envelope():
    assert bone_envelope(np.ones((5, 5, 5), dtype=bool), [], np.ones(3)) is None


@pytest.mark.parametrize("hole_mm", [9.0, 12.0])
@pytest.mark.parametrize("spacing", [(0.5, 0.5, 0.5), (0.4, 0.4, 1.0)])
def test_the_plug_of_a_bracket_hole_reaches_its_mouth(hole_mm, spacing):
    """The same shell with a hole as wide as a bracket: the plug fills the channel up to its mouth (97 % of it within
    1 mm of the outer surface, 75 % within 0.5 mm), so the hole's wall there faces into the envelope (family seeds
    14026, 20099: IPC points on such walls 0.5-2 mm under the surface). The one-cell trim of the rest of the envelope
    left a fifth to two thirds of its outer half millimetre out."""
    spacing = np.array(spacing)
    shape = np.rint(44.0 / spacing).astype(int)
    points = _grid(shape, spacing) - shape * spacing / 2.0
    radius = np.linalg.norm(points, axis=-1)
    hole = (np.hypot(points[..., 0], points[..., 1]) <= hole_mm / 2.0) & (points[..., 2] > 0)
    envelope = bone_envelope((radius <= 15.0) & (radius >= 12.5) & ~hole, ALL_SIDES, spacing)
    channel = hole & (radius > 12.5)
    assert envelope[channel & (radius < 14.0)].mean() >= 0.97
    assert envelope[channel & (radius < 14.5)].mean() >= 0.75
    assert not envelope[radius >= 15.5].any()
