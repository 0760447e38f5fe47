"""Balls on a surface mesh (``image.surface_balls``) and the IPC's check for marker spheres no look at the CT found
(``ipc_self_check.unfound_spheres_in_surface``). Meshes are iso-surfaces of shapes built by hand (signed distances
on a 0.5 mm grid), so every centre and distance is known: spheres sunk into a plate as family seed 40192's are, a
shaft as thick as a marker, a rod's rounded end, and the tool's own distances against others."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.image.ipc_self_check import describe_unfound, unfound_spheres_in_surface
from RAMSICPRegistrationLib.image.iso_surface import iso_surface
from RAMSICPRegistrationLib.image.surface_balls import find_balls, vertex_normals
from RAMSICPRegistrationLib.io.ndi_tools import tool_marker_geometry

RADIUS = 5.75  # an NDI passive sphere of 11.5 mm
STEP = 0.5  # mm
TOOL = tool_marker_geometry()


def _mesh(distance, low, high):
    """The surface where ``distance`` (a signed distance in mm, negative inside, of (..., 3) points) is 0, over the
    box ``low``-``high`` (mm) on a 0.5 mm grid: points (N, 3) mm and triangles."""
    axes = [np.arange(a, b + STEP / 2, STEP) for a, b in zip(low, high)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    vertices, triangles = iso_surface(-distance(grid), 0.0)
    return np.asarray(low, float) + vertices * STEP, triangles


def _ball(centre):
    return lambda p: np.linalg.norm(p - np.asarray(centre, float), axis=-1) - RADIUS


def _slab(thickness, half=200.0):
    return lambda p: np.maximum(np.abs(p[..., 2]) - thickness / 2.0, np.abs(p[..., :2]).max(axis=-1) - half)


def _union(*shapes):
    return lambda p: np.min([shape(p) for shape in shapes], axis=0)


def _sunk_spheres(centres, plate_mm=7.7):
    """Spheres sunk into a plate ``plate_mm`` thick (its mid-plane z = 0), their caps standing out on both sides."""
    centres = np.asarray(centres, float)
    low, high = centres.min(axis=0) - 12.0, centres.max(axis=0) + 12.0
    plate = _slab(plate_mm, half=float(np.abs(np.concatenate([low, high])).max()) - 4.0)
    return _mesh(_union(plate, *[_ball(c) for c in centres]), low, high)


def _tool_pair():
    """Two of the tool's markers, laid in the plate's mid-plane: (2, 3) mm, and their distance."""
    apart = float(np.linalg.norm(TOOL[0] - TOOL[1]))
    return np.array([[-apart / 2.0, 0.3, 0.0], [apart / 2.0, 0.3, 0.0]]), apart


def test_normals_of_a_balls_mesh_point_along_its_radii():
    points, triangles = _mesh(_ball((0.0, 0.0, 0.0)), (-8, -8, -8), (8, 8, 8))
    normals = vertex_normals(points, triangles)
    radial = points / np.linalg.norm(points, axis=1, keepdims=True)
    assert np.all(np.abs(np.sum(normals * radial, axis=1)) > 0.99)


def test_a_whole_ball_and_spheres_sunk_into_a_plate_are_found_at_their_centres():
    points, triangles = _mesh(_ball((1.2, -0.7, 0.4)), (-9, -9, -9), (9, 9, 9))
    centres = find_balls(points, triangles, RADIUS)
    assert len(centres) == 1 and np.linalg.norm(centres[0] - (1.2, -0.7, 0.4)) < 0.3
    truth, _ = _tool_pair()
    points, triangles = _sunk_spheres(truth)  # caps 1.9 mm high on both sides, as in 40192
    centres = find_balls(points, triangles, RADIUS)
    assert len(centres) == 2
    for centre in truth:
        assert np.linalg.norm(centres - centre, axis=1).min() < 0.3


def test_a_shaft_as_thick_as_a_marker_and_a_rods_rounded_end_are_no_balls():
    """A shaft of the marker's radius: its votes meet on its axis, from directions in a plane. A rod's rounded end:
    from one side only."""
    shaft = lambda p: np.maximum(np.linalg.norm(p[..., :2], axis=-1) - RADIUS, np.abs(p[..., 2]) - 30.0)  # noqa: E731
    points, triangles = _mesh(shaft, (-9, -9, -34), (9, 9, 34))
    assert len(find_balls(points, triangles, RADIUS)) == 0

    def rod(p):  # a capsule: the axis from z = -30 to z = 0, rounded at both ends
        along = np.clip(p[..., 2], -30.0, 0.0)
        return np.linalg.norm(p - np.stack([0 * along, 0 * along, along], axis=-1), axis=-1) - RADIUS

    points, triangles = _mesh(rod, (-9, -9, -38), (9, 9, 8))
    assert len(find_balls(points, triangles, RADIUS)) == 0


def test_spheres_sunk_into_a_plate_at_the_tools_distance_are_the_reference_bodys():
    truth, apart = _tool_pair()
    points, triangles = _sunk_spheres(truth)
    found = unfound_spheres_in_surface(points, triangles, TOOL)
    assert len(found) == 2 and all(item.coverage > 0.4 and item.number == 0 for item in found)
    words = describe_unfound(found)
    assert "no marker sphere was found, but the surface taken for the bone holds 2 balls" in words
    assert "no IPC is written" in words


@pytest.mark.parametrize("shift", [2.6, -3.5, 28.0])
def test_two_balls_at_no_distance_of_the_tools_are_not_its_spheres(shift):
    """The same plate and spheres, one moved so that they lie off every distance of the tool's by more than 2 mm."""
    truth, apart = _tool_pair()
    distances = np.linalg.norm(TOOL[:, None] - TOOL[None], axis=-1)[np.triu_indices(len(TOOL), 1)]
    truth[1, 0] += shift
    assert np.abs(distances - np.linalg.norm(truth[1] - truth[0])).min() > 2.0
    points, triangles = _sunk_spheres(truth)
    assert len(find_balls(points, triangles, RADIUS)) == 2  # the balls are there ...
    assert unfound_spheres_in_surface(points, triangles, TOOL) == []  # ... but not at the tool's distances


def test_no_mesh_gives_nothing():
    assert len(find_balls(np.zeros((0, 3)), np.zeros((0, 3), int), RADIUS)) == 0
    assert unfound_spheres_in_surface(np.zeros((0, 3)), None, TOOL) == []
    plane = _mesh(_slab(4.0, half=30.0), (-34, -34, -6), (34, 34, 6))
    assert len(find_balls(*plane, RADIUS)) == 0
