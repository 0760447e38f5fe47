"""Shared fixtures: known transforms and analytic surfaces whose answers can be computed by hand."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.transforms import make_transform, rotation_about_axis


def random_transform(rng, max_angle_deg=180.0, max_translation_mm=100.0):
    """A random rigid (4, 4) transform."""
    axis = rng.normal(size=3)
    angle = np.radians(rng.uniform(-max_angle_deg, max_angle_deg))
    return make_transform(rotation_about_axis(axis, angle), rng.uniform(-max_translation_mm, max_translation_mm, 3))


def ellipsoid_points(count, semi_axes=(40.0, 25.0, 15.0), seed=0):
    """(count, 3) points on an ellipsoid surface (mm): a closed surface that fixes all six pose parameters."""
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    return directions * np.asarray(semi_axes)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def tibia_patient():
    """The demo's virtual patient: the shipped right tibia with an NDI 8700339 reference body."""
    from RAMSICPRegistrationLib.package_data import BONES, bone_mesh_path, tool_marker_geometry
    from RAMSICPRegistrationLib.surface_files import read_surface_mesh
    from RAMSICPRegistrationLib.virtual_patient import VirtualPatient

    vertices, triangles = read_surface_mesh(bone_mesh_path("right-tibia"))
    return VirtualPatient.from_mesh(vertices, triangles, tool_marker_geometry(), BONES["right-tibia"]["medial"])


@pytest.fixture(scope="session")
def tibia_index(tibia_patient):
    from RAMSICPRegistrationLib.surface_index import SurfaceIndex

    return SurfaceIndex(tibia_patient.ipc)
