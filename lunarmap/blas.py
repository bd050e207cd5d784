"""Run a block with single-threaded OpenBLAS, or with ``n`` threads (best effort, no dependency).

Why (first met in the RPC fit): its least-squares problems are tall and thin (tens of thousands
of rows, 39 columns). On this project's shared 2-core machines, OpenBLAS's
threads made ``numpy.linalg.lstsq`` on them 10-20 times slower than one
thread whenever another process held a core (measured: 6.4 s vs 0.4 s for
one NAC fit). dask worker processes already run with one BLAS thread
(distributed's ``pre-spawn-environ``); this gives the serial path the same.

Implemented with ``ctypes`` on the OpenBLAS that numpy loaded; a no-op
when the library or its symbols are not found. Nested and concurrent use is
counted under a lock, so the original thread count is restored by the last
exit. threadpoolctl (3.8) was tried instead and is not equivalent here: it
lets only one "controlling" Python thread change OpenBLAS's process-wide
limit and silently ignores the others, so on dask's threaded scheduler a
task entering the block from a second thread (or leaving it last) did not
set or restore the limit; the tiled fit then ran some BLAS calls on two
threads and stopped being bit-identical to the serial fit
(``tests/test_rpc_fit.py::test_dask_tiles_equal_serial`` failed).
"""

from __future__ import annotations

import contextlib
import ctypes
import threading
from typing import Callable, Iterator

__all__ = ["single_threaded_blas", "blas_threads"]

_lock = threading.Lock()
_depth = 0
_saved: list[int] | None = None
_api: list[tuple[Callable[[], int], Callable[[int], None]]] | None = None  # None: not looked up yet
_paths: frozenset[str] = frozenset()
_held: list[tuple[Callable[[], int], Callable[[int], None]]] = []   # the libraries the outermost block set


def _current_api() -> list[tuple[Callable[[], int], Callable[[int], None]]]:
    """The thread-count functions of the OpenBLAS libraries loaded now: looked up again whenever a library was
    loaded since (scipy.linalg's own, or a third one another package brings: a cached list would leave it
    at its own count)."""
    global _api, _paths
    paths = _openblas_paths()
    if _api is None or paths != _paths:
        _api, _paths = _find_api(paths), paths
    return _api


def _openblas_paths() -> frozenset[str]:
    """The OpenBLAS libraries mapped into the process now (~0.5 ms to read ``/proc/self/maps``)."""
    try:
        with open("/proc/self/maps", encoding="ascii", errors="replace") as fh:
            return frozenset(ln.split()[-1] for ln in fh
                             if "openblas" in ln.lower() and ln.split()[-1].startswith("/"))
    except OSError:
        return frozenset()


def _find_api(paths: frozenset[str] | None = None) -> list[tuple[Callable[[], int], Callable[[int], None]]]:
    """(get, set) thread-count functions of every OpenBLAS in the process (numpy and scipy each ship one; other
    packages may load more later)."""
    if paths is None:
        paths = _openblas_paths()
    found = []
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for prefix, suffix in (("scipy_openblas", "64_"), ("scipy_openblas", ""), ("openblas", "64_"),
                               ("openblas", "")):
            get = getattr(lib, f"{prefix}_get_num_threads{suffix}", None)
            put = getattr(lib, f"{prefix}_set_num_threads{suffix}", None)
            if get is not None and put is not None:
                get.restype = ctypes.c_int
                put.argtypes = [ctypes.c_int]
                found.append((get, put))
                break
    return found


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Context in which OpenBLAS uses one thread; restores the previous count on exit."""
    global _depth, _saved, _held
    with _lock:
        if _depth == 0:
            _held = _current_api()
            _saved = [int(get()) for get, _ in _held]
            for _, put in _held:
                put(1)
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0 and _saved is not None:
                for (_, put), n in zip(_held, _saved):
                    put(n)
                _saved = None


@contextlib.contextmanager
def blas_threads(n: int) -> Iterator[None]:
    """Context in which OpenBLAS may use ``n`` threads (a run step that runs alone: :mod:`lunarmap.workflows.steps`).

    :func:`single_threaded_blas` wins: entered inside this block it limits BLAS to one thread until it exits
    (code that found threads only spin at its sizes keeps one), and while any other thread of the process
    holds it this block changes nothing. OpenBLAS started with ``OPENBLAS_NUM_THREADS=1`` (dask workers)
    starts its extra threads when asked for them.
    """
    global _saved
    n = max(1, int(n))
    mine: list[int] | None = None
    with _lock:
        api = _current_api()
        if _depth == 0:
            mine = [int(get()) for get, _ in api]
            for _, put in api:
                put(n)
    try:
        yield
    finally:
        with _lock:
            if mine is not None:
                if _depth == 0:
                    for (_, put), k in zip(api, mine):
                        put(k)
                elif _saved is not None and _held is api:
                    _saved = mine       # a single-threaded block of another thread restores the original count
