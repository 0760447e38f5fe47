"""The shifted-copy morphology gives exactly what SciPy's voxel loops give (and what a brute-force window gives),
on random masks of every small shape, sides and thin dimensions included."""

import numpy as np
import pytest
from scipy import ndimage

from RAMSICPRegistrationLib.image.morphology import (
    VoxelGraph,
    all_ahead,
    any_ahead,
    any_behind,
    block_any,
    block_max,
    bounding_box,
    box_max,
    box_sum,
    dilate,
    dilate_by_cube,
    erode,
    labelled,
    open_by_cube,
    reaching_no_side,
    unblock,
)


def random_masks(seed, count=60):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        shape = tuple(int(n) for n in rng.integers(1, 12, size=3))
        blur = rng.uniform(0.0, 2.0)
        yield rng, ndimage.gaussian_filter(rng.normal(size=shape), blur) > rng.uniform(-0.3, 0.3)


@pytest.mark.parametrize("seed", range(3))
def test_dilate_and_erode_match_scipy_cross(seed):
    for rng, mask in random_masks(seed):
        iterations = int(rng.integers(1, 5))
        within = rng.random(mask.shape) > 0.3
        np.testing.assert_array_equal(dilate(mask, iterations), ndimage.binary_dilation(mask, iterations=iterations))
        np.testing.assert_array_equal(erode(mask, iterations), ndimage.binary_erosion(mask, iterations=iterations))
        np.testing.assert_array_equal(
            dilate(mask, iterations, within=within),
            ndimage.binary_dilation(mask, iterations=iterations, mask=within),
        )


@pytest.mark.parametrize("seed", range(3))
def test_cube_filters_match_scipy(seed):
    for rng, mask in random_masks(seed):
        size = int(rng.choice([1, 3, 5, 7]))
        as_bytes = mask.view(np.uint8)
        opened = ndimage.maximum_filter(ndimage.minimum_filter(as_bytes, size=size), size=size).view(bool)
        np.testing.assert_array_equal(open_by_cube(mask, size), opened)
        cube = np.ones((3, 3, 3), dtype=bool)
        np.testing.assert_array_equal(dilate_by_cube(mask), ndimage.binary_dilation(mask, structure=cube))


@pytest.mark.parametrize("seed", range(3))
def test_box_sums_and_maxima_match_scipy(seed):
    for rng, mask in random_masks(seed):
        counts = rng.integers(0, 50, size=mask.shape).astype(np.float32) * mask
        sums = ndimage.uniform_filter(counts.astype(np.float64), size=3, mode="constant") * 27.0
        np.testing.assert_allclose(box_sum(counts), sums, atol=1e-9)
        np.testing.assert_array_equal(box_sum(counts), np.rint(sums))  # whole counts, exactly
        np.testing.assert_array_equal(box_max(counts), ndimage.maximum_filter(counts, size=3, mode="constant"))


@pytest.mark.parametrize("seed", range(3))
def test_windows_along_an_axis_match_brute_force(seed):
    for rng, mask in random_masks(seed):
        axis, length = int(rng.integers(3)), int(rng.integers(1, 20))
        moved = np.moveaxis(mask, axis, 0)
        n = len(moved)
        ahead_any = np.stack([moved[x : x + length].any(axis=0) for x in range(n)])
        ahead_all = np.stack([moved[x : x + length].all(axis=0) for x in range(n)])
        behind_any = np.stack([moved[max(0, x - length + 1) : x + 1].any(axis=0) for x in range(n)])
        np.testing.assert_array_equal(np.moveaxis(any_ahead(mask, axis, length), axis, 0), ahead_any)
        np.testing.assert_array_equal(np.moveaxis(all_ahead(mask, axis, length), axis, 0), ahead_all)
        np.testing.assert_array_equal(np.moveaxis(any_behind(mask, axis, length), axis, 0), behind_any)


def test_the_input_is_left_alone():
    mask = np.zeros((5, 5, 5), dtype=bool)
    mask[2, 2, 2] = True
    for result in (dilate(mask, 2), erode(mask), open_by_cube(mask, 3), any_ahead(mask, 0, 3), dilate_by_cube(mask)):
        assert result is not mask
    assert mask.sum() == 1
    assert dilate(mask, 2).sum() == 25  # the city-block ball of radius 2: 1 + 6 + 18 voxels


def test_labelled_picks_the_chosen_labels_never_the_background():
    labels = np.array([[[0, 1, 2, 3, 3, 0]]])
    np.testing.assert_array_equal(labelled(labels, [0, 3]), [[[False, False, False, True, True, False]]])
    np.testing.assert_array_equal(labelled(labels, []), np.zeros(labels.shape, dtype=bool))


