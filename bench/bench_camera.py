"""Throughput of the line-scan camera model (a script, not a test).

Builds the synthetic 52,224-line x 5,064-sample NAC-like line-scan camera of
the tests (circular polar orbit at 50 km over a 1737.4 km sphere, LRO NAC
``lrolrocnac`` distortion), runs ``image_to_ground`` and ``ground_to_image``
on ``--points`` random pixels and prints one JSON line::

    python bench/bench_camera.py [--points 1000000] [--workers 2] [--seed 0]

``baseline_per_point`` is the hook for a per-point reference implementation
(e.g. a SPICE ``sincpt`` loop on synthetic kernels); it times whatever
callable it is given on a subset of the points and reports points/s.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from typing import Any, Callable

import numpy as np

from lunarmap.camera import LineScanCamera, Shape
from lunarmap.simulate.orbits import NAC_LINE_TIME, NAC_LINES, NAC_SAMPLES, nac_like_interior, polar_orbit_eo


def build_camera(workers: int | None = None) -> LineScanCamera:
    """The synthetic NAC-like line-scan camera of ``tests/test_camera_linescan.py``."""
    eo = polar_orbit_eo(lat_center=0.0, lon=30.0, altitude=50_000.0, half_span=12.0, step=0.05)
    t0 = -NAC_LINES * NAC_LINE_TIME / 2.0
    return LineScanCamera(nac_like_interior(), eo, Shape.moon(), line_times=(t0, NAC_LINE_TIME),
                          workers=workers)


# ----------------------------------------------------------------------------
# HOOK: baseline_per_point
# Wire a per-point reference here (e.g. a spiceypy.sincpt loop on synthetic
# SPICE kernels). ``func(line, sample)`` is called once per point with Python
# floats and may return anything; only the time is measured.
# ----------------------------------------------------------------------------
def baseline_per_point(func: Callable[[float, float], Any], line: np.ndarray, sample: np.ndarray,
                       max_points: int = 20_000, max_seconds: float = 30.0) -> dict[str, float]:
    """Time a per-point callable on up to ``max_points`` points (stopping after ``max_seconds``).

    Returns
    -------
    dict
        ``{"points": n_done, "seconds": elapsed, "points_per_s": rate}``.
    """
    n = min(max_points, line.size)
    t_start = time.perf_counter()
    done = 0
    for i in range(n):
        func(float(line[i]), float(sample[i]))
        done += 1
        if time.perf_counter() - t_start > max_seconds:
            break
    elapsed = time.perf_counter() - t_start
    return {"points": done, "seconds": elapsed, "points_per_s": done / elapsed if elapsed > 0 else float("nan")}


def run(n_points: int, workers: int | None, seed: int,
        baseline: Callable[[float, float], Any] | None = None) -> dict[str, Any]:
    rng = np.random.default_rng(seed)
    line = rng.uniform(0.0, NAC_LINES, n_points)
    sample = rng.uniform(0.0, NAC_SAMPLES, n_points)
    cam = build_camera(workers)

    t = time.perf_counter()
    cam.ground_to_image(cam.image_to_ground(line[:1000], sample[:1000]))  # builds the line table
    setup = time.perf_counter() - t

    t = time.perf_counter()
    ground = cam.image_to_ground(line, sample)
    t_i2g = time.perf_counter() - t

    t = time.perf_counter()
    l2, s2 = cam.ground_to_image(ground)
    t_g2i = time.perf_counter() - t

    err = np.hypot(l2 - line, s2 - sample)
    result: dict[str, Any] = {
        "benchmark": "lunarmap.camera.LineScanCamera",
        "image": [NAC_LINES, NAC_SAMPLES],
        "points": n_points,
        "workers": cam.workers,
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "setup_s": round(setup, 4),
        "image_to_ground_points_per_s": round(n_points / t_i2g),
        "ground_to_image_points_per_s": round(n_points / t_g2i),
        "image_to_ground_s": round(t_i2g, 4),
        "ground_to_image_s": round(t_g2i, 4),
        "round_trip_max_px": float(np.nanmax(err)),
        "not_seen": int(np.count_nonzero(np.isnan(err))),
    }
    if baseline is not None:
        result["baseline_per_point"] = baseline_per_point(baseline, line, sample)
    return result


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    print(json.dumps(run(args.points, args.workers, args.seed)))


if __name__ == "__main__":
    main()
