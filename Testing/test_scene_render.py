"""The offscreen picture: a PNG of the right size in which residuals show as green (0 mm) and red (1 mm)."""

import numpy as np
from vtkmodules.util.numpy_support import vtk_to_numpy
from vtkmodules.vtkIOImage import vtkPNGReader

from RAMSICPRegistrationLib.navigation.scene_render import render_registration

from conftest import ellipsoid_points


def test_render_shows_residual_colours(tmp_path):
    surface = ellipsoid_points(3000, semi_axes=(20.0, 15.0, 60.0))
    probe = np.array([[-16.0, 12.0, -20.0], [-16.0, 12.0, 20.0]])  # on the side facing the camera
    markers = np.array([[60.0, -60.0, -30.0], [60.0, -60.0, 30.0], [60.0, -90.0, 0.0]])  # behind the bone
    path = tmp_path / "scene.png"
    render_registration(path, surface, None, probe, [0.0, 1.0], markers, size=(400, 300))
    reader = vtkPNGReader()
    reader.SetFileName(str(path))
    reader.Update()
    image = reader.GetOutput()
    assert image.GetDimensions()[:2] == (400, 300)
    pixels = vtk_to_numpy(image.GetPointData().GetScalars())[:, :3].astype(int).reshape(300, 400, 3)
    scene = pixels[:, :300]  # left of the colour bar, which has both colours too
    green = (scene[..., 1] > 150) & (scene[..., 0] < 90) & (scene[..., 2] < 90)
    red = (scene[..., 0] > 150) & (scene[..., 1] < 90) & (scene[..., 2] < 90)
    assert green.sum() > 3 and red.sum() > 3  # the 0 mm point and the 1 mm point
