"""The osteotomy plane placed by numbers (``core.plane_placement``) and through the controller, as the browser page
places it: known answers on a cylinder along S, the round trip over random placements on the shipped bones, and the
plan on the placed plane."""

import sys

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.plane_placement import (
    PlanePlacement,
    bone_frame,
    placed_plane,
    placement_of,
    placement_through,
)

from conftest import CYLINDER_RADIUS_MM as R
from conftest import cylinder_mesh, headless_scene


def test_on_a_cylinder_along_s_the_numbers_mean_what_they_say():
    vertices, _ = cylinder_mesh()  # axis +z (S), 0 <= z <= 100
    frame = bone_frame(vertices)
    np.testing.assert_allclose(frame.axis, (0, 0, 1), atol=1e-9)
    np.testing.assert_allclose(frame.anterior, (0, 1, 0), atol=1e-9)
    np.testing.assert_allclose(frame.side, (-1, 0, 0), atol=1e-9)  # S x A = L (RAS -x)
    assert frame.length_mm == pytest.approx(100.0)
    origin, normal, depth = placed_plane(frame, PlanePlacement(level_mm=30.0))
    np.testing.assert_allclose(origin[2], 70.0, atol=1e-9)  # 30 mm below the top (z = 100)
    np.testing.assert_allclose(normal, (0, 0, 1), atol=1e-12)
    np.testing.assert_allclose(depth, (0, -1, 0), atol=1e-12)  # entering from anterior, advancing posterior
    _, normal, depth = placed_plane(frame, PlanePlacement(30.0, tilt_anterior_deg=10.0, entry_deg=90.0))
    np.testing.assert_allclose(normal, (0.0, np.sin(np.radians(10)), np.cos(np.radians(10))), atol=1e-12)
    np.testing.assert_allclose(depth, (1.0, 0.0, 0.0), atol=1e-12)  # from the left (-x) towards the right
    through = placement_through(frame, (R, 0.0, 40.0))  # a tip on the right-hand side at z = 40
    assert through.level_mm == pytest.approx(60.0) and through.entry_deg == pytest.approx(270.0)
    with pytest.raises(ValueError, match="at most 60 degrees"):
        placed_plane(frame, PlanePlacement(30.0, tilt_side_deg=61.0))
    with pytest.raises(ValueError, match="runs along the bone"):
        placement_of(frame, origin, (1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    with pytest.raises(ValueError, match="no long axis"):
        bone_frame(np.random.default_rng(0).normal(size=(500, 3)))


@pytest.mark.parametrize("bone", ["right-tibia", "left-tibia", "right-fibula", "right-ilium"])
def test_any_placement_reads_back_from_its_plane(bone):
    """200 placements drawn over the whole range a surgeon can type, on each shipped bone's surface."""
    from RAMSICPRegistrationLib.simulation.package_data import bone_mesh

    frame = bone_frame(bone_mesh(bone)[0])
    rng = np.random.default_rng(len(bone))
    for _ in range(200):
        asked = PlanePlacement(
            level_mm=rng.uniform(0.0, frame.length_mm),
            tilt_anterior_deg=rng.uniform(-60.0, 60.0),
            tilt_side_deg=rng.uniform(-60.0, 60.0),
            entry_deg=rng.uniform(0.0, 360.0),
        )
        origin, normal, depth = placed_plane(frame, asked)
        assert abs(normal @ depth) < 1e-12 and np.linalg.norm(depth) == pytest.approx(1.0)
        back = placement_of(frame, origin + rng.normal() * np.cross(normal, depth), normal, depth)  # any plane point
        np.testing.assert_allclose(
            [back.level_mm, back.tilt_anterior_deg, back.tilt_side_deg],
            [asked.level_mm, asked.tilt_anterior_deg, asked.tilt_side_deg],
            atol=1e-8,
        )
        assert (back.entry_deg - asked.entry_deg + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-8)
        back = placement_of(frame, origin, -normal, depth)  # a plane's normal may point either way
        assert back.level_mm == pytest.approx(asked.level_mm)


@pytest.mark.skipif(sys.version_info < (3, 10), reason="slicer-core (real MRML) needs Python >= 3.10")
def test_the_controller_places_the_plane_and_plans_the_cut_on_it():
    """The page's plane fields: a plane 40 mm below the cylinder's top, entered from anterior, planned: its four
    endpoints by hand; then the tilt alone changed (the level kept)."""
    from RAMSICPRegistrationLib.navigation import mrml_nodes
    from RAMSICPRegistrationLib.navigation.controller import NavigationController

    scene = headless_scene()
    controller = NavigationController(scene)
    parameters = controller.parameters
    assert controller.availability()["place_osteotomy_plane"].startswith("build the IPC")
    assert controller.availability()["plan_cut"].startswith("place the osteotomy plane on the bone first")
    parameters.ipcModel = mrml_nodes.model_node(scene, *cylinder_mesh())
    placement = controller.run("place_osteotomy_plane", level_mm=40.0)
    assert placement == PlanePlacement(40.0, 0.0, 0.0, 0.0)  # a new plane: square to the bone, from anterior
    assert parameters.osteotomyPlane.GetName() == "OsteotomyPlane"
    cut = controller.run("plan_cut")
    expected = [(R, 0, 60), (-R, 0, 60), (0, R, 60), (0, -R, 60)]  # across and along the blade's way, z = 100 - 40
    np.testing.assert_allclose(np.sort(cut.endpoints, axis=0), np.sort(expected, axis=0), atol=1e-9)
    assert controller.status().plane_placement.level_mm == pytest.approx(40.0)
    controller.run("place_osteotomy_plane", tilt_side_deg=5.0)
    shown = controller.status().plane_placement
    assert shown.level_mm == pytest.approx(40.0) and shown.tilt_side_deg == pytest.approx(5.0)
    assert controller.status().cut.startswith("OUT OF DATE")
    controller.close()
