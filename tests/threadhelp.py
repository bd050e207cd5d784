"""Run a function in several threads at once and hand back every thread's result or exception.

A thread that raises must fail the test: ``threading.Thread`` only prints the traceback, so a
test that joins threads and checks a list the threads append to still passes when a thread
crashed before appending. :func:`in_threads` re-raises the first exception in the calling thread.
"""

from __future__ import annotations

import threading
from typing import Any, Callable

__all__ = ["ThreadFailure", "in_threads"]


class ThreadFailure(AssertionError):
    """A worker thread raised; the original exception is the ``__cause__``."""


def in_threads(fn: Callable[[int], Any], n: int = 4, timeout: float = 120.0) -> list[Any]:
    """``[fn(0), ..., fn(n - 1)]``, each in its own thread, all released at the same instant.

    The threads wait at a barrier so that their first calls really overlap (a lazy cache is
    built by whichever arrives first while the others are already asking for it).

    Raises
    ------
    ThreadFailure
        A thread raised (the first exception is chained) or did not finish within ``timeout`` s.
    """
    barrier = threading.Barrier(n)
    results: list[Any] = [None] * n
    errors: list[tuple[int, BaseException]] = []

    def run(i: int) -> None:
        try:
            barrier.wait()
            results[i] = fn(i)
        except BaseException as err:  # noqa: BLE001 - handed to the calling thread
            errors.append((i, err))

    threads = [threading.Thread(target=run, args=(i,), daemon=True) for i in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout)
    if any(t.is_alive() for t in threads):
        raise ThreadFailure(f"{sum(t.is_alive() for t in threads)} of {n} threads still running after {timeout} s")
    if errors:
        i, err = errors[0]
        raise ThreadFailure(f"thread {i} raised {type(err).__name__}: {err} ({len(errors)} of {n} threads failed)") from err
    return results
