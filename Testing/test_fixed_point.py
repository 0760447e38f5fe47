"""The fixed point of a moving body's poses (core.fixed_point): the least squares of R_i p + t_i = q, from running
sums, completed by a prior where the poses say nothing; known answers from poses built about a point we chose."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.fixed_point import FixedPointSums, fixed_point_fit, rotation_range_deg
from RAMSICPRegistrationLib.core.transforms import make_transform, rotation_about_axis

P = np.array([3.0, -4.0, 150.0])  # the held point in the moving frame (mm)
Q = np.array([-800.0, 85.0, -2100.0])  # where it stays, far from the origin as in a tracker's frame (mm)


def _poses(rotations):
    return np.array([make_transform(rotation, Q - rotation @ P) for rotation in rotations])


def _sums(poses):
    sums = FixedPointSums()
    for pose in poses:
        sums.add(pose[:3, :3], pose[:3, 3])
    return sums


def _turns(axes, degrees, count=30):
    angles = np.radians(np.linspace(-degrees / 2, degrees / 2, count))
    return [rotation_about_axis(axis, angle) for axis in axes for angle in angles]


def test_two_axes_of_turn_fix_the_point_exactly_from_the_sums_as_from_the_stacked_system():
    poses = _poses(_turns([(1, 0, 0), (0, 1, 0)], 40.0))
    sums = _sums(poses)
    fit = sums.within(P + (2.0, -1.0, 1.5), max_offset_mm=5.0)
    np.testing.assert_allclose(fit.p, P, atol=1e-9)
    np.testing.assert_allclose(fit.q, Q, atol=1e-9)
    assert fit.determined_axes == 3 and sums.residual_rms(fit.p) < 1e-6
    p, q = fixed_point_fit(poses)
    np.testing.assert_allclose(p, P, atol=1e-9)
    np.testing.assert_allclose(q, Q, atol=1e-9)
    turns, _ = sums.turns_rad()
    assert turns.min() > np.radians(5.0)


def test_the_prior_bounds_the_point_within_its_radius_and_completes_it_where_there_was_no_turn():
    """Turns about x only (a fan): p along x is unknown. ``within`` leaves x at the prior's value (no turn there) and
    fits y, z; with the prior 4 mm off in y and a radius of 1 mm it stops exactly on that radius. ``determined``
    keeps the prior along x and takes y, z from the poses."""
    poses = _poses(_turns([(1, 0, 0)], 40.0))
    sums = _sums(poses)
    prior = P + (2.0, 0.0, 0.0)
    free = sums.within(prior, 5.0)
    np.testing.assert_allclose(free.p, P + (2.0, 0.0, 0.0), atol=1e-9)
    assert free.determined_axes == 2
    bounded = sums.within(P + (0.0, 4.0, 0.0), 1.0)
    assert np.linalg.norm(bounded.p - (P + (0.0, 4.0, 0.0))) == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(bounded.p, P + (0.0, 3.0, 0.0), atol=1e-6)  # straight towards the point
    fit = sums.determined(prior, noise_mm=0.1, max_error_mm=0.1, min_turn_rad=np.radians(1.0))
    np.testing.assert_allclose(fit.p, P + (2.0, 0.0, 0.0), atol=1e-9)
    assert fit.determined_axes == 2
    np.testing.assert_allclose(fit.q, np.mean([pose[:3, :3] @ fit.p + pose[:3, 3] for pose in poses], axis=0))


def test_without_any_turn_the_point_is_the_mean_of_the_prior_tips_and_noise_decides_nothing():
    rng = np.random.default_rng(3)
    poses = _poses([np.eye(3)] * 20)
    poses[:, :3, 3] += rng.normal(scale=0.2, size=(20, 3))
    sums = _sums(poses)
    prior = P + (1.0, 1.0, 1.0)
    tips = poses[:, :3, :3] @ prior + poses[:, :3, 3]
    for fit in (sums.within(prior, 5.0), sums.determined(prior, 0.2, 0.1, np.radians(1.0))):
        np.testing.assert_allclose(fit.p, prior, atol=1e-12)
        np.testing.assert_allclose(fit.q, tips.mean(axis=0), atol=1e-9)
        assert fit.determined_axes == 0
    assert sums.residual_rms(prior) == pytest.approx(np.sqrt(np.mean(np.sum((tips - tips.mean(0)) ** 2, 1))))


def test_a_direction_the_poses_locate_too_loosely_keeps_the_prior():
    """Turns of 40 degrees about x, 4 degrees about y: along x the fit's standard error is the noise over the square
    root of the smallest eigenvalue of H (the squared turns about y, summed): with 0.02 mm of noise that is 0.18 mm,
    above 0.1 mm, and the prior is kept along x; with 0.001 mm it is 0.009 mm and the poses fix x too."""
    rotations = _turns([(1, 0, 0)], 40.0) + _turns([(0, 1, 0)], 4.0)
    sums = _sums(_poses(rotations))
    prior = P + (1.0, 0.0, 0.0)
    turns, _ = sums.turns_rad()
    assert 0.02 / np.sqrt(len(rotations) * turns[0] ** 2) == pytest.approx(0.18, abs=0.01)
    strict = sums.determined(prior, noise_mm=0.02, max_error_mm=0.1, min_turn_rad=np.radians(0.1))
    loose = sums.determined(prior, noise_mm=0.001, max_error_mm=0.1, min_turn_rad=np.radians(0.1))
    assert strict.determined_axes == 2 and loose.determined_axes == 3
    np.testing.assert_allclose(strict.p[0], prior[0], atol=1e-9)
    np.testing.assert_allclose(loose.p, P, atol=1e-9)


def test_the_rotation_range_is_the_largest_angle_between_two_poses():
    rotations = [rotation_about_axis((0, 0, 1), np.radians(angle)) for angle in (-10.0, 5.0, 25.0)]
    assert rotation_range_deg(rotations) == pytest.approx(35.0)
    assert rotation_range_deg([np.eye(3)] * 3) == pytest.approx(0.0, abs=1e-6)
    many = [rotation_about_axis((1, 0, 0), np.radians(angle)) for angle in np.linspace(0, 50, 2500)]
    assert rotation_range_deg(many) == pytest.approx(50.0)  # past one block of 1024
