"""Resident memory of this process: now, its peak, and the peak over a block of code (Linux ``/proc``).

Memory counts like time: the run records the peak resident memory of its processes and of its
adjustment step (:mod:`lunarmap.workflows`), so scale figures come with their memory. Off Linux the
peak falls back to ``ru_maxrss`` and the block peak to the values at its ends.
"""

from __future__ import annotations

import contextlib
import functools
import threading
from dataclasses import dataclass
from typing import Any, Iterator

__all__ = ["rss_mb", "peak_rss_mb", "PeakRss", "peak_rss_during", "release_free_memory"]


def _status(key: str) -> float | None:
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(key):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def rss_mb() -> float:
    """Resident memory of this process now, MB (``VmRSS``; 0 where unknown)."""
    v = _status("VmRSS:")
    return v if v is not None else 0.0


def peak_rss_mb() -> float:
    """Peak resident memory of this process, MB (``VmHWM``; ``ru_maxrss`` elsewhere)."""
    v = _status("VmHWM:")
    if v is not None:
        return v
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


@dataclass
class PeakRss:
    """What :func:`peak_rss_during` measured: resident memory at the start and its peak during the block, MB."""

    start_mb: float = 0.0
    peak_mb: float = 0.0

    @property
    def added_mb(self) -> float:
        """Peak minus start, MB: what the block needed beyond what the process already held."""
        return max(self.peak_mb - self.start_mb, 0.0)


class _Sampler:
    """One daemon thread per process that samples the resident memory while any block is being watched.

    A thread per watched block cost a thread start and join for every run step, also for the thousands
    of steps a rerun only finds in its store; this one starts once (again after a fork) and idles, without
    sampling, while nothing is watched.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._watched: dict[int, tuple[PeakRss, float]] = {}
        self._wake = threading.Condition(self._lock)
        self._pid = 0

    def _ensure_thread(self) -> None:
        import os

        if self._pid != os.getpid():       # first use, or a forked child without the parent's thread
            self._pid = os.getpid()
            self._watched = {}
            self._wake = threading.Condition(self._lock)
            threading.Thread(target=self._loop, name="lunarmap-rss", daemon=True).start()

    def _loop(self) -> None:
        with self._lock:
            while True:
                while not self._watched:
                    self._wake.wait()
                interval = min(iv for _, iv in self._watched.values())
                self._wake.wait(interval)
                if self._watched:
                    now = rss_mb()
                    for out, _ in self._watched.values():
                        out.peak_mb = max(out.peak_mb, now)

    def watch(self, out: PeakRss, interval: float) -> None:
        with self._lock:
            self._ensure_thread()
            self._watched[id(out)] = (out, interval)
            self._wake.notify()

    def unwatch(self, out: PeakRss) -> None:
        with self._lock:
            self._watched.pop(id(out), None)


_SAMPLER = _Sampler()


@contextlib.contextmanager
def peak_rss_during(interval: float = 0.05) -> Iterator[PeakRss]:
    """Sample the resident memory every ``interval`` seconds while the block runs (one daemon thread per process).

    Blocks may nest and run in several threads at once; each sees the process's resident memory, so
    concurrent blocks share their peaks.
    """
    now = rss_mb()
    out = PeakRss(now, now)
    _SAMPLER.watch(out, interval)
    try:
        yield out
    finally:
        _SAMPLER.unwatch(out)
        out.peak_mb = max(out.peak_mb, rss_mb())


def release_free_memory() -> None:
    """Give the C heap's free pages back to the system (glibc ``malloc_trim``; nothing elsewhere).

    numpy's temporaries of a few MB come from the heap once glibc has raised its mmap threshold, and freed
    ones stay resident: a worker matching full-size pairs one after another held ~250 MB more after each
    batch (measured: 862 MB resident before a trim, 618 MB after).
    """
    trim = _malloc_trim()
    if trim is not None:
        trim(0)


@functools.lru_cache(maxsize=1)
def _malloc_trim() -> Any:
    """glibc's ``malloc_trim``, looked up once per process (``None`` off Linux or without glibc)."""
    import ctypes
    import sys

    if not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL("libc.so.6").malloc_trim
    except (OSError, AttributeError):      # not glibc (musl): nothing to do
        return None
