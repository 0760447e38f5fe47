"""Independent image steps run at once: results in order, errors raised, nested steps and one core run in turn."""

import threading
import time

import numpy as np
import pytest
from scipy import ndimage

from RAMSICPRegistrationLib.image import parallel
from RAMSICPRegistrationLib.image.parallel import in_parallel


def test_results_come_back_in_the_order_of_the_steps():
    steps = [lambda value=value: (time.sleep(0.01 * (5 - value)), value)[1] for value in range(5)]
    assert in_parallel(*steps) == [0, 1, 2, 3, 4]
    assert in_parallel() == []
    assert in_parallel(lambda: 7) == [7]


def test_the_same_arrays_as_one_after_the_other():
    rng = np.random.default_rng(0)
    masks = [rng.random((40, 40, 40)) > 0.5 for _ in range(4)]
    labelled = in_parallel(*[lambda mask=mask: ndimage.label(mask)[0] for mask in masks])
    for mask, labels in zip(masks, labelled):
        np.testing.assert_array_equal(labels, ndimage.label(mask)[0])


def test_an_error_in_any_step_is_raised_once_every_step_has_ended():
    ended = []

    def slow():
        time.sleep(0.05)
        ended.append("slow")
        return 1

    def fails():
        raise ValueError("step 2 failed")

    with pytest.raises(ValueError, match="step 2 failed"):
        in_parallel(slow, fails, slow)
    finished = len(ended)  # the first, and the third unless it was cancelled before it started
    time.sleep(0.1)
    assert ended == ["slow"] * finished and finished in (1, 2)  # none went on running after the error


def test_steps_asked_for_inside_a_step_run_in_turn_in_its_thread(monkeypatch):
    monkeypatch.setattr(parallel, "cores", lambda: 2)

    def outer():
        threads = in_parallel(threading.get_ident, threading.get_ident)
        return threading.get_ident(), threads

    for caller, inner in in_parallel(outer, outer):
        if caller != threading.get_ident():  # a worker: its own steps ran in its thread
            assert inner == [caller, caller]


def test_one_core_runs_every_step_in_the_calling_thread(monkeypatch):
    monkeypatch.setenv("RAMSICP_THREADS", "1")
    assert parallel.cores() == 1
    assert in_parallel(threading.get_ident, threading.get_ident) == [threading.get_ident()] * 2
    monkeypatch.setenv("RAMSICP_THREADS", "3")
    assert parallel.cores() == 3


def test_slabs_cover_every_row_once_one_per_core_and_none_thinner_than_asked(monkeypatch):
    from RAMSICPRegistrationLib.image.parallel import in_slabs

    monkeypatch.setattr(parallel, "cores", lambda: 4)
    for length, min_rows, slabs in ((100, 1, 4), (100, 40, 2), (10, 40, 1), (3, 1, 3), (0, 1, 1)):
        seen = []
        in_slabs(length, lambda start, stop, seen=seen: seen.append((start, stop)), min_rows=min_rows)
        seen.sort()
        assert len(seen) == slabs
        assert [row for start, stop in seen for row in range(start, stop)] == list(range(length))
        if slabs > 1:
            assert min(stop - start for start, stop in seen) >= min_rows
