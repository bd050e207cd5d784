"""Per-phase CPU and wall time of the adjustment's iterations (off unless a :class:`PhaseTimer` is active).

The solver and the normal-equation code mark their phases with ``with phase("name"):``. Without an active
timer that is a no-op (one global read), so the instrumentation stays in the production path. CPU time is
``time.process_time`` (all threads of the process): on a shared machine, where other jobs stretch the wall
time of a niced process, the CPU seconds per phase and their shares are the figures that compare.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from typing import Iterator

__all__ = ["PhaseTimer", "phase"]

_active: list["PhaseTimer"] = []


class PhaseTimer:
    """Accumulates CPU seconds (``time.process_time``), wall seconds and call counts per phase name.

    Use as a context manager around :func:`lunarmap.adjust.solve`. Times are exclusive: a phase opened
    inside another is charged to itself only (the outer phase's figure excludes it), so the phases sum to
    the instrumented total.
    """

    def __init__(self) -> None:
        self.cpu: dict[str, float] = {}
        self.wall: dict[str, float] = {}
        self.calls: dict[str, int] = {}
        self._stack: list[list[float]] = []     # [cpu, wall] of nested phases, per open phase

    def __enter__(self) -> "PhaseTimer":
        _active.append(self)
        return self

    def __exit__(self, *exc) -> None:
        _active.remove(self)

    def add(self, name: str, cpu: float, wall: float) -> None:
        self.cpu[name] = self.cpu.get(name, 0.0) + cpu
        self.wall[name] = self.wall.get(name, 0.0) + wall
        self.calls[name] = self.calls.get(name, 0) + 1

    def table(self) -> list[dict]:
        """Rows ``{phase, calls, cpu_s, wall_s, cpu_share}`` sorted by CPU time; shares of the phases' total."""
        total = sum(self.cpu.values()) or 1.0
        return [{"phase": k, "calls": self.calls[k], "cpu_s": round(self.cpu[k], 4),
                 "wall_s": round(self.wall[k], 4), "cpu_share": round(self.cpu[k] / total, 4)}
                for k in sorted(self.cpu, key=lambda k: -self.cpu[k])]


@contextmanager
def phase(name: str) -> Iterator[None]:
    """Charge the enclosed code's CPU and wall time to ``name`` in the active :class:`PhaseTimer`, if any."""
    if not _active:
        yield
        return
    timer = _active[-1]
    timer._stack.append([0.0, 0.0])
    c0, w0 = time.process_time(), time.perf_counter()
    try:
        yield
    finally:
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        inner = timer._stack.pop()
        timer.add(name, cpu - inner[0], wall - inner[1])
        if timer._stack:
            timer._stack[-1][0] += cpu
            timer._stack[-1][1] += wall
