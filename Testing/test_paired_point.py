"""Paired-point SVD fit: known transforms, known residuals, and every bad input's message."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.paired_point import fit_rigid_transform
from RAMSICPRegistrationLib.core.transforms import apply_transform, invert_transform, make_transform

from conftest import random_transform


def test_recovers_known_transform_to_1e9(rng):
    for _ in range(20):
        truth = random_transform(rng)
        source = rng.uniform(-80, 80, size=(rng.integers(3, 40), 3))
        fit = fit_rigid_transform(source, apply_transform(truth, source))
        np.testing.assert_allclose(fit.transform, truth, atol=1e-9)
        assert fit.fre_mm < 1e-9
        assert np.linalg.det(fit.transform[:3, :3]) == pytest.approx(1.0)


def test_fre_and_residuals_match_hand_computation():
    # A square whose image corners are pushed 1 mm outward in the plane: by symmetry the best fit is the
    # identity, so every residual is exactly 1 mm and FRE = 1 mm.
    square = np.array([[10.0, 10.0, 0.0], [-10.0, 10.0, 0.0], [-10.0, -10.0, 0.0], [10.0, -10.0, 0.0]])
    outward = square / np.linalg.norm(square, axis=1, keepdims=True)
    fit = fit_rigid_transform(square, square + outward)
    np.testing.assert_allclose(fit.transform, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(fit.residuals_mm, 1.0, atol=1e-12)
    assert fit.fre_mm == pytest.approx(1.0)


def test_never_returns_a_reflection_for_mirrored_points():
    # GOOD has three different arm lengths, so it is chiral: its mirror image is fitted exactly only by a
    # reflection (det -1), which the guard refuses; the best rotation leaves a large FRE.
    fit = fit_rigid_transform(GOOD, GOOD * np.array([-1.0, 1.0, 1.0]))
    assert np.linalg.det(fit.transform[:3, :3]) == pytest.approx(1.0)
    assert fit.fre_mm > 10.0


def test_zero_weight_ignores_a_point_and_weights_shift_the_fit(rng):
    truth = random_transform(rng)
    source = rng.uniform(-50, 50, size=(6, 3))
    target = apply_transform(truth, source)
    target[5] += (30.0, 0.0, 0.0)  # an outlier
    weighted = fit_rigid_transform(source, target, weights=[1, 1, 1, 1, 1, 0])
    np.testing.assert_allclose(weighted.transform, truth, atol=1e-9)
    # Two points only differing in translation: a weight of 3 on one moves the centroid fit 3/4 of the way.
    flat = np.array([[0.0, 0.0, 0.0], [0.0, 10.0, 0.0], [10.0, 0.0, 0.0], [10.0, 10.0, 0.0]])
    moved = flat.copy()
    moved[:2, 2] += 4.0  # two points 4 mm up, two not: a tilt, plus a 2 mm shift of the centroid
    unweighted = fit_rigid_transform(flat, moved)
    centroid = apply_transform(unweighted.transform, flat.mean(axis=0, keepdims=True))[0]
    assert centroid[2] == pytest.approx(2.0)


def test_inverse_fit_is_inverse_transform(rng):
    truth = random_transform(rng)
    source = rng.uniform(-50, 50, size=(5, 3))
    target = apply_transform(truth, source)
    forward = fit_rigid_transform(source, target).transform
    backward = fit_rigid_transform(target, source).transform
    np.testing.assert_allclose(backward, invert_transform(forward), atol=1e-9)


GOOD = np.array([[0.0, 0.0, 0.0], [50.0, 0.0, 0.0], [0.0, 40.0, 0.0], [0.0, 0.0, 30.0]])


@pytest.mark.parametrize(
    "source, target, weights, message",
    [
        (GOOD[:2], GOOD[:2], None, "2 point(s) given, at least 3 needed"),
        (GOOD, GOOD[:3], None, "source has 4 points but target has 3"),
        (GOOD[:, :2], GOOD[:, :2], None, "expected an (N, 3) array"),
        (
            np.where(np.eye(4, 3, dtype=bool), np.nan, GOOD),
            GOOD,
            None,
            "point(s) 1, 2, 3 (counted from 1) contain NaN",
        ),
        (
            GOOD,
            np.where(np.eye(4, 3, k=-3, dtype=bool), np.inf, GOOD),
            None,
            "target: point(s) 4 (counted",
        ),
        (np.vstack((GOOD[:3], GOOD[2])), GOOD, None, "points 3 and 4 (counted from 1) are the same point"),
        (np.array([[0, 0, 0], [10, 0, 0], [20, 0, 0], [30, 0, 0]], float), GOOD, None, "collinear"),
        (np.array([[0, 0, 0], [10, 0, 0], [20, 0.001, 0], [30, 0, 0]], float), GOOD, None, "collinear"),
        (GOOD, GOOD, [1, 1, -1, 1], "weights: expected 4 finite non-negative"),
        (GOOD, GOOD, [1, 1, 0, 0], "at least 3 points need a positive weight"),
        ("abc", GOOD, None, "cannot read as numbers"),
    ],
)
def test_bad_input_raises_clear_message(source, target, weights, message):
    with pytest.raises(ValueError) as error:
        fit_rigid_transform(source, target, weights=weights)
    assert message in str(error.value)


def test_a_single_mislabelled_point_pair_is_still_solved_but_shows_in_fre():
    target = apply_transform(make_transform(translation=(5.0, 0.0, 0.0)), GOOD)
    swapped = target[[1, 0, 2, 3]]
    assert fit_rigid_transform(GOOD, swapped).fre_mm > 10.0
