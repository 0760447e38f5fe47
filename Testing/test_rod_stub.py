"""A long stub of a bracket left on the bone (``image.rod_stub``), on shapes whose geometry is known: a square bar
standing on a flat bone, cut off the body far above it."""

import numpy as np

from RAMSICPRegistrationLib.image.rod_stub import rod_stub

SPACING = np.array([0.6, 0.6, 0.5])
BAR_HU, CORTEX_HU, MARROW_HU = 1200.0, 800.0, 200.0


def _scene(stub_mm, bar_half=3.5, tilt=0.0, slab_half=4.5, resting_plate=False):
    """A flat bone (a slab ``slab_half`` mm either side of z = 20 mm, over the whole grid in x and y) and a square bar
    (``bar_half`` mm each side of x = 24, y = 20) standing on it; the bar's first ``stub_mm`` above the slab (a
    plane tilted by ``tilt`` in z per mm of x) are the bone's voxels, the rest the body's. ``resting_plate``: a plate
    lies on the slab instead of the bar (the body meets the bone over 30 x 30 mm). Returns (mask, body, image, truth
    of the stub, height above the slab's top in mm)."""
    shape = (80, 70, 110)
    x, y, z = np.meshgrid(*[np.arange(n) * s for n, s in zip(shape, SPACING)], indexing="ij")
    slab = np.abs(z - 20.0) <= slab_half
    top = 20.0 + slab_half
    if resting_plate:
        bar = (np.abs(x - 24.0) <= 15.0) & (np.abs(y - 20.0) <= 15.0) & (z > top) & (z <= top + 5.0)
    else:
        bar = (np.abs(x - 24.0) <= bar_half) & (np.abs(y - 20.0) <= bar_half) & (z > top)
    stub = bar & (z <= top + stub_mm + tilt * (x - 24.0))
    image = np.full(shape, -1000.0)
    image[slab] = MARROW_HU
    image[slab & (np.abs(z - 20.0) >= slab_half - 1.5)] = CORTEX_HU
    image[bar] = BAR_HU
    return slab | stub, bar & ~stub, image, stub, z - top


def test_a_long_stub_of_a_square_bar_on_a_flat_bone_is_found_to_the_bone_and_none_of_the_bone():
    """A 7 mm square bar cut 15 mm above a 9 mm flat bone (held-out draw 1104): the stub is found from the junction
    down to the bone's surface; no voxel of the bone deeper than a step under its surface is taken."""
    mask, body, image, stub, height = _scene(stub_mm=15.0)
    found = rod_stub(mask, body, SPACING, image)
    assert found[stub & (height >= 1.0)].all()
    assert not found[mask & ~stub & (height < -0.5)].any()


def test_a_stub_whose_cut_leans_is_followed_down_the_bar_not_along_the_cut():
    """The cut between the body and the stub leans by 20 degrees (the junction's normal leans as much off the bar):
    the axis fitted again to the stub walked so far follows the bar down to the bone."""
    mask, body, image, stub, height = _scene(stub_mm=15.0, tilt=np.tan(np.radians(20.0)))
    found = rod_stub(mask, body, SPACING, image)
    assert found[stub & (height >= 1.0)].all()
    assert not found[mask & ~stub & (height < -0.5)].any()


def test_a_wide_bar_resting_on_a_bone_leaves_its_stub_found_too():
    """A 15 mm square bar (held-out draw 2014: wider than any opening), cut 20 mm above the bone."""
    mask, body, image, stub, height = _scene(stub_mm=20.0, bar_half=7.5, slab_half=9.0)
    found = rod_stub(mask, body, SPACING, image)
    assert found[stub & (height >= 1.0)].all()
    assert not found[mask & ~stub & (height < -0.5)].any()


def test_a_bar_cut_at_the_bone_or_a_plate_resting_on_it_leaves_no_stub():
    """Cut 1 mm above the bone (the bracket's foot, ``bracket_stub``'s), or a plate lying on the bone (the bone widens
    at once under the junction): no stub."""
    mask, body, image, _, _ = _scene(stub_mm=1.0)
    assert not rod_stub(mask, body, SPACING, image).any()
    mask, body, image, _, _ = _scene(stub_mm=0.0, resting_plate=True)
    assert not rod_stub(mask, body, SPACING, image).any()


def test_a_bone_that_goes_on_along_the_bracket_with_its_marrow_is_no_stub():
    """The body's bar ends on a piece of bone as thick as it, along its axis (a thin process): the bone's axis holds
    marrow, 1,000 HU off the bar's, and the walk stops within a millimetre."""
    mask, body, image, stub, height = _scene(stub_mm=15.0)
    image[stub & (np.abs(height - 7.5) < 7.0)] = MARROW_HU  # the stub's inside is marrow: bone, not the bar
    image[stub & (np.abs(height - 7.5) >= 7.0)] = CORTEX_HU
    found = rod_stub(mask, body, SPACING, image)
    assert found.sum() * np.prod(SPACING) < 1.0 * 49.0  # at most a millimetre of the bar's cross-section


def test_no_body_no_stub():
    mask, body, image, _, _ = _scene(stub_mm=15.0)
    assert not rod_stub(mask, np.zeros_like(body), SPACING, image).any()
