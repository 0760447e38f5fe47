"""The offscreen picture: residual colours, targets, the legend's band kept free, and clear errors for bad paths."""

import numpy as np
import pytest
from vtkmodules.util.numpy_support import vtk_to_numpy
from vtkmodules.vtkIOImage import vtkPNGReader

from RAMSICPRegistrationLib.navigation.scene_render import render_registration

from conftest import ellipsoid_points

SURFACE = ellipsoid_points(3000, semi_axes=(20.0, 15.0, 60.0))
PROBE = np.array([[-16.0, 12.0, -20.0], [-16.0, 12.0, 20.0]])  # on the side facing the camera
MARKERS = np.array([[60.0, -60.0, -30.0], [60.0, -60.0, 30.0], [60.0, -90.0, 0.0]])  # behind the bone
TARGETS = np.array([[-20.0, 0.0, 40.0], [0.0, 15.0, 40.0]])  # the medial and anterior ends of a cut at z = 40


def _pixels(path):
    reader = vtkPNGReader()
    reader.SetFileName(str(path))
    reader.Update()
    image = reader.GetOutput()
    width, height = image.GetDimensions()[:2]
    rgb = vtk_to_numpy(image.GetPointData().GetScalars())[:, :3].astype(int).reshape(height, width, 3)
    return rgb[::-1]  # top row first, as the picture is seen


def test_render_shows_residual_colours_targets_and_a_scale_bar(tmp_path):
    path = tmp_path / "scene.png"
    cut = (np.array([0.0, 0.0, 40.0]), np.array([0.0, 0.0, 1.0]))
    render_registration(path, SURFACE, None, PROBE, [0.0, 1.0], MARKERS, targets=TARGETS, cut=cut, size=(800, 600))
    pixels = _pixels(path)
    assert pixels.shape == (600, 800, 3)
    scene = pixels[140:, 150:640]  # below the title and the legend, left of the colour bar
    green = (scene[..., 1] > 150) & (scene[..., 0] < 90) & (scene[..., 2] < 90)
    red = (scene[..., 0] > 150) & (scene[..., 1] < 90) & (scene[..., 2] < 90)
    magenta = (scene[..., 0] > 180) & (scene[..., 2] > 160) & (scene[..., 1] < 110)
    assert green.sum() > 3 and red.sum() > 3  # the 0 mm point and the 1 mm point
    assert magenta.sum() > 20  # a 6 mm target cube
    corner = pixels[-70:, -300:]  # the scale bar: a white line in the lower right
    assert ((corner > 230).all(axis=-1)).sum() > 100


@pytest.mark.parametrize(
    "name, words",
    [("missing/scene.png", "does not exist"), ("scene.jpg", "ending in .png"), (".", "is a folder")],
)
def test_bad_paths_are_refused_before_rendering(tmp_path, name, words):
    with pytest.raises(ValueError, match=words):
        render_registration(tmp_path / name, SURFACE, None, PROBE, [0.0, 1.0], MARKERS)


def test_a_headless_screenshot_says_nothing_about_an_x_server(tmp_path):
    """Issue 14, item 6: every headless screenshot printed VTK's ``bad X server connection. DISPLAY=``; without a
    display the picture is rendered through EGL, chosen before VTK's first window, and nothing is printed."""
    import os
    import subprocess
    import sys

    script = (
        "import sys, numpy as np\n"
        "from RAMSICPRegistrationLib.navigation.scene_render import render_registration\n"
        "surface = np.random.default_rng(0).normal(size=(500, 3)) * 20.0\n"
        "render_registration(sys.argv[1], surface, None, surface[:2], [0.0, 1.0], surface[2:5], size=(300, 200))\n"
    )
    environment = {key: value for key, value in os.environ.items() if key not in ("DISPLAY", "WAYLAND_DISPLAY")}
    environment.pop("VTK_DEFAULT_OPENGL_WINDOW", None)
    path = tmp_path / "headless.png"
    completed = subprocess.run(
        [sys.executable, "-c", script, str(path)], capture_output=True, text=True, env=environment, timeout=120
    )
    assert completed.returncode == 0, completed.stderr
    assert "X server" not in completed.stderr and "DISPLAY" not in completed.stderr, completed.stderr
    assert _pixels(path).shape == (200, 300, 3)
