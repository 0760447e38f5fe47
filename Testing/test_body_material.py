"""Plateaus of one material (``image.body_material``): the levels read among cells and the plateau that reaches the
body, on grids whose materials, blur and noise are known."""

import numpy as np
from scipy import ndimage

from RAMSICPRegistrationLib.image.body_material import (
    BAND_HU,
    MIN_LEVEL_CELLS,
    NOISY_HU,
    averaged_means,
    levels_among,
    means_noise_hu,
    plateau,
    plateau_from_nearest,
)
from RAMSICPRegistrationLib.image.morphology import erode

#: A flat bone resting under a bar, on a grid of 1 mm cells: the bone's cortex (2 cells) round its inside, the bar on
#: its upper cortex, and air round both.
CORTEX_HU, INSIDE_HU, BAR_HU, AIR_HU = 850.0, 500.0, 670.0, -1000.0


def bar_on_a_flat_bone(noise_hu=0.0, seed=0):
    """(mean_hu (40, 30, 40), bone, bar, inside): a 16-cell bar lying along a flat bone 18 cells thick, blurred by
    0.6 cells as a CT's block means are, with ``noise_hu`` of white noise."""
    grid = np.full((40, 30, 40), AIR_HU)
    bone = np.zeros(grid.shape, dtype=bool)
    bone[2:38, 2:28, 2:20] = True
    inside = np.zeros(grid.shape, dtype=bool)
    inside[4:36, 4:26, 4:18] = True
    bar = np.zeros(grid.shape, dtype=bool)
    bar[12:28, 2:28, 20:36] = True  # resting on the bone's upper side, as long as the bone is wide
    grid[bone] = CORTEX_HU
    grid[inside] = INSIDE_HU
    grid[bar] = BAR_HU
    grid = ndimage.gaussian_filter(grid, 0.6)
    grid += np.random.default_rng(seed).normal(0.0, noise_hu, grid.shape)
    return grid.astype(np.float32), bone, bar, inside


def test_the_levels_are_the_materials_most_common_first_and_not_the_blur_between_them():
    grid, bone, bar, inside = bar_on_a_flat_bone(noise_hu=10.0)
    levels = levels_among(grid, bone | bar)
    # the bone's inside has the most cells, then the bar; the cortex, 2 cells thick, is all blur
    assert len(levels) == 2
    assert abs(levels[0] - INSIDE_HU) < 5.0 and abs(levels[1] - BAR_HU) < 5.0
    ramp = np.linspace(0.0, 2000.0, 40, dtype=np.float32)[:, None, None] * np.ones((1, 10, 10), np.float32)
    within = np.zeros(ramp.shape, dtype=bool)
    within[1:-1] = True  # (at the grid's ends the neighbourhood is cut)
    assert levels_among(ramp, within) == []  # 51 HU a cell: nothing flat enough ...
    gentle = ramp / 40.0  # 1.3 HU a cell
    assert len(levels_among(gentle, np.ones(gentle.shape, dtype=bool))) == 1  # ... but this is one material


def test_a_level_needs_enough_flat_cells_and_levels_stand_apart():
    grid = np.full((12, 12, 12), 300.0, dtype=np.float32)
    grid[:, :, 6:] = 300.0 + 0.5 * BAND_HU  # two levels closer than the band: read as one
    levels = levels_among(grid, np.ones(grid.shape, dtype=bool))
    assert len(levels) == 1 and 300.0 <= levels[0] <= 300.0 + 0.5 * BAND_HU
    few = np.zeros(grid.shape, dtype=bool)
    few[5, 5, : MIN_LEVEL_CELLS - 1] = True
    assert levels_among(grid, few) == []


def thin_bar(cells_wide, noise_hu, bar_hu=1300.0):
    """(mean_hu (20, 20, 30), bar): a square bar ``cells_wide`` cells across and 26 long in air, blurred by 0.6 cells,
    with ``noise_hu`` of white noise."""
    grid = np.full((20, 20, 30), AIR_HU)
    bar = np.zeros(grid.shape, dtype=bool)
    bar[8 : 8 + cells_wide, 8 : 8 + cells_wide, 2:28] = True
    grid[bar] = bar_hu
    grid = ndimage.gaussian_filter(grid, 0.6) + np.random.default_rng(0).normal(0.0, noise_hu, grid.shape)
    return grid.astype(np.float32), bar


def test_a_thin_bars_level_is_read_among_its_deep_cells_where_every_neighbourhood_meets_its_blur():
    """A bar 4 cells across (a 7.3 mm bar on cells of 1.5 mm: wide seed 40278), or 6 under 25 HU of noise: every
    3 x 3 x 3 neighbourhood of its deep cells reaches the blur at its surface or spans the noise, and no level is read;
    with the neighbourhoods taken among those cells, the bar's is, within 15 HU (its 2 x 2 core is a cell from the
    blur on every side). Among cells that hold two materials, the step between them is still no level."""
    for cells_wide, noise, deep_by in ((4, 15.0, 1), (6, 25.0, 2)):
        grid, bar = thin_bar(cells_wide, noise)
        deep = ndimage.binary_erosion(bar, iterations=deep_by)
        assert levels_among(grid, deep) == []
        levels = levels_among(grid, deep, neighbours_among_cells=True)
        assert len(levels) == 1 and abs(levels[0] - 1300.0) < 15.0
    grid, bone, bar, _ = bar_on_a_flat_bone(noise_hu=10.0)
    levels = levels_among(grid, bone | bar, neighbours_among_cells=True)
    assert len(levels) == 2 and abs(levels[0] - INSIDE_HU) < 5.0 and abs(levels[1] - BAR_HU) < 5.0


