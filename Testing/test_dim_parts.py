"""Where a part dimmer than the bone threshold meets the bone (``image.dim_parts``, issue 27): known geometry."""

import numpy as np
import pytest
from scipy import ndimage

from RAMSICPRegistrationLib.image.ct_segmentation import _near
from RAMSICPRegistrationLib.image.dim_parts import MARGIN_MM, MAX_CONTACT_MM2, dim_parts_at_bone
from RAMSICPRegistrationLib.image.morphology import block_max, block_mean

SPACING = np.array([0.6, 0.6, 0.6])
TOP_MM = 25.0  # the bone's top face
AXIS_MM = (35.0, 35.0)  # a rod's axis
ROD_RADIUS_MM = 3.0


def _ct(part=None, part_hu=120.0, noise_hu=10.0, seed=0):
    """(I, J, K) denoised HU on SPACING: a flat bone (60 x 60 x 10 mm of 1500 HU, its top face at TOP_MM) in 40 HU
    of tissue, and on it a ``part`` of ``part_hu``: 'rod' (6 mm across, 20 mm long, standing on it), 'pad' (45 x 45
    x 5 mm lying on it) or None; blurred (0.5 mm) and noisy. Returns it with the bone's voxels (the largest object
    above 200 HU)."""
    i, j, k = np.meshgrid(*[(np.arange(n) + 0.5) * 0.6 for n in (117, 117, 84)], indexing="ij")
    hu = np.full(i.shape, 40.0)
    hu[(np.abs(i - 35) <= 30) & (np.abs(j - 35) <= 30) & (np.abs(k - 20) <= 5)] = 1500.0
    if part == "rod":
        hu[((i - AXIS_MM[0]) ** 2 + (j - AXIS_MM[1]) ** 2 <= ROD_RADIUS_MM**2) & (k > TOP_MM) & (k <= TOP_MM + 20)] = (
            part_hu
        )
    elif part == "pad":
        hu[(np.abs(i - 35) <= 22.5) & (np.abs(j - 35) <= 22.5) & (k > TOP_MM) & (k <= TOP_MM + 5)] = part_hu
    hu = ndimage.gaussian_filter(hu, 0.5 / SPACING)
    hu += ndimage.gaussian_filter(np.random.default_rng(seed).normal(0.0, noise_hu, hu.shape), 0.3 / SPACING)
    hu = hu.astype(np.float32)
    labels, _ = ndimage.label(hu >= 200.0)
    return hu, labels == np.argmax(np.bincount(labels.ravel())[1:]) + 1


def _contacts_mm(hu, bone):
    low = np.argwhere(bone).min(axis=0)
    high = np.argwhere(bone).max(axis=0) + 1
    box = tuple(slice(a, b) for a, b in zip(low, high))
    return dim_parts_at_bone(hu, bone[box], low, SPACING) * SPACING


def test_a_dim_rod_standing_on_the_bone_is_met_at_its_foot_only():
    """A 120 HU rod, 80 HU above the tissue, standing on the bone: it meets the bone's blur at its foot, within a
    cell or two of its side and a few mm above the face; nowhere else."""
    contacts = _contacts_mm(*_ct("rod"))
    assert len(contacts) > 0
    from_axis = np.hypot(contacts[:, 0] - AXIS_MM[0], contacts[:, 1] - AXIS_MM[1])
    assert from_axis.max() <= ROD_RADIUS_MM + 2 * 1.5
    assert (contacts[:, 2] > TOP_MM).all() and (contacts[:, 2] < TOP_MM + 6.0).all()


@pytest.mark.parametrize("part, part_hu", [(None, 40.0), ("rod", 60.0)])
def test_tissue_and_its_noise_meet_no_part(part, part_hu):
    """Tissue alone (40 HU with noise) and a rod only 20 HU above it (under BRIGHTER_HU): nothing meets the bone."""
    assert len(_contacts_mm(*_ct(part, part_hu))) == 0


def test_a_part_lying_on_the_bone_over_a_wide_area_is_soft_tissue_not_a_bracket():
    """A 45 x 45 mm pad (2,025 mm^2, over MAX_CONTACT_MM2) as bright as the rod lying on the bone: soft tissue round
    a bone, not where a bracket meets it (an 18 mm dim bracket inserted into a bone meets its blur over 1,159 mm^2:
    wide seed 40272)."""
    assert 45.0 * 45.0 > MAX_CONTACT_MM2
    assert len(_contacts_mm(*_ct("pad"))) == 0


def test_a_noisier_ct_needs_a_brighter_part():
    """With 60 HU of noise in the tissue (its cells' spread about 15 HU), a rod 30 HU above the tissue is no part
    (NOISE_SIGMAS times the spread lifts the bar), a rod 120 HU above it is."""
    assert len(_contacts_mm(*_ct("rod", 70.0, noise_hu=60.0))) == 0
    assert len(_contacts_mm(*_ct("rod", 160.0, noise_hu=60.0))) > 0


def test_points_within_the_margin_of_where_a_part_meets_the_bone_are_near_it():
    contacts = np.array([[10.0, 10.0, 10.0]])  # indices on a 0.5 mm grid: (5, 5, 5) mm
    spacing = np.array([0.5, 0.5, 0.5])
    inside = (MARGIN_MM - 0.1) / 0.5
    outside = (MARGIN_MM + 0.1) / 0.5
    vertices = np.array([[10.0 + inside, 10.0, 10.0], [10.0, 10.0 + outside, 10.0], [10.0, 10.0, 10.0]])
    assert _near(vertices, contacts, spacing, MARGIN_MM).tolist() == [True, False, True]


def test_block_means_and_maxima_are_over_whole_blocks():
    image = np.arange(5 * 4 * 3).reshape(5, 4, 3)
    means, maxima = block_mean(image, np.array([2, 2, 1])), block_max(image, np.array([2, 2, 1]))
    assert means.shape == maxima.shape == (2, 2, 3) and means.dtype == np.float32
    assert means[1, 0, 2] == pytest.approx(image[2:4, 0:2, 2].mean()) and maxima[1, 0, 2] == image[3, 1, 2]
