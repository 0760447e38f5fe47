"""The scale sweep (L = 1..5 step 0.2) and the policies that choose L."""

import numpy as np
import pytest

from RAMSICPRegistrationLib.core.icp import FineResult, ramsicp
from RAMSICPRegistrationLib.core.metrics import target_registration_error
from RAMSICPRegistrationLib.core.registration import select_scale
from RAMSICPRegistrationLib.core.surface_index import SurfaceIndex
from RAMSICPRegistrationLib.core.sweep import MAX_SCALES, PAPER_SCALES, SweepEntry, make_scales, sweep_scales
from RAMSICPRegistrationLib.core.transforms import make_transform, rotation_about_axis

from conftest import ellipsoid_points


def test_paper_scales_are_1_to_5_step_0_2():
    assert len(PAPER_SCALES) == 21
    assert PAPER_SCALES[0] == 1.0 and PAPER_SCALES[1] == 1.2 and PAPER_SCALES[-1] == 5.0
    assert make_scales(1.0, 2.0, 0.5) == (1.0, 1.5, 2.0)
    assert make_scales(1.0, 5.0, 0.2) == PAPER_SCALES


@pytest.mark.parametrize(
    "start, stop, step", [(0.5, 5, 0.2), (1, 5, 0), (3, 2, 0.1), (1, np.nan, 0.2), (1, 1e6, 1e-4), (1, 20.5, 1)]
)
def test_bad_scale_ranges_are_rejected(start, stop, step):
    with pytest.raises(ValueError, match="need 1 <= start <= stop <= 20, a step above 0 and at most 101 values"):
        make_scales(start, stop, step)


def test_a_sweep_runs_at_most_101_values():
    """Issue 14: ``--scales 1 1e6 0.0001`` asked for 10^10 values (74.5 GiB); the count is bounded and said."""
    assert len(make_scales(1.0, 5.0, 0.04)) == MAX_SCALES == 101
    with pytest.raises(ValueError, match="1 to 5 step 0.001: 4,001 values of L, but a sweep runs at most 101"):
        make_scales(1.0, 5.0, 0.001)


def test_sweep_equals_independent_runs_and_reports_tre():
    ipc = ellipsoid_points(30_000)
    index = SurfaceIndex(ipc)
    rng = np.random.default_rng(3)
    ppc = ipc[rng.choice(len(ipc), 40, replace=False)] + rng.normal(scale=0.1, size=(40, 3))
    coarse = make_transform(rotation_about_axis((0, 1, 1), np.radians(2.0)), (1.0, 0.5, -0.5))
    targets = np.array([[0.0, 0.0, 0.0], [30.0, 0.0, 0.0]])
    entries = sweep_scales(index, ppc, coarse, (1.0, 2.2, 5.0), targets, targets)
    for entry in entries:
        alone = ramsicp(index, ppc, coarse, entry.scale)
        np.testing.assert_array_equal(entry.result.transform, alone.transform)
        assert entry.result.iterations == alone.iterations
        assert entry.tre_mm == pytest.approx(target_registration_error(alone.transform, targets, targets))
    assert [entry.to_dict()["scale"] for entry in entries] == [1.0, 2.2, 5.0]


def _entries(rms_values, tre_values):
    entries = []
    for scale, rms, tre in zip(PAPER_SCALES, rms_values, tre_values):
        result = FineResult(np.eye(4), np.eye(4), rms, 3, True, np.zeros(1, int), (rms,), scale)
        entries.append(SweepEntry(scale=scale, result=result, tre_mm=tre))
    return tuple(entries)


def test_policies_choose_the_documented_entry():
    rms = [0.9, 0.5, 0.40, 0.301, 0.3005, 0.300, 0.30] + [0.30] * 14
    tre = [1.0, 0.8, 0.55, 0.6, 0.7, 0.9, 1.0] + [1.0] * 14
    entries = _entries(rms, tre)
    assert entries[select_scale(entries, "targets")].scale == 1.4  # minimum TRE
    assert entries[select_scale(entries, "fixed", 2.0)].scale == 2.0
    # smallest L whose RMS is within 0.5 % of the lowest (0.300): 0.301 is within, 0.40 is not
    assert entries[select_scale(entries, "rms-plateau")].scale == 1.6


def test_targets_policy_without_targets_says_what_to_do():
    entries = _entries([0.3] * 21, [None] * 21)
    with pytest.raises(ValueError, match="needs target points"):
        select_scale(entries, "targets")
    with pytest.raises(ValueError, match="use one of"):
        select_scale(entries, "best")
