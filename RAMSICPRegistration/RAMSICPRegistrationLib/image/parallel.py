"""Independent array steps of the image side run at once, one per core.

SciPy's labelling and distance transforms and NumPy's element-wise operations let go of Python's lock while they
work, so two of them in two threads take about the time of one on two cores. Only steps that share no writable
array run together; each returns its own result. One core (or ``RAMSICP_THREADS=1``) runs them one after the
other, in order, in the calling thread; so does a step that asks for more steps at once from inside a worker
(nested steps would wait on a pool their parents fill).
"""

import os
import threading
from concurrent.futures import ThreadPoolExecutor, wait
from functools import partial

import numpy as np

_pool = None
_pool_lock = threading.Lock()
_in_worker = threading.local()


def cores():
    """How many threads the image side uses: the cores this process may run on, or ``RAMSICP_THREADS``."""
    asked = os.environ.get("RAMSICP_THREADS", "").strip()
    if asked.isdigit() and int(asked) > 0:
        return int(asked)
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


def in_parallel(*steps):
    """The results of ``steps`` (callables without arguments), in their order. The workers take the steps after the
    first; the calling thread runs the first, then any the workers have not started yet. An exception in any step
    is raised here once none is running any more."""
    if len(steps) < 2 or cores() < 2 or getattr(_in_worker, "busy", False):
        return [step() for step in steps]
    futures = [_workers().submit(_run_in_worker, step) for step in steps[1:]]
    try:
        results = [steps[0]()]
        for step, future in zip(steps[1:], futures):
            results.append(step() if future.cancel() else future.result())
        return results
    finally:
        for future in futures:  # never leave a step running on arrays the caller may drop or reuse
            future.cancel()
        wait(futures)


def slab_cuts(length, min_rows=1):
    """(S + 1,) ints: where the slabs of ``in_slabs`` start, and ``length``: ``range(length)`` cut into one slab per
    core, fewer when a slab would hold under ``min_rows`` rows."""
    count = min(cores(), max(1, length // max(min_rows, 1)))
    return np.linspace(0, length, count + 1).astype(int)


def in_slabs(length, work, min_rows=1):
    """The results of ``work(start, stop)`` over the slabs of rows ``start:stop`` of ``slab_cuts(length, min_rows)``,
    in their order, with ``in_parallel``."""
    cuts = slab_cuts(length, min_rows)
    return in_parallel(*[partial(work, int(start), int(stop)) for start, stop in zip(cuts[:-1], cuts[1:])])


def _run_in_worker(step):
    _in_worker.busy = True
    try:
        return step()
    finally:
        _in_worker.busy = False


def _workers():
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=max(1, cores() - 1), thread_name_prefix="ramsicp image")
        return _pool
