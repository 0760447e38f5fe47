"""ICP and RAMSICP: known poses recovered on an analytic surface, the ranges of eqs. 6-8, L = 1, the stopping rule."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.icp import DEFAULT_MAX_ITERATIONS, MatchingRanges, icp, ramsicp
from RAMSICPRegistrationLib.core.paired_point import rigid_procrustes
from RAMSICPRegistrationLib.core.surface_index import SurfaceIndex
from RAMSICPRegistrationLib.core.transforms import (
    apply_transform,
    invert_transform,
    make_transform,
    rotation_about_axis,
)

from conftest import ellipsoid_points

TRUE_POSE = make_transform(rotation_about_axis((1.0, 2.0, 3.0), np.radians(35.0)), (12.0, -7.0, 30.0))
CR_ERROR = make_transform(rotation_about_axis((0.3, -1.0, 0.5), np.radians(1.0)), (0.4, -0.3, 0.25))
#: The paper's stopping rule (after eq. 9): iterations end when the objective changes by less than 1e-5 mm.
PAPER_EPSILON_MM = 1e-5
#: The ellipsoid turned by 10 degrees about its long (x, 40 mm) axis: closest-point steps unwind the turn slowly,
#: in about 30 iterations of which many change the RMS by between 1e-5 and 1e-2 mm.
SLOW_TURN = make_transform(rotation_about_axis((1.0, 0.0, 0.0), np.radians(10.0)))


@pytest.fixture(scope="module")
def ellipsoid():
    points = ellipsoid_points(60_000)
    return points, SurfaceIndex(points)


def _patient_points(points, count, seed=1):
    """Probe points that are IPC points (so the true pose leaves zero residual), in reference coordinates."""
    chosen = points[np.random.default_rng(seed).choice(len(points), count, replace=False)]
    return apply_transform(invert_transform(TRUE_POSE), chosen)


def _pose_error_mm(transform, points):
    return float(
        np.max(np.linalg.norm(apply_transform(transform, points) - apply_transform(TRUE_POSE, points), axis=1))
    )


def test_icp_recovers_known_pose_from_perturbed_start(ellipsoid):
    points, index = ellipsoid
    ppc = _patient_points(points, 60)
    result = icp(index, ppc, CR_ERROR @ TRUE_POSE)
    assert result.converged
    assert _pose_error_mm(result.transform, ppc) < 0.01
    assert result.rms_mm < 0.01
    np.testing.assert_allclose(result.transform, result.fine_transform @ CR_ERROR @ TRUE_POSE, atol=1e-12)


def test_ramsicp_recovers_known_pose_when_truth_is_in_range(ellipsoid):
    points, index = ellipsoid
    ppc = _patient_points(points, 400)
    coarse = CR_ERROR @ TRUE_POSE
    cr_points = apply_transform(coarse, ppc)
    closest, _ = index.nearest(cr_points)
    true_positions = apply_transform(TRUE_POSE, ppc)
    # Keep the points whose true match lies within k_i = 5 D_i of their CR position (eq. 6-8, L = 5).
    reachable = np.linalg.norm(true_positions - cr_points, axis=1) <= 5.0 * closest
    assert reachable.sum() >= 40
    result = ramsicp(index, ppc[reachable], coarse, scale=5.0)
    assert result.converged
    assert _pose_error_mm(result.transform, ppc) < 0.01
    # eq. 10: final = F @ coarse
    np.testing.assert_allclose(result.transform, result.fine_transform @ coarse, atol=1e-12)


def test_scale_one_is_one_closest_point_procrustes_step(ellipsoid):
    points, index = ellipsoid
    ppc = _patient_points(points, 50)
    coarse = CR_ERROR @ TRUE_POSE
    cr_points = apply_transform(coarse, ppc)
    _, closest = index.nearest(cr_points)
    one_step = rigid_procrustes(cr_points, points[closest])
    result = ramsicp(index, ppc, coarse, scale=1.0, min_radius_mm=0.0)
    np.testing.assert_allclose(result.fine_transform, one_step, atol=1e-12)
    assert result.iterations == 2  # the second iteration finds the same matches and the RMS does not change
    assert result.rms_history_mm[0] == result.rms_history_mm[1]


def _brute_force_match(ipc, centres, scale, moving, min_radius_mm):
    """Eqs. 6-8 literally, without a KD-tree: D_i is the distance from CR x_i to the closest of all IPC points,
    k_i = max(L * D_i, min radius), and each moving point takes its closest IPC point with |y - CR x_i| <= k_i."""
    matches = []
    for centre, point in zip(centres, moving):
        from_centre = np.linalg.norm(ipc - centre, axis=1)
        in_range = np.flatnonzero(from_centre <= max(scale * from_centre.min(), min_radius_mm))
        matches.append(in_range[np.argmin(np.linalg.norm(ipc[in_range] - point, axis=1))])
    return np.array(matches)


@pytest.mark.parametrize("scale", [1.0, 1.4, 2.0, 3.6, 5.0])
def test_range_matching_equals_brute_force(ellipsoid, scale, rng):
    points, index = ellipsoid
    centres = points[rng.choice(len(points), 30)] + rng.normal(scale=1.5, size=(30, 3))
    moving = centres + rng.normal(scale=2.0, size=centres.shape)
    # Three centres on IPC points (D = 0) whose closest neighbour is 0.09 mm away, moved towards it: only the
    # minimum radius lets them reach it.
    gaps, pairs = index.tree.query(points, k=2)
    for row, first in enumerate(np.argsort(np.abs(gaps[:, 1] - 0.09))[:3]):
        centres[row], neighbour = points[first], points[pairs[first, 1]]
        moving[row] = centres[row] + 20.0 * (neighbour - centres[row])
    ranges = MatchingRanges(index, centres, max_scale=5.0)
    # 0.1 mm: the documented smallest k_i (interpretation 2 of core.icp), written here, not read from the code.
    expected = _brute_force_match(points, centres, scale, moving, min_radius_mm=0.1)
    np.testing.assert_array_equal(ranges.matcher(scale)(moving), expected)


@pytest.mark.parametrize("scale", [1.0, 2.6, 5.0])
def test_points_in_the_air_moved_far_match_as_by_brute_force(ellipsoid, scale, rng):
    """Points 30-80 mm off the surface (touched in the air: k_i up to 400 mm), moved 0-40 mm by the fine step or
    through the bone: the ranges keep only D_i + 20 mm of candidates and search farther when a point moved over
    10 mm; the matches are those of the whole range all the same."""
    points, index = ellipsoid
    directions = rng.normal(size=(40, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    centres = directions * rng.uniform(30.0, 80.0, size=(40, 1)) * np.array([2.0, 1.5, 1.0])
    moves = rng.normal(size=(40, 3))
    moving = centres + moves / np.linalg.norm(moves, axis=1, keepdims=True) * rng.uniform(0.0, 40.0, size=(40, 1))
    moving[:10] = -0.3 * centres[:10]  # moved through the bone: their closest IPC points are on the far side
    ranges = MatchingRanges(index, centres, max_scale=5.0)
    match = ranges.matcher(scale)
    expected = _brute_force_match(points, centres, scale, moving, min_radius_mm=0.1)
    np.testing.assert_array_equal(match(moving), expected)
    np.testing.assert_array_equal(match(moving), expected)  # again, from the longer lists kept the first time
    assert ranges.counts(ranges.radii(5.0)).max() < len(points)


def test_range_is_inclusive_and_grows_with_scale():
    # The CR point sits at the origin; IPC points at 1, 1.5, 2 and 3 mm: D = 1 mm.
    ipc = np.array([[1.0, 0.0, 0.0], [0.0, 1.5, 0.0], [0.0, 0.0, 2.0], [-3.0, 0.0, 0.0]])
    ranges = MatchingRanges(SurfaceIndex(ipc), np.zeros((1, 3)), max_scale=5.0, min_radius_mm=0.0)
    assert ranges.closest_distance_mm[0] == 1.0
    counts = [int(ranges.counts(ranges.radii(scale))[0]) for scale in (1.0, 1.5, 2.0, 2.9, 3.0)]
    assert counts == [1, 2, 3, 3, 4]
    far_away = np.array([[-10.0, 0.0, 0.0]])  # closest overall is (-3, 0, 0), only inside the range from L = 3
    assert ranges.matcher(2.9)(far_away)[0] != 3
    assert ranges.matcher(3.0)(far_away)[0] == 3


def test_minimum_radius_lets_a_point_on_the_surface_move():
    ipc = np.array([[0.0, 0.0, 0.0], [0.08, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 5.0, 0.0]])
    ranges = MatchingRanges(SurfaceIndex(ipc), np.zeros((1, 3)), max_scale=5.0)
    assert ranges.closest_distance_mm[0] == 0.0
    assert ranges.counts(ranges.radii(5.0))[0] == 2  # the point itself and its neighbour 0.08 mm away


@pytest.mark.parametrize("scale", [0.5, 0.99, np.nan, np.inf, 20.01, 1e6])
def test_scale_below_one_above_twenty_or_not_finite_is_rejected(ellipsoid, scale):
    """Issue 14: L = 10^6 took a 1.1 GB ball query on a 200,000-point IPC; above 20 RAMSICP is plain ICP anyway."""
    points, index = ellipsoid
    with pytest.raises(ValueError, match="give a number from 1 to 20"):
        ramsicp(index, points[:10], np.eye(4), scale=scale)


def test_max_iterations_is_reported(ellipsoid):
    points, index = ellipsoid
    ppc = _patient_points(points, 60)
    result = icp(
        index, ppc, make_transform(rotation_about_axis((0, 0, 1), np.radians(10))) @ TRUE_POSE, max_iterations=2
    )
    assert result.iterations == 2
    assert not result.converged


@pytest.mark.parametrize("method", ["icp", "ramsicp"])
def test_default_run_stops_when_and_only_when_the_rms_changes_by_less_than_1e_5_mm(ellipsoid, method):
    points, index = ellipsoid
    ppc = _patient_points(points, 60)
    start = SLOW_TURN @ TRUE_POSE
    result = icp(index, ppc, start) if method == "icp" else ramsicp(index, ppc, start, scale=5.0)
    history = np.array(result.rms_history_mm)
    changes = np.abs(np.diff(history))
    assert result.converged and result.iterations == len(history) < DEFAULT_MAX_ITERATIONS
    assert changes[-1] < PAPER_EPSILON_MM  # it stops when the change falls below 1e-5 mm ...
    assert np.all(changes[:-1] >= PAPER_EPSILON_MM)  # ... and not before
    # A slow case: at least 5 earlier steps changed the RMS by less than 1e-2 mm (a looser tolerance stops there).
    assert np.count_nonzero(changes[:-1] < 1e-2) >= 5
    # Each step cannot raise the objective: the matches and the fit each minimise it (Besl and McKay 1992).
    assert np.all(np.diff(history) <= 1e-12)


def test_stopping_at_1e_2_mm_would_leave_the_points_half_a_millimetre_off(ellipsoid):
    points, index = ellipsoid
    ppc = _patient_points(points, 60)
    start = SLOW_TURN @ TRUE_POSE
    assert _pose_error_mm(icp(index, ppc, start).transform, ppc) < 0.01  # the paper's tolerance reaches the pose
    assert _pose_error_mm(icp(index, ppc, start, tolerance_mm=1e-2).transform, ppc) > 0.5


@pytest.mark.parametrize("tolerance", [1e-1, 3e-2, 1e-2, 1e-3, 1e-4])
def test_a_run_stops_at_the_first_change_below_its_tolerance(ellipsoid, tolerance):
    points, index = ellipsoid
    ppc = _patient_points(points, 60)
    start = SLOW_TURN @ TRUE_POSE
    full = ramsicp(index, ppc, start, scale=5.0, tolerance_mm=PAPER_EPSILON_MM)
    changes = np.abs(np.diff(full.rms_history_mm))
    stop = int(np.flatnonzero(changes < tolerance)[0]) + 2  # changes[h - 2] compares iterations h - 1 and h
    result = ramsicp(index, ppc, start, scale=5.0, tolerance_mm=tolerance)
    assert result.iterations == stop and result.converged
    assert result.rms_history_mm == full.rms_history_mm[:stop]  # the same run, cut at its first small change
