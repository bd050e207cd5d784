#!/usr/bin/env python3
"""Solve a BAL problem with lunarmap.adjust; prints one JSON line with the keys of the shared harness.

Control points listed in the ``.meta.json`` sidecar are held fixed (as the scipy and Ceres
solvers of ``../shared/bench`` do).  ``--precision`` also computes the posterior standard
deviations of all images and points and reports the time it took.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time

import numpy as np

from lunarmap.adjust import SolverOptions, bal_to_problem, problem_to_bal_cameras, read_bal, solve

SHARED = os.environ.get("LUNARMAP_SHARED_BENCH", os.path.join(os.path.dirname(os.path.abspath(__file__)),
                                                              "..", "..", "shared", "bench"))


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _status_mb(key: str) -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def phase_peak() -> float:
    """Peak RSS (MB) since the last call, then reset (Linux ``/proc/self/clear_refs``; NaN elsewhere)."""
    try:
        peak = _status_mb("VmHWM:")
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return peak
    except OSError:
        return float("nan")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("bal")
    ap.add_argument("--backend", default="auto")
    ap.add_argument("--ftol", type=float, default=1e-6)
    ap.add_argument("--max-iterations", type=int, default=100)
    ap.add_argument("--precision", action="store_true")
    ap.add_argument("--no-datum-check", action="store_true")
    ap.add_argument("--acceleration-memory", type=int, default=SolverOptions.acceleration_memory,
                    help="Anderson acceleration memory (0: plain Levenberg-Marquardt)")
    ap.add_argument("--min-mu-factor", type=float, default=SolverOptions.min_mu_factor,
                    help="smallest factor by which an accepted step lowers the damping")
    ap.add_argument("--linear-solver", default=SolverOptions.linear_solver, choices=["auto", "direct", "pcg"],
                    help="reduced camera system: sparse Cholesky, block-Jacobi PCG, or by size")
    ap.add_argument("--pcg-tolerance", type=float, default=SolverOptions.pcg_tolerance,
                    help="PCG relative residual (forcing tolerance)")
    ap.add_argument("--time-limit", type=float, default=0.0, help="accepted for harness compatibility (unused)")
    args = ap.parse_args(argv)
    phase_peak()
    base = _status_mb("VmRSS:") if os.path.exists("/proc/self/status") else float("nan")
    t0 = time.perf_counter()
    data = read_bal(args.bal)
    t_read = time.perf_counter() - t0
    t0 = time.perf_counter()
    problem = bal_to_problem(data)
    opts = SolverOptions(ftol=args.ftol, max_iterations=args.max_iterations, backend=args.backend,
                         check_datum=not args.no_datum_check, acceleration_memory=args.acceleration_memory,
                         min_mu_factor=args.min_mu_factor, linear_solver=args.linear_solver,
                         pcg_tolerance=args.pcg_tolerance)
    peak_read = phase_peak()
    c0 = time.process_time()
    res = solve(problem, opts)
    t_solve = time.perf_counter() - t0
    cpu_solve = time.process_time() - c0
    peak_solve = phase_peak()
    out = {
        "solver": f"lunarmap-{args.backend}",
        "problem": os.path.basename(args.bal),
        "n_cameras": problem.n_images, "n_points": problem.n_points, "n_observations": problem.obs.n,
        "solve_s": round(t_solve, 3),
        "read_s": round(t_read, 3),
        # CPU seconds of the solve (all threads): comparable between runs on a loaded machine, unlike solve_s
        "solve_cpu_s": round(cpu_solve, 3),
        "linear_solver": res.linear_solver, "linear_iterations": res.linear_iterations,
        "iterations": res.iterations, "successful_steps": res.accepted,
        "message": res.message,
        "cost_initial": res.cost_initial, "cost_final": res.cost,
        "rms_final_px": res.rms_px(), "sigma0": res.sigma0,
        "trace_t_cost": [(round(t, 4), c) for t, c in res.trace],
    }
    if args.precision:
        t1 = time.perf_counter()
        pr = res.precision()
        out["precision_s"] = round(time.perf_counter() - t1, 3)
        out["precision_method"] = pr.method
        sig = np.sqrt(np.diagonal(pr.pt_cov, axis1=1, axis2=2))
        out["median_point_sigma"] = float(np.median(sig[np.isfinite(sig).all(axis=1)]))
        out["undetermined_points"] = int(len(pr.undetermined_points))
        peak_prec = phase_peak()
        out["peak_rss_precision_mb"] = round(peak_prec, 1)
        out["bytes_per_obs_precision"] = round((peak_prec - base) * 2**20 / problem.obs.n, 1)
    # the adjustment's memory per image observation: peak above the process after its imports (the BAL
    # data, the problem, the solver's arrays and factor), MB -> bytes per observation
    out["rss_after_imports_mb"] = round(base, 1)
    out["peak_rss_read_mb"] = round(peak_read, 1)
    out["peak_rss_solve_mb"] = round(peak_solve, 1)
    out["bytes_per_obs_solve"] = round((max(peak_read, peak_solve) - base) * 2**20 / problem.obs.n, 1)
    try:
        sys.path.insert(0, SHARED)
        import balutil as bu

        cams = problem_to_bal_cameras(problem.model, res.cam_params)
        out["accuracy_final"] = bu.accuracy_vs_truth(args.bal, cams, res.points)
        out["rms_final_px_balutil"] = bu.read_bal(args.bal).rms_px(cams, res.points)
    except ImportError:
        pass
    out["peak_rss_mb"] = round(peak_rss_mb(), 1)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
