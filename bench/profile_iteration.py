#!/usr/bin/env python3
"""Where an LM iteration of the bundle adjustment spends its time: CPU seconds per phase and their shares.

    python bench/profile_iteration.py BLOCK.bal.txt [--max-iterations 5] [--linear-solver direct|pcg]

Runs :func:`lunarmap.adjust.solve` on a BAL block (control points of the ``.meta.json`` sidecar fixed, as
``bench/solve_lunarmap.py`` does) inside a :class:`lunarmap.adjust.timing.PhaseTimer` and prints a markdown
table (phase, calls, CPU s per iteration, share of the solve's CPU, wall s per iteration) and one JSON line.
CPU time is ``time.process_time`` (all threads): on a shared machine a niced process's wall time stretches
with the load, its CPU time much less, so the shares are the figures that compare between runs.
A warm-up solve of one iteration first (numba's compiled kernels load or compile, caches fill); it is
not counted. ``untracked`` is the solve's CPU outside the instrumented phases (damping, right-hand side,
bookkeeping).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time

from lunarmap.adjust import SolverOptions, bal_to_problem, read_bal, solve
from lunarmap.adjust.timing import PhaseTimer

#: the phases of one iteration in the order they run (solver.py, normal.py, factor.py, pcg via solver.py)
ORDER = ["jacobians", "whiten", "normal_blocks", "schur_complement", "assemble_S", "factor_symbolic",
         "factor_numeric", "factorize", "triangular_solves", "preconditioner", "pcg", "back_substitution", "cost",
         "acceleration", "datum_check", "untracked"]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bal")
    ap.add_argument("--max-iterations", type=int, default=5)
    ap.add_argument("--linear-solver", default="direct", choices=["auto", "direct", "pcg"])
    ap.add_argument("--pcg-tolerance", type=float, default=SolverOptions.pcg_tolerance)
    ap.add_argument("--ftol", type=float, default=1e-6)
    ap.add_argument("--no-warmup", action="store_true")
    args = ap.parse_args(argv)
    problem = bal_to_problem(read_bal(args.bal))
    opts = SolverOptions(ftol=args.ftol, max_iterations=args.max_iterations, linear_solver=args.linear_solver,
                         pcg_tolerance=args.pcg_tolerance, check_datum=False)
    if not args.no_warmup:
        solve(problem, SolverOptions(max_iterations=1, linear_solver=args.linear_solver, check_datum=False))
    c0, w0 = time.process_time(), time.perf_counter()
    with PhaseTimer() as timer:
        res = solve(problem, opts)
    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
    timer.cpu["untracked"] = cpu - sum(timer.cpu.values())
    timer.wall["untracked"] = wall - sum(timer.wall.values())
    timer.calls["untracked"] = res.iterations
    n = res.iterations
    rows = []
    for name in ORDER + sorted(set(timer.cpu) - set(ORDER)):
        if name in timer.cpu:
            rows.append({"phase": name, "calls": timer.calls[name], "cpu_s_per_iteration": timer.cpu[name] / n,
                         "cpu_share": timer.cpu[name] / cpu, "wall_s_per_iteration": timer.wall[name] / n})
    print(f"{os.path.basename(args.bal)}: {problem.n_images} images, {problem.n_points} points, "
          f"{problem.obs.n} observations; {n} iterations ({res.accepted} accepted), linear solver "
          f"{res.linear_solver}; solve CPU {cpu:.2f} s, wall {wall:.2f} s", file=sys.stderr)
    print("| phase | calls | CPU s / iteration | CPU share | wall s / iteration |", file=sys.stderr)
    print("|---|---|---|---|---|", file=sys.stderr)
    for r in rows:
        print(f"| {r['phase']} | {r['calls']} | {r['cpu_s_per_iteration']:.3f} | {100 * r['cpu_share']:.1f} % "
              f"| {r['wall_s_per_iteration']:.3f} |", file=sys.stderr)
    print(json.dumps({"problem": os.path.basename(args.bal), "n_cameras": problem.n_images,
                      "n_points": problem.n_points, "n_observations": problem.obs.n, "iterations": n,
                      "accepted": res.accepted, "linear_solver": res.linear_solver,
                      "linear_iterations": res.linear_iterations, "cost_final": res.cost, "message": res.message,
                      "solve_cpu_s": round(cpu, 3), "solve_wall_s": round(wall, 3),
                      "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1),
                      "phases": [{k: (round(v, 4) if isinstance(v, float) else v) for k, v in r.items()}
                                 for r in rows]}))


if __name__ == "__main__":
    main()
