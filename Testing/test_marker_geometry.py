"""Markers paired by their geometry (core/marker_geometry.py): known layouts moved by transforms built here, shuffled,
thinned and mixed with other bright spots; the pairing must find the permutation that was applied."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.marker_geometry import (
    PAIRING_TOLERANCE_MM,
    at_pairwise_distances,
    check_marker_centres,
    pair_by_geometry,
    unit_hint,
)
from RAMSICPRegistrationLib.core.transforms import apply_transform
from RAMSICPRegistrationLib.io.ndi_tools import tool_marker_geometry

from conftest import random_transform

TOOLS = ("8700339", "8700340", "8700449")


@pytest.mark.parametrize("tool", TOOLS)
def test_any_order_in_any_frame_is_paired_back(tool, rng):
    markers = tool_marker_geometry(tool)
    for _ in range(30):
        transform = random_transform(rng)
        order = rng.permutation(len(markers))
        measured = apply_transform(transform, markers)[order] + rng.normal(0, 0.3, (len(markers), 3))
        pairing = pair_by_geometry(measured, markers)
        # reference marker k was written to row where order == k
        assert pairing.indices.tolist() == [int(np.flatnonzero(order == k)[0]) for k in range(len(markers))]
        assert not pairing.ambiguous
        assert pairing.fre_mm < 1.0
        np.testing.assert_allclose(pairing.transform[:3, :3], transform[:3, :3], atol=0.03)


def test_given_order_is_said_to_be_kept(rng):
    markers = tool_marker_geometry("8700339")
    pairing = pair_by_geometry(apply_transform(random_transform(rng), markers), markers)
    assert pairing.in_given_order and pairing.fre_mm < 1e-9


def test_markers_found_among_other_bright_spots_and_a_missing_one_located(rng):
    markers = tool_marker_geometry("8700449")
    transform = random_transform(rng)
    moved = apply_transform(transform, markers)
    clutter = rng.uniform(-150, 150, (40, 3))
    # marker 3 (row 2) not found; the others hidden among 40 other spots at random rows
    measured = np.vstack([clutter, moved[[0, 1, 3]]])
    rows = rng.permutation(len(measured))
    measured = measured[rows]
    pairing = pair_by_geometry(measured, markers)
    inverse = np.argsort(rows)
    assert pairing.indices.tolist() == [int(inverse[40]), int(inverse[41]), -1, int(inverse[42])]
    assert pairing.count == 3
    np.testing.assert_allclose(pairing.expected[2], moved[2], atol=1e-6)
    assert np.isnan(pairing.residuals_mm[2])


def test_a_patient_side_set_pairs_with_the_image_side_set(rng):
    """No tool needed: the image centres are the reference layout for the patient centres."""
    markers = tool_marker_geometry("8700340")
    image = apply_transform(random_transform(rng), markers)
    patient = apply_transform(random_transform(rng), markers)[[2, 0, 3, 1]]
    pairing = pair_by_geometry(patient, image)
    assert pairing.indices.tolist() == [1, 3, 0, 2]


def test_a_marker_moved_by_more_than_the_tolerance_is_not_paired(rng):
    markers = tool_marker_geometry("8700339")
    measured = apply_transform(random_transform(rng), markers)
    measured[1] += np.array([0.0, 0.0, 3 * PAIRING_TOLERANCE_MM])
    pairing = pair_by_geometry(measured, markers)  # three still pair; the moved one is left out
    assert pairing.indices.tolist() == [0, -1, 2, 3]
    with pytest.raises(ValueError, match="within 2 mm"):
        pair_by_geometry(measured, markers, min_pairs=4)


def test_metres_are_named_as_the_likely_cause(rng):
    markers = tool_marker_geometry("8700339")
    with pytest.raises(ValueError, match="look to be in metres"):
        pair_by_geometry(apply_transform(random_transform(rng), markers) / 1000.0, markers)
    assert "centimetres" in unit_hint(markers / 10.0, markers)
    assert "inches" in unit_hint(markers / 25.4, markers)
    assert unit_hint(markers, markers) == ""


def test_another_tool_is_refused(rng):
    with pytest.raises(ValueError, match="match no arrangement"):
        pair_by_geometry(tool_marker_geometry("8700340"), tool_marker_geometry("8700339"), min_pairs=4)


def test_a_symmetric_layout_is_reported_ambiguous():
    square = np.array([[0.0, 0, 0], [50, 0, 0], [50, 50, 0], [0, 50, 0]])
    pairing = pair_by_geometry(square, square)
    assert pairing.ambiguous and pairing.runner_up_fre_mm < 1e-9


def test_duplicated_and_collinear_centres_are_refused():
    markers = tool_marker_geometry("8700339")
    with pytest.raises(ValueError, match=r"markers 2 and 4 are 0\.50 mm apart"):
        check_marker_centres(np.vstack([markers[:3], markers[1] + [0.5, 0, 0]]), "markers")
    line = np.outer(np.arange(4.0), [30.0, 0, 0]) + [[0, 0.1, 0], [0, -0.2, 0], [0, 0.3, 0], [0, 0, 0]]
    with pytest.raises(ValueError, match="straight line"):
        check_marker_centres(line, "markers")
    with pytest.raises(ValueError, match="NaN"):
        check_marker_centres(np.vstack([markers[:3], [np.nan, 0, 0]]), "markers")
    np.testing.assert_array_equal(check_marker_centres(markers, "markers"), markers)


def test_points_at_one_of_the_tools_distances_from_another_are_told_apart_from_the_rest():
    """Two points 60 mm apart (a distance of the tool's: markers 1 and 4 of 8700339), one 30 mm from both (none of
    its distances), and a pair 1.5 mm off a distance (inside the 2 mm tolerance) and 2.5 mm off (outside)."""
    tool = tool_marker_geometry("8700339")
    distances = np.linalg.norm(tool[:, None] - tool[None], axis=-1)
    assert abs(distances[0, 3] - 60.0) < 0.01
    points = np.array([[0.0, 0.0, 0.0], [60.0, 0.0, 0.0], [30.0, 0.0, 0.0]])
    assert at_pairwise_distances(points, tool) == [0, 1]
    assert at_pairwise_distances(points[[0, 2]], tool) == []
    assert at_pairwise_distances([[0, 0, 0], [0, 61.5, 0]], tool) == [0, 1]
    assert at_pairwise_distances([[0, 0, 0], [0, 62.5, 0]], tool) == []
    assert at_pairwise_distances(np.zeros((0, 3)), tool) == []
