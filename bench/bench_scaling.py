#!/usr/bin/env python3
"""How the block adjustment grows with the number of images: the figures behind ``docs/SCALING.md``.

For each size, in a fresh process: the DLR-paper frame block of :func:`lunarmap.simulate.frame_block`
(parallel orbits of Clementine-like frame images, 40 points per image, 2-4 images per point), solved on
the rigorous cameras (:class:`lunarmap.adjust.SensorImageModel`, OD_K distortion) with navigation
observations (per-orbit offset and drift) and control points, then:

* the reduced camera system at the solution: unknowns, stored 6 x 6 blocks (camera pairs that share a
  point), the time of one sparse Cholesky factorisation (symbolic + numeric, the backend ``auto``
  picks), and the factor's nonzeros when the backend exposes them;
* the solve (wall seconds, iterations), the posterior precision (every camera and point covariance,
  redundancy numbers), and the process's peak resident memory.

Prints one table and appends a JSON line to ``bench/results/scaling.jsonl``. Usage::

    python bench/bench_scaling.py [--sizes 48 500 2000 4000] [--points-per-image 40]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))

#: images -> (orbits, images per orbit)
LAYOUT = {48: (4, 12), 500: (20, 25), 1000: (25, 40), 2000: (40, 50), 4000: (50, 80), 8000: (80, 100)}


def one(n: int, ppi: int, precision: bool) -> dict:
    import numpy as np

    sys.path.insert(0, HERE)
    from bench_rigorous_frame import rigorous_problem

    from lunarmap.adjust import SolverOptions, solve
    from lunarmap.adjust.factor import Factorizer, available_backends
    from lunarmap.adjust.normal import Terms, linearize, reduced_system
    from lunarmap.simulate import frame_block

    orbits, per = LAYOUT[n]
    out: dict = {"images": n, "layout": [orbits, per]}
    t = time.perf_counter()
    sb = frame_block(orbits=orbits, per_orbit=per, points=ppi * n, n_control=max(4, n // 25), control_sigma=1.0,
                     seed=3)
    pb = rigorous_problem(sb)
    out["simulate_s"] = time.perf_counter() - t
    out["points"] = int(pb.n_points)
    out["observations"] = int(pb.obs.n)
    solve(pb, SolverOptions(max_iterations=1))           # compile once, outside the timings
    t = time.perf_counter()
    res = solve(pb, SolverOptions(ftol=1e-8))
    out["solve_s"] = time.perf_counter() - t
    out["iterations"] = int(res.iterations)
    out["sigma0"] = float(res.sigma0)
    terms = Terms(pb)
    lin = linearize(pb, res.state, res.structure, terms, pb.point_fixed())
    S = reduced_system(lin, res.structure, terms, 0.0, res.free_red)[0]
    out["rcs_unknowns"] = int(S.shape[0])
    out["rcs_nnz"] = int(S.nnz)
    out["rcs_neighbours_per_image"] = float((S.nnz / 36.0 - n) / n) if S.shape[0] >= 6 * n else float("nan")
    out["backend"] = available_backends()[0]
    t = time.perf_counter()
    solve_S = Factorizer("auto")(S)
    out["factor_s"] = time.perf_counter() - t
    t = time.perf_counter()
    solve_S(np.ones(S.shape[0]))
    out["triangular_solve_s"] = time.perf_counter() - t
    if precision:
        t = time.perf_counter()
        res.precision()
        out["precision_s"] = time.perf_counter() - t
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[48, 500, 2000])
    ap.add_argument("--points-per-image", type=int, default=40)
    ap.add_argument("--no-precision", action="store_true")
    ap.add_argument("--one", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.one:
        print(json.dumps(one(args.one, args.points_per_image, not args.no_precision)))
        return
    rows = []
    for n in args.sizes:
        if n not in LAYOUT:
            raise SystemExit(f"size {n} not in {sorted(LAYOUT)}")
        cmd = [sys.executable, __file__, "--one", str(n), "--points-per-image", str(args.points_per_image)]
        if args.no_precision:
            cmd.append("--no-precision")
        load = os.getloadavg()[0]
        p = subprocess.run(cmd, capture_output=True, text=True, check=True)
        row = json.loads(p.stdout.strip().splitlines()[-1])
        row["load"] = load
        rows.append(row)
        print(f"{n:6d} images {row['points']:8d} points {row['observations']:9d} obs | RCS {row['rcs_unknowns']:7d} "
              f"unknowns {row['rcs_nnz']:10d} nnz ({row['rcs_neighbours_per_image']:.1f} neighbours/image) "
              f"factor {row['factor_s']:7.3f} s | solve {row['solve_s']:7.2f} s ({row['iterations']} it, "
              f"sigma0 {row['sigma0']:.3f}) | precision {row.get('precision_s', float('nan')):7.2f} s | "
              f"peak {row['peak_rss_mb']:7.0f} MB | load {load:.1f}", flush=True)
    os.makedirs(os.path.join(HERE, "results"), exist_ok=True)
    with open(os.path.join(HERE, "results", "scaling.jsonl"), "a") as fh:
        fh.write(json.dumps({"date": time.strftime("%Y-%m-%d %H:%M"), "machine": platform.node(),
                             "rows": rows}) + "\n")


if __name__ == "__main__":
    main()
