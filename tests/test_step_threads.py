"""The run steps' decorator (``lunarmap.workflows.steps._step``): thread policy, reuse without limits, memory
records; ``lunarmap.blas.blas_threads`` under ``single_threaded_blas``; the adjustment's per-image threads give
the serial results."""

from __future__ import annotations

import numpy as np
import pytest
from blockhelp import linescan_case

from lunarmap import blas
from lunarmap.adjust import SolverOptions, solve
from lunarmap.adjust.sensors import _IMAGE_THREADS, image_threads
from lunarmap.workflows import steps
from lunarmap.workflows.steps import ALL, Done, _cores, _step
from lunarmap.workflows.store import Store


def _blas_counts() -> list[int]:
    api = blas._find_api()
    return [int(get()) for get, _ in api]


def _accepts(n: int) -> list[int]:
    """What each OpenBLAS of the process reports when asked for ``n`` threads itself (a single-threaded build,
    as cvxopt's, stays at 1): the oracle of the contexts' counts."""
    out = []
    for get, put in blas._find_api():
        old = int(get())
        put(n)
        out.append(int(get()))
        put(old)
    return out


def _seen(store: Store, key: str, seen: list) -> Done:
    # what the body of a step sees: BLAS threads, image threads; computes when its output is missing
    seen.append((_blas_counts(), _IMAGE_THREADS.get()))
    if store.has("demo", key, "txt"):
        return Done("demo", key, "", str(store.path("demo", key, "txt")), False)
    path = store.write("demo", key, "txt", lambda tmp: tmp.write_text("x"))
    return Done("demo", key, "", str(path), True, 0.0)


@pytest.mark.parametrize("threads", [1, ALL])
def test_computed_step_runs_under_its_policy_and_records_peak_memory(tmp_path, threads):
    step = _step("demo", "txt", threads=threads)(_seen)
    seen: list = []
    out = step(Store(tmp_path), "k", seen)
    assert out.computed and out.peak_mb > 0.0
    counts, images = seen[0]
    n = 1 if threads == 1 else _cores()
    assert images == n
    assert all(c == 1 for c in counts)       # BLAS keeps one thread (none found: nothing to check)


def test_a_step_may_ask_for_blas_threads(tmp_path):
    step = _step("demo", "txt", threads=2, blas=True)(_seen)
    seen: list = []
    step(Store(tmp_path), "k", seen)
    assert seen[0][1] == 2 and seen[0][0] == _accepts(2)


def test_reused_step_returns_its_record_without_limits(tmp_path):
    api = blas._find_api()
    store = Store(tmp_path)
    step = _step("demo", "txt")(_seen)
    step(store, "k", [])                     # computed: stored now
    seen: list = []
    before = [int(get()) for get, _ in api]
    with blas.blas_threads(2):               # a limit the reused step must not touch
        out = step(store, "k", seen)
        want = _blas_counts()
    assert not out.computed and out.peak_mb == 0.0
    assert seen[0][0] == want and seen[0][1] == 1
    assert [int(get()) for get, _ in api] == before


def test_single_threaded_blas_wins_inside_blas_threads():
    api = blas._find_api()
    if not api:
        pytest.skip("no OpenBLAS found in this process")
    before = _blas_counts()
    two = _accepts(2)
    with blas.blas_threads(2):
        assert _blas_counts() == two
        with blas.single_threaded_blas():
            assert _blas_counts() == [1] * len(api)
        assert _blas_counts() == two
    with blas.single_threaded_blas():
        with blas.blas_threads(2):       # held single-threaded: unchanged
            assert _blas_counts() == [1] * len(api)
        assert _blas_counts() == [1] * len(api)
    assert _blas_counts() == before



def test_only_the_adjust_step_takes_every_core():
    # the adjustment is a barrier of the run's graph; the kernels run beside the adjusted RFMs' tasks
    assert steps.adjust_step.threads == ALL
    assert all(f.threads == 1 for f in (steps.kernels_step, steps.match_step, steps.detect_step, steps.isd_step,
                                         steps.rpc_step, steps.pyramid_step, steps.tiepoints_step))


def test_image_threads_give_the_serial_adjustment():
    # a fresh block per thread count: the line-scan time search keeps a warm start from call to call, so
    # both runs see the same history; the 1-thread run is the image-by-image loop
    results = []
    for n in (1, 2):
        case = linescan_case(seed=0)
        with image_threads(n):
            res = solve(case.problem, SolverOptions(ftol=1e-10))
        assert res.converged
        results.append(res)
    a, b = results
    assert a.iterations == b.iterations
    for x, y in ((a.cam_params, b.cam_params), (a.points, b.points)):
        scale = np.maximum(np.abs(x), 1.0)
        assert np.max(np.abs(x - y) / scale) <= 1e-9


def test_a_serial_run_limits_the_barrier_step_to_one_thread(tmp_path):
    # engine._compute runs the sync scheduler under barrier_threads(1): a serial run is the one-core baseline
    step = _step("demo", "txt", threads=ALL)(_seen)
    seen: list = []
    with steps.barrier_threads(1):
        step(Store(tmp_path), "k", seen)
    assert seen[0][1] == 1 and all(c == 1 for c in seen[0][0])


def test_altimetry_table_is_read_once_per_process_and_named_when_bad(tmp_path):
    # the run reads its shot tables before any work; the adjust step then finds them in the process's cache
    import os

    from lunarmap.errors import AltimetryInputError
    from lunarmap.io.altimetry import AltimetryShots, write_altimetry

    shots = AltimetryShots(np.array(["a", "a", "b", "b"]), np.arange(4.0), np.array([1.0, 1.1, 1.2, 1.3]),
                           np.array([2.0, 2.1, 2.2, 2.3]), np.full(4, 1737.4e3))
    path = write_altimetry(tmp_path / "shots.csv", shots)
    first = steps.altimetry_table(path)
    assert steps.altimetry_table(path) is first
    np.testing.assert_array_equal(first.lat, shots.lat)       # oracle: the table written
    with pytest.raises(ValueError):
        first.radius[0] = 0.0                                 # shared: read-only
    with open(path, "a") as fh:
        fh.write("c,9,1,2,nan\n")                             # changed content: read again, and named
    os.utime(path, ns=(1, 1))
    with pytest.raises(AltimetryInputError, match="NaN"):
        steps.altimetry_table(path)
    with pytest.raises(AltimetryInputError, match="does not exist"):
        steps.altimetry_table(tmp_path / "missing.csv")
