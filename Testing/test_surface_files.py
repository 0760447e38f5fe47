"""Surface files via VTK: round trips in every format, Slicer's SPACE tags, untagged data, corrupt files."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.io.point_files import PointFileError, write_points
from RAMSICPRegistrationLib.io.surface_files import read_surface_mesh, read_surface_points, write_surface
from RAMSICPRegistrationLib.simulation.package_data import bone_mesh_path

TETRA = np.array([[10.0, 20.0, 30.0], [15.0, 20.0, 30.0], [10.0, 26.0, 30.0], [10.0, 20.0, 37.0]])
FACES = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


@pytest.mark.parametrize("suffix", [".vtk", ".vtp", ".stl", ".ply", ".obj"])
def test_round_trip_keeps_ras_coordinates(tmp_path, suffix):
    path = tmp_path / f"tetra{suffix}"
    write_surface(path, TETRA, FACES)
    vertices, triangles = read_surface_mesh(path)
    assert len(triangles) == 4
    # STL stores float32 and repeats vertices per triangle: compare as sets.
    for vertex in TETRA:
        assert np.min(np.linalg.norm(vertices - vertex, axis=1)) < 1e-5


@pytest.mark.parametrize("suffix", [".vtk", ".stl", ".ply", ".obj", ".vtp"])
def test_files_are_tagged_lps_like_slicer(tmp_path, suffix):
    path = tmp_path / f"t{suffix}"
    write_surface(path, TETRA, FACES)
    assert b"SPACE" in path.read_bytes()
    # Read as if untagged files were LPS: a tagged file must still come back in RAS.
    vertices = read_surface_points(path, untagged_space="LPS")
    assert np.min(np.linalg.norm(vertices - TETRA[0], axis=1)) < 1e-5


def test_point_cloud_without_faces_round_trips(tmp_path):
    path = tmp_path / "cloud.vtp"
    write_surface(path, TETRA)
    vertices, triangles = read_surface_mesh(path)
    np.testing.assert_allclose(vertices, TETRA, atol=1e-12)
    assert triangles.shape == (0, 3)


def test_untagged_stl_follows_untagged_space():
    ras = read_surface_points(bone_mesh_path("right-tibia"), untagged_space="RAS")
    lps = read_surface_points(bone_mesh_path("right-tibia"), untagged_space="LPS")
    assert ras[:, 0].min() > 500  # the shipped tibia's frame: x from 567.8 to 655.7 mm
    np.testing.assert_allclose(lps, ras * [-1, -1, 1])


def test_ipc_may_be_a_point_file(tmp_path):
    write_points(tmp_path / "ipc.csv", TETRA)
    np.testing.assert_allclose(read_surface_points(tmp_path / "ipc.csv"), TETRA)


@pytest.mark.parametrize("suffix", [".vtk", ".vtp", ".stl", ".ply", ".obj"])
def test_corrupt_surface_gives_one_line_error(tmp_path, suffix):
    path = tmp_path / f"broken{suffix}"
    path.write_bytes(b"this is not a mesh\n" * 3)
    with pytest.raises(PointFileError) as error:
        read_surface_mesh(path)
    assert str(error.value).startswith(str(path)) and "\n" not in str(error.value)


def test_missing_and_unknown_surface_files(tmp_path):
    with pytest.raises(PointFileError, match="no such file"):
        read_surface_mesh(tmp_path / "none.stl")
    (tmp_path / "mesh.off").write_text("OFF\n")
    with pytest.raises(PointFileError, match="unknown surface type"):
        read_surface_mesh(tmp_path / "mesh.off")
