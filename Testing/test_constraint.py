"""Warnings when probe points leave a motion free: plane, cylinder, and a fully constraining corner."""

import numpy as np

from RAMSICPRegistrationLib.core.constraint import analyse_pose_constraint


def test_points_on_a_plane_leave_motions_free():
    rng = np.random.default_rng(0)
    points = np.column_stack((rng.uniform(-20, 20, 40), rng.uniform(-20, 20, 40), np.zeros(40)))
    normals = np.tile((0.0, 0.0, 1.0), (40, 1))
    report = analyse_pose_constraint(points, normals)
    assert not np.isfinite(report.uncertainty_mm[:3]).any()  # two slides and the spin about z
    assert "is not constrained at all" in report.warning


def test_points_on_a_cylinder_leave_rotation_about_its_axis_free():
    rng = np.random.default_rng(1)
    angle = rng.uniform(0, np.pi, 40)  # half the circumference, as a probe reaches
    height = rng.uniform(0, 80, 40)
    normals = np.column_stack((np.cos(angle), np.sin(angle), np.zeros(40)))
    points = 12.0 * normals + np.column_stack((np.zeros((40, 2)), height))
    report = analyse_pose_constraint(points, normals, long_axis=np.array([0.0, 0.0, 1.0]))
    assert report.warning is not None
    assert abs(report.axis[2]) > 0.999  # the weak motion is about or along z
    assert "bone's long axis" in report.warning


def test_points_on_three_faces_of_a_box_constrain_everything():
    rng = np.random.default_rng(2)
    points, normals = [], []
    for axis in range(3):
        face = rng.uniform(5, 40, size=(15, 3))
        face[:, axis] = 0.0
        normal = np.zeros(3)
        normal[axis] = 1.0
        points.append(face)
        normals.append(np.tile(normal, (15, 1)))
    report = analyse_pose_constraint(np.vstack(points), np.vstack(normals))
    assert report.warning is None
    assert np.all(report.uncertainty_mm < 0.5)
