"""The IPC's last check (``image.ipc_self_check``): it never leaves holding a marker sphere's surface (issue 27: the
IPC written was the reference body's, with exit 0). Shapes built by hand, distances known."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.image.ipc_self_check import describe, spheres_in_surface
from RAMSICPRegistrationLib.image.marker_spheres import MarkerSphere

RADIUS = 5.75  # an NDI passive sphere of 11.5 mm


def _sphere(centre, number):
    return MarkerSphere(np.asarray(centre, float), RADIUS, 0.05, 0.9, "ok", 500, 1, number=number)


def _ball_surface(centre, radius, count=2000, keep=None):
    index = np.arange(count) + 0.5
    polar = np.arccos(1.0 - 2.0 * index / count)
    azimuth = np.pi * (1.0 + 5.0**0.5) * index
    unit = np.column_stack((np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)))
    if keep is not None:
        unit = unit[keep(unit)]
    return np.asarray(centre) + radius * unit


def _plane(z, half=40.0, step=0.5):
    """Points of the plane z = ``z`` (mm), 0.5 mm apart: a flat bone's surface."""
    x, y = np.meshgrid(np.arange(-half, half, step), np.arange(-half, half, step))
    return np.column_stack((x.ravel(), y.ravel(), np.full(x.size, z)))


def test_a_bone_surface_touching_a_spheres_shell_is_not_taken_for_the_sphere():
    """A plane 5.75 mm from a sphere's centre (tangent to the sphere itself, well inside the 1.5 mm shell) covers
    the cap of half-angle 37 degrees: a sixth of the directions with the 10 degree cone, under the 40 %."""
    sphere = _sphere((0.0, 0.0, RADIUS), 1)
    assert spheres_in_surface(_plane(0.0), [sphere]) == []
    assert spheres_in_surface(_plane(-4.0), [sphere]) == []  # 4 mm under the sphere: nothing on its shell


def test_a_sphere_whose_surface_is_in_the_ipc_is_found_with_its_number():
    """The IPC of the reference body: two spheres whole, one with the lower 35 % missing (its post and the frame
    it is sunk into), beside a bone plane far away; the third sphere's surface alone is not in the IPC."""
    body = [_sphere((0.0, 0.0, 30.0), 1), _sphere((40.0, 0.0, 30.0), 2), _sphere((0.0, 40.0, 30.0), 3)]
    points = np.vstack(
        [
            _plane(0.0),
            _ball_surface(body[0].centre, RADIUS),
            _ball_surface(body[1].centre, RADIUS + 0.6),  # a half-max surface a little outside the fitted sphere
        ]
    )
    found = spheres_in_surface(points, body)
    assert [item.number for item in found] == [1, 2]
    assert all(item.coverage > 0.95 and item.points > 1500 for item in found)
    sunk = _ball_surface(body[2].centre, RADIUS, keep=lambda unit: unit[:, 2] > -0.3)
    found = spheres_in_surface(np.vstack([points, sunk]), body)
    assert [item.number for item in found] == [1, 2, 3] and 0.55 < found[2].coverage < 0.8
    message = describe(found)
    assert "marker 1 at (0, 0, 30) mm" in message and "no IPC is written" in message


def test_a_speck_on_a_shell_is_not_a_sphere():
    sphere = _sphere((0.0, 0.0, 30.0), 4)
    speck = _ball_surface(sphere.centre, RADIUS, count=200, keep=lambda unit: unit[:, 0] > 0.0)[:20]
    assert spheres_in_surface(np.vstack([_plane(0.0), speck]), [sphere]) == []


@pytest.mark.parametrize("points", [np.zeros((0, 3)), _plane(0.0)])
def test_no_points_or_no_spheres_give_nothing(points):
    assert spheres_in_surface(points, []) == []
    assert spheres_in_surface(np.zeros((0, 3)), [_sphere((0.0, 0.0, 30.0), 1)]) == []


def _blurred(inside, spacing_mm=0.5, sigma_mm=0.3):
    """A CT (HU) of booleans ``inside`` -> values, blurred by a point spread of ``sigma_mm``."""
    from scipy import ndimage

    return ndimage.gaussian_filter(inside.astype(np.float32), sigma_mm / spacing_mm)


def _in_plane(shape=(100, 100, 12), spacing_mm=0.5):
    """(x, y) mm of every voxel of a grid of ``shape``, the axis (x = y = 0) through its middle."""
    i, j = np.meshgrid(*(np.arange(n) for n in shape[:2]), indexing="ij")
    x, y = ((i - (shape[0] - 1) / 2) * spacing_mm, (j - (shape[1] - 1) / 2) * spacing_mm)
    return np.repeat(x[:, :, None], shape[2], 2), np.repeat(y[:, :, None], shape[2], 2)


def test_the_cortex_under_a_tube_with_a_thick_cortex_is_read_and_a_solid_bar_has_none():
    """``cortex_under`` across the surface, in an image of 0.5 mm voxels blurred by 0.3 mm. A tibia's shaft: a tube
    15 mm in radius whose cortex (1,500 HU) is 7 mm thick round marrow (0 HU), as a real one has (the family's are
    4 mm at most). Its rim (0.5-2.5 mm in) is cortex; of the 19 samples 3-12 mm in, the 9 from 3 to 7 mm are cortex
    (the one at 7 mm on the marrow's edge, half of it): the rim is brighter by (1 - 8.5/19) x 1,500 = 829 HU. A square
    bar 16 mm across (1,000 HU) is the same all through: 0 HU at the middle of its faces. The blur takes a little off
    each (the rim's first sample, 0.5 mm in, is 1.7 sigmas from the edge), and the grid's staircase a little more."""
    from RAMSICPRegistrationLib.image.ipc_self_check import cortex_under

    spacing = np.full(3, 0.5)
    x, y = _in_plane()
    radius = np.hypot(x, y)
    tube = 1500.0 * _blurred((radius <= 15.0) & (radius > 8.0))
    angles = np.radians(np.arange(0, 360, 15))
    centre = (np.array(tube.shape) - 1) / 2
    on_tube = centre + np.column_stack((15.0 * np.cos(angles), 15.0 * np.sin(angles), np.zeros(len(angles)))) / 0.5
    contrast = cortex_under(tube, on_tube, spacing)
    assert np.all(np.abs(contrast - 829.0) < 60.0), contrast  # measured: 788-816 HU
    bar = 1000.0 * _blurred((np.abs(x) <= 8.0) & (np.abs(y) <= 8.0))
    faces = np.array([[8.0, 0.0], [-8.0, 0.0], [0.0, 8.0], [0.0, -8.0], [8.0, 3.0], [-3.0, -8.0]])
    on_bar = centre + np.column_stack((faces / 0.5, np.zeros(len(faces))))
    contrast = cortex_under(bar, on_bar, spacing)
    assert np.all(np.abs(contrast) < 25.0), contrast  # measured: -17 HU
