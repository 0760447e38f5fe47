"""Spots as thick as a marker ball (``image.thick_spots``), on a CT whose geometry is built by hand: spheres dimmer than
the plate they are sunk into, beside a rod, a slab and a block as thick as a ball or thicker, which are no spots."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.image.ct_segmentation import threshold_ct
from RAMSICPRegistrationLib.image.thick_spots import thick_spots
from RAMSICPRegistrationLib.image.volume_io import CTVolume

RADIUS_MM = 5.75
#: Sphere centres (mm, RAS = voxel index times spacing from the origin), 2 mm off the plate's mid-plane for one.
CENTRES = np.array([[20.0, 20.0, 15.0], [75.0, 22.0, 15.0], [30.0, 70.0, 17.0], [70.0, 65.0, 15.0]])


def _ct(spacing):
    """A 5 mm plate of 1,900 HU (z 12.5-17.5 mm) holding four spheres of 690 HU (CENTRES); beside it a rod of the
    ball's radius along x, a 12 mm slab and a 16 mm cube, all of 1,300 HU, in air (-1,000 HU)."""
    shape = np.round(np.array([100.0, 100.0, 60.0]) / spacing).astype(int)
    x, y, z = np.meshgrid(*[np.arange(n) * s for n, s in zip(shape, spacing)], indexing="ij")
    voxels = np.full(shape, -1000.0, dtype=np.float32)
    voxels[(x < 90) & (y < 90) & (np.abs(z - 15.0) <= 2.5)] = 1900.0
    for centre in CENTRES:
        voxels[(x - centre[0]) ** 2 + (y - centre[1]) ** 2 + (z - centre[2]) ** 2 <= RADIUS_MM**2] = 690.0
    voxels[(np.hypot(y - 45.0, z - 42.0) <= RADIUS_MM) & (x > 10) & (x < 90)] = 1300.0  # a rod
    voxels[(x > 10) & (x < 40) & (y > 75) & (y < 95) & (np.abs(z - 45.0) <= 6.0)] = 1300.0  # a slab
    voxels[(np.abs(x - 70.0) <= 8) & (np.abs(y - 82.0) <= 8) & (np.abs(z - 45.0) <= 8)] = 1300.0  # a block
    ijk_to_ras = np.diag([*spacing, 1.0])
    return CTVolume(voxels, ijk_to_ras)


@pytest.mark.parametrize("spacing", [(0.5, 0.5, 0.5), (0.7, 0.7, 1.0), (1.0, 1.0, 1.0)])
def test_spheres_sunk_into_a_brighter_plate_are_found_and_nothing_else(spacing):
    volume = _ct(np.array(spacing))
    spots = thick_spots(volume, threshold_ct(volume), RADIUS_MM)
    assert len(spots) == len(CENTRES)
    distances = np.linalg.norm(spots[:, None] - CENTRES[None], axis=-1)
    assert sorted(distances.argmin(axis=1)) == [0, 1, 2, 3]
    assert distances.min(axis=1).max() < 1.0  # within the tool's pairing tolerance (2 mm) with room to spare


def test_a_speck_above_the_threshold_is_no_spot():
    volume = CTVolume(np.full((20, 20, 20), -1000.0, dtype=np.float32), np.eye(4))
    volume.voxels[5:8, 5:8, 5:8] = 400.0  # a speck: some object, no ball
    assert thick_spots(volume, threshold_ct(volume), RADIUS_MM).shape == (0, 3)
