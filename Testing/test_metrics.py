"""TRE (eq. 11), FLE from FRE, and the Fitzpatrick-West-Maurer prediction against hand values and simulation."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.metrics import fle_from_fre, predicted_tre, target_registration_error
from RAMSICPRegistrationLib.core.paired_point import rigid_procrustes
from RAMSICPRegistrationLib.core.transforms import apply_transform, make_transform, rotation_about_axis

SQUARE = np.array([[10.0, 10.0, 0.0], [-10.0, 10.0, 0.0], [-10.0, -10.0, 0.0], [10.0, -10.0, 0.0]])


def test_tre_of_a_pure_translation_is_its_length():
    targets = np.array([[0.0, 0.0, 0.0], [10.0, 5.0, 2.0], [-3.0, 8.0, 1.0], [4.0, 4.0, 4.0]])
    shifted = make_transform(translation=(0.3, 0.4, 0.0))
    assert target_registration_error(shifted, targets, targets) == pytest.approx(0.5)


def test_tre_is_rms_over_targets():
    # 90 degrees about z: targets at distance 1 and 2 from the axis move by sqrt(2) and 2 sqrt(2).
    turn = make_transform(rotation_about_axis((0, 0, 1), np.pi / 2))
    targets = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 5.0]])
    assert target_registration_error(turn, targets, targets) == pytest.approx(np.sqrt((2 + 8) / 2))


def test_predicted_tre_matches_hand_formula_for_a_square():
    # Square of half-side a = 10: f_x^2 = f_y^2 = a^2, f_z^2 = 2 a^2. At the centre TRE = FLE / sqrt(N);
    # at (0, 0, d): TRE^2 = FLE^2 / 4 * (1 + (d^2/a^2 + d^2/a^2) / 3).
    a, d, fle = 10.0, 30.0, 1.0
    predicted = predicted_tre(SQUARE, np.array([[0.0, 0.0, 0.0], [0.0, 0.0, d]]), fle)
    assert predicted[0] == pytest.approx(fle / 2.0)
    assert predicted[1] == pytest.approx(np.sqrt(fle**2 / 4.0 * (1.0 + (2.0 * d**2 / a**2) / 3.0)))


def test_predicted_tre_agrees_with_simulation():
    rng = np.random.default_rng(5)
    markers = np.array([[0.0, 0.0, 0.0], [0.0, 28.59, 41.02], [0.0, 0.0, 88.0], [0.0, -44.32, 40.45]])
    target = np.array([[120.0, 30.0, -60.0]])
    fle = 1.0
    squared = []
    for _ in range(20000):
        placed = markers + rng.normal(scale=fle / np.sqrt(3.0), size=markers.shape)
        squared.append(np.sum((apply_transform(rigid_procrustes(markers, placed), target) - target) ** 2))
    assert np.sqrt(np.mean(squared)) == pytest.approx(predicted_tre(markers, target, fle)[0], rel=0.03)


def test_fle_from_fre_inverts_the_expectation():
    assert fle_from_fre(1.0, 4) == pytest.approx(np.sqrt(2.0))
    with pytest.raises(ValueError, match="at least 3 markers"):
        fle_from_fre(1.0, 2)