@pytest.mark.parametrize("seed", range(3))
def test_block_reductions_match_a_loop_over_the_blocks(seed):
    """``block_max`` drops the partial blocks at the far sides, ``block_any`` keeps them (padded with False), and
    ``unblock`` takes ``block_any``'s cells back to the voxels, cut to the mask's shape."""
    for rng, mask in random_masks(seed):
        block = rng.integers(1, 4, size=3)
        values = rng.normal(size=mask.shape)
        kept = np.array(mask.shape) // block
        expected = np.zeros(kept)
        for index in np.ndindex(*kept):
            window = tuple(slice(i * b, (i + 1) * b) for i, b in zip(index, block))
            expected[index] = values[window].max()
        np.testing.assert_array_equal(block_max(values, block), expected)
        covered = -(-np.array(mask.shape) // block)
        expected_any = np.zeros(covered, dtype=bool)
        for index in np.ndindex(*covered):
            window = tuple(slice(i * b, (i + 1) * b) for i, b in zip(index, block))
            expected_any[index] = mask[window].any()
        np.testing.assert_array_equal(block_any(mask, block), expected_any)
        # unblock gives each voxel its block's value: back on the mask's grid, what block_any covers.
        back = unblock(expected_any, block, mask.shape)
        assert back.shape == mask.shape
        for index in np.ndindex(*mask.shape):
            assert back[index] == expected_any[tuple(np.array(index) // block)]
        assert not (mask & ~back).any()


def test_distances_through_a_mask_go_round_a_wall_in_steps_to_the_26_neighbours():
    """A 20-voxel cube (1 x 1 x 2 mm voxels) split by a wall at i = 10 with a gap at j >= 15: straight along j the
    distance is the straight one (10 steps of 1 mm); to the other side of the wall it goes round through the gap, 5
    diagonal and 8 straight steps each way; past the limit, in the wall or with no source, inf."""
    mask = np.ones((20, 20, 20), dtype=bool)
    mask[10, :15, :] = False
    sources = np.zeros_like(mask)
    sources[5, 2, 10] = True
    graph = VoxelGraph(mask, [1.0, 1.0, 2.0])
    distance = graph.distance(sources, limit_mm=40.0)
    assert distance[5, 2, 10] == 0.0 and distance[5, 12, 10] == pytest.approx(10.0)
    assert distance[5, 2, 13] == pytest.approx(6.0)  # 3 steps of 2 mm along k
    assert distance[15, 2, 10] == pytest.approx(2 * (5 * np.sqrt(2.0) + 8.0))
    assert np.isinf(distance[10, 5, 10])  # in the wall
    assert np.isinf(graph.distance(sources, limit_mm=5.0)[5, 12, 10])
    assert np.isinf(graph.distance(np.zeros_like(mask), limit_mm=40.0)).all()


def test_the_bounding_box_is_widened_by_its_pad_per_axis_and_cut_to_the_volume():
    """Voxels at (3, 5, 7) and (4, 9, 8) in a 10 x 12 x 9 volume: padded by 2 the box runs 1-6, 3-11, 5-9 (cut at the
    last slice); padded by (0, 1, 3), 3-4, 4-10, 4-9."""
    mask = np.zeros((10, 12, 9), dtype=bool)
    mask[3, 5, 7] = mask[4, 9, 8] = True
    low, high = bounding_box(mask, pad=2)
    assert low.tolist() == [1, 3, 5] and high.tolist() == [7, 12, 9]
    low, high = bounding_box(mask, pad=[0, 1, 3])
    assert low.tolist() == [3, 4, 4] and high.tolist() == [5, 11, 9]


def test_reaching_no_side_keeps_what_walls_enclose_and_not_what_leads_out_of_the_box():
    # A 10 x 10 x 10 box: a closed 6 x 6 x 6 shell of walls round a 4 x 4 x 4 cavity (64 voxels), whose outside
    # reaches the box's high side along axis 0 (open). The cavity is enclosed; the outside is not. A hole in the
    # shell joins the two: then nothing is.
    walls = np.zeros((10, 10, 10), dtype=bool)
    walls[2:8, 2:8, 2:8] = True
    walls[3:7, 3:7, 3:7] = False
    enclosed = reaching_no_side(~walls, [(0, -1)])
    assert enclosed.sum() == 64 and enclosed[3:7, 3:7, 3:7].all()
    walls[7, 4, 4] = False  # a hole through the shell's high face
    assert not reaching_no_side(~walls, [(0, -1)]).any()
    # With the low side along axis 2 open instead, the outside, and the cavity through the hole, lead out there.
    assert not reaching_no_side(~walls, [(2, 0)]).any()