def test_the_bars_plateau_is_the_bar_and_not_the_bone_it_rests_on():
    for seed in range(3):
        grid, bone, bar, inside = bar_on_a_flat_bone(noise_hu=15.0, seed=seed)
        seeds = np.zeros(grid.shape, dtype=bool)
        seeds[14:26, 20:23, 24:32] = True  # cells across the bar, where a cut ran through it
        found = plateau(grid, bone | bar, BAR_HU, seeds)
        assert (found & bone).sum() == 0  # not a cell of the cortex or the inside
        # the bar less the blur at its edge (a cell or two), and no more
        core = ndimage.binary_erosion(bar, iterations=2)
        assert (found & core).sum() == core.sum() and found.sum() <= bar.sum()


def test_the_bones_inside_is_a_plateau_of_its_own_that_the_bars_does_not_reach():
    grid, bone, bar, inside = bar_on_a_flat_bone()
    seeds = np.zeros(grid.shape, dtype=bool)
    seeds[14:26, 20:23, 24:32] = True
    assert not plateau(grid, bone | bar, INSIDE_HU, seeds).any()  # the inside does not reach the bar's seeds
    inner = np.zeros(grid.shape, dtype=bool)
    inner[20, 15, 10] = True
    found = plateau(grid, bone | bar, INSIDE_HU, inner)
    assert (found & ~inside).sum() == 0 and found.sum() >= ndimage.binary_erosion(inside).sum()
    assert not plateau(grid, np.zeros(grid.shape, dtype=bool), BAR_HU, seeds).any()  # nothing among no cells


def test_a_plateau_whose_seeds_all_lie_in_the_blur_grows_from_its_cells_nearest_the_body():
    """The body's side 2 mm above the bar's top cell (a cut's margin): the bar's cells within 3 mm of it are its top
    layer, in the blur with the air above, and grow nothing; the cells at the bar's level nearest the body (within a
    cell of the nearest, among those within 8 mm of it, where the level is read) grow the bar's plateau, and nothing
    of the bone."""
    grid, bone, bar, inside = bar_on_a_flat_bone(noise_hu=10.0)
    among = bone | bar
    to_body = np.broadcast_to(37.5 - np.arange(40.0), grid.shape)  # mm; the bar's top cell (k = 35) 2.5 mm off
    seeds = among & (to_body <= 3.0)
    candidates = among & (to_body <= 8.0)
    assert seeds.any() and (seeds <= bar).all() and not plateau(grid, among, BAR_HU, seeds).any()
    found = plateau_from_nearest(grid, among, BAR_HU, seeds, candidates, to_body, 1.0)
    core = ndimage.binary_erosion(bar, iterations=2)
    assert (found & bone).sum() == 0 and (found & core).sum() == core.sum() and found.sum() <= bar.sum()
    # seeds that reach the plateau are used as they are; no candidate at the level grows nothing
    touching = np.zeros(grid.shape, dtype=bool)
    touching[14:26, 20:23, 24:32] = True
    assert np.array_equal(
        plateau_from_nearest(grid, among, BAR_HU, touching, candidates, to_body, 1.0),
        plateau(grid, among, BAR_HU, touching),
    )
    assert not plateau_from_nearest(grid, among, 2000.0, seeds, candidates, to_body, 1.0).any()


def test_the_noise_of_the_means_is_read_from_neighbouring_deep_cells():
    """White noise of known deviation added to the blurred grid: read among the cells two cells deep (the steps at the
    cortex's edges lift it a little: 11.3 HU for 10 measured), none on a clean grid, none where no two cells meet."""
    for noise in (0.0, 10.0, 40.0, 60.0):
        grid, bone, bar, _ = bar_on_a_flat_bone(noise_hu=noise, seed=1)
        deep = erode(erode(bone | bar))
        assert abs(means_noise_hu(grid, deep) - noise) <= 0.15 * noise + 1e-9
    lone = np.zeros(grid.shape, dtype=bool)
    lone[5, 5, 5] = lone[7, 7, 7] = True
    assert means_noise_hu(grid, lone) == 0.0


def test_under_heavy_noise_the_levels_are_read_from_the_averaged_means():
    """Under 40-60 HU of noise no 3 x 3 x 3 neighbourhood spans less than the band: no level is read from the means;
    averaged over each cell's neighbours within the object (air not mixed in), the inside's and the bar's are, within
    15 HU (the bar's edge, a cell from the cortex, pulls its level down by 7-11 HU). Outside the object the means are
    left as they are."""
    for noise in (40.0, 60.0):
        grid, bone, bar, _ = bar_on_a_flat_bone(noise_hu=noise, seed=2)
        assert noise * 0.85 > NOISY_HU
        assert levels_among(grid, bone | bar) == []
        averaged = averaged_means(grid, bone | bar)
        levels = levels_among(averaged, bone | bar)
        assert len(levels) == 2
        assert abs(levels[0] - INSIDE_HU) < 15.0 and abs(levels[1] - BAR_HU) < 15.0
        assert np.array_equal(averaged[~(bone | bar)], grid[~(bone | bar)])
        corner = averaged[2, 2, 2]  # a corner of the bone: the mean of its 8 neighbours in the object, no air
        assert abs(corner - grid[2:4, 2:4, 2:4].astype(np.float64).mean()) < 1e-6
