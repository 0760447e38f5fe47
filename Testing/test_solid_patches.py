"""Patches of the IPC over a solid part dimmer than the cortex (``image.solid_patches``): a rod resting on a long
bone, in a CT built by hand (0.5 mm voxels, blurred by 0.3 mm), its surface at the cortex's half-max."""

import types

import numpy as np
import pytest
from scipy import ndimage

from RAMSICPRegistrationLib.image.bone_recognition import BoneRecognition, ObjectVerdict
from RAMSICPRegistrationLib.image.ct_segmentation import BoneSurface
from RAMSICPRegistrationLib.image.iso_surface import iso_surface
from RAMSICPRegistrationLib.image.solid_patches import _in_patches, without_solid_patches
from RAMSICPRegistrationLib.image.volume_io import CTVolume

SPACING = 0.5
ROD_X = 14.5  # mm: the rod's axis, 4.5 mm in radius, rests on the bone's 10 mm radius


def _bone_and_rod(inner_radius_mm, rod_hu, cortex_hu=1500.0):
    """(CTVolume, segmentation-like, BoneSurface at 750 HU, (x, y) mm of its points from the bone's axis): a tube of
    cortex (10 mm outer radius) round marrow (0 HU) along k, and a rod (``rod_hu``, None for none) beside it."""
    shape = (110, 70, 24)
    i, j, _ = np.meshgrid(*(np.arange(n) for n in shape), indexing="ij")
    x, y = i * SPACING - 20.0, j * SPACING - 17.5
    radius = np.hypot(x, y)
    image = np.zeros(shape, np.float32)
    image[(radius <= 10.0) & (radius > inner_radius_mm)] = cortex_hu
    if rod_hu is not None:
        image[np.hypot(x - ROD_X, y) <= 4.5] = rod_hu
    image = ndimage.gaussian_filter(image, 0.3 / SPACING)
    volume = CTVolume(image, np.diag([SPACING, SPACING, SPACING, 1.0]))
    vertices, triangles = iso_surface(image, 750.0)
    points = volume.ijk_to_ras_points(vertices)
    bone = ObjectVerdict(1, 10_000.0, 10.0, 800.0, 0, "bone")  # the bone's verdict: a cortex
    recognition = BoneRecognition(1, None, 0.0, (bone,))
    segmentation = types.SimpleNamespace(smoothed=image, origin=np.zeros(3, int), recognition=recognition)
    return volume, segmentation, BoneSurface(points, triangles), points[:, :2] - [20.0, 17.5]


def _left_out(surface, kept):
    """(M,) booleans: the points of ``surface`` not in ``kept`` (a BoneSurface)."""
    remaining = {tuple(point) for point in np.round(kept.points, 6)}
    return np.array([tuple(point) not in remaining for point in np.round(surface.points, 6)])


def test_a_rod_dimmer_than_the_cortex_resting_on_the_bone_is_left_out_and_the_bone_kept():
    """A 9 mm rod of 900 HU resting on a tube whose 2 mm cortex is 1,500 HU (57010's kind: 875 HU on a 1,543 HU
    fibula). Under the rod's surface the CT peaks at 900 HU, below 750 + 0.65 x (1,500 - 750) = 1,237 HU, and is as
    bright 3-6 mm in; under the bone's, the cortex peaks at 1,500 HU and the marrow lies 3-6 mm in. Measured: 1,608 of
    the rod's 1,656 points left out (the rest where it meets the bone), none of the bone's."""
    volume, segmentation, surface, xy = _bone_and_rod(8.0, 900.0)
    left_out = _left_out(surface, without_solid_patches(volume, segmentation, surface))
    on_rod = np.hypot(xy[:, 0] - ROD_X, xy[:, 1]) < 4.6
    on_bone = (np.hypot(*xy.T) < 10.6) & ~on_rod
    assert left_out[on_rod].mean() > 0.95
    assert not left_out[on_bone].any()


@pytest.mark.parametrize("inner_radius_mm, rod_hu", [(3.0, None), (8.0, 2500.0)])
def test_a_thick_cortex_and_a_rod_brighter_than_the_cortex_are_not_taken(inner_radius_mm, rod_hu):
    """A cortex 7 mm thick (a real shaft's) is solid 3-6 mm in but is the brightest layer: kept, every point. A rod
    brighter than the cortex (2,500 HU) is no such patch either (the cortex read over the IPC is not above it): the
    rule leaves it to the other checks."""
    volume, segmentation, surface, _ = _bone_and_rod(inner_radius_mm, rod_hu)
    assert len(without_solid_patches(volume, segmentation, surface).points) == len(surface.points)


def test_only_patches_of_the_least_size_are_taken():
    """Two flagged patches on a strip of triangles, of 3 and 5 vertices, one lone flagged vertex: with a least size of
    4, only the 5 are taken."""
    triangles = np.array([[i, i + 1, i + 2] for i in range(14)])
    flagged = np.zeros(16, dtype=bool)
    flagged[[0, 1, 2]] = True  # 3 joined
    flagged[[5, 6, 7, 8, 9]] = True  # 5 joined
    flagged[13] = True  # alone
    taken = _in_patches(triangles, flagged, 4)
    assert np.flatnonzero(taken).tolist() == [5, 6, 7, 8, 9]
