#!/usr/bin/env python3
"""Benchmark lunarmap.adjust against scipy.optimize.least_squares and Ceres on the same BAL problems.

Every figure is a ratio against baselines measured in the same run: for each round, each
problem is solved by each solver in turn (interleaved, separate processes), and medians over
rounds are reported.  The BAL problems come from the shared generator
(``../shared/bench/make_block.py``; generated into ``bench/data/``, git-ignored) and the
reference solvers are the shared harness' ``solve_scipy.py`` (trf, analytic sparse Jacobian)
and ``solve_ceres.py`` (pycolmap's Ceres 2.2, SPARSE_SCHUR).  Ceres is skipped, with a
message, when pycolmap is not importable.

"Time to target" is the time at which a solver's cost trace first reaches the final cost of
Ceres (or of scipy if Ceres is absent) times ``1 + 1e-6``; the table also gives it as a ratio to
the reference solver's own time to that cost, and the precision time as a ratio to the solve.

Usage::

    python bench/bench_adjust.py --sizes small medium --rounds 2
    python bench/bench_adjust.py --sizes large1m --rounds 2 --solvers lunarmap ceres --precision
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import statistics
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
SHARED = os.environ.get("LUNARMAP_SHARED_BENCH", os.path.join(HERE, "..", "..", "shared", "bench"))
DATA = os.path.join(HERE, "data")
RESULTS = os.path.join(HERE, "results")


def solver_cmd(name: str, bal: str, args) -> list[str] | None:
    py = sys.executable
    if name == "lunarmap":
        cmd = [py, os.path.join(HERE, "solve_lunarmap.py"), bal]
        return cmd + (["--precision"] if args.precision else [])
    if name == "scipy":
        return [py, os.path.join(SHARED, "solve_scipy.py"), bal, "--jac", "analytic",
                "--time-limit", str(args.scipy_time_limit)]
    if name == "ceres":
        return [py, os.path.join(SHARED, "solve_ceres.py"), bal, "--linear-solver", "SPARSE_SCHUR", "--threads", "2"]
    raise ValueError(name)


def ensure_data(size: str) -> str:
    bal = os.path.join(DATA, f"{size}.bal.txt")
    if not os.path.exists(bal):
        os.makedirs(DATA, exist_ok=True)
        subprocess.run([sys.executable, os.path.join(SHARED, "make_block.py"), "--preset", size, "--out", bal],
                       check=True)
    return bal


def time_to(trace, target):
    for t, c in trace:
        if c <= target:
            return t
    return None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", nargs="+", default=["small", "medium"])
    ap.add_argument("--solvers", nargs="+", default=["lunarmap", "scipy", "ceres"])
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--precision", action="store_true", help="lunarmap also computes posterior precision")
    ap.add_argument("--scipy-time-limit", type=float, default=600.0)
    ap.add_argument("--out", default=os.path.join(RESULTS, "bench_adjust.jsonl"))
    args = ap.parse_args(argv)
    solvers = list(args.solvers)
    if "ceres" in solvers and importlib.util.find_spec("pycolmap") is None:
        print("Ceres skipped: pycolmap is not installed (pip install pycolmap pyceres; benchmark-only)")
        solvers.remove("ceres")
    os.makedirs(RESULTS, exist_ok=True)
    runs: dict = {}
    for size in args.sizes:
        bal = ensure_data(size)
        for rnd in range(args.rounds):
            for name in solvers:
                t0 = time.time()
                p = subprocess.run(solver_cmd(name, bal, args), capture_output=True, text=True)
                lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
                rec = {"size": size, "round": rnd, "solver": name, "wall_s": round(time.time() - t0, 2),
                       "started": time.strftime("%Y-%m-%dT%H:%M:%S", time.localtime(t0))}
                if lines:
                    rec["result"] = json.loads(lines[-1])
                else:
                    rec["error"] = (p.stdout[-1500:] + p.stderr[-1500:]).strip()
                with open(args.out, "a") as fh:
                    fh.write(json.dumps(rec) + "\n")
                runs.setdefault((size, name), []).append(rec)
                r = rec.get("result", {})
                print(f"{size:8s} round {rnd} {name:9s} solve {r.get('solve_s')} s, cost {r.get('cost_final')}, "
                      f"iterations {r.get('iterations')}, peak RSS {r.get('peak_rss_mb')} MB"
                      + (f", precision {r.get('precision_s')} s" if 'precision_s' in r else "")
                      + (f"  ERROR {rec['error'][-300:]}" if "error" in rec else ""), flush=True)
    print()
    print("| size | solver | median solve s | median time to target s | time to target / reference |"
          " final cost | iterations | peak RSS MB | ratio solve / lunarmap | precision s | precision / solve |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for size in args.sizes:
        ref = "ceres" if (size, "ceres") in runs else "scipy"
        finals = [r["result"]["cost_final"] for r in runs.get((size, ref), []) if "result" in r]
        target = (min(finals) if finals else None)
        med, ttt = {}, {}
        for name in solvers:
            rs = [r["result"] for r in runs.get((size, name), []) if "result" in r]
            if rs:
                tt = [time_to(r.get("trace_t_cost", []), target * (1 + 1e-6)) for r in rs] if target else []
                tt = [t for t in tt if t is not None]
                ttt[name] = statistics.median(tt) if tt else None
        for name in solvers:
            rs = [r["result"] for r in runs.get((size, name), []) if "result" in r]
            if not rs:
                continue
            solve_s = statistics.median(r["solve_s"] for r in rs)
            med[name] = solve_s
            prec = [r["precision_s"] for r in rs if "precision_s" in r]
            tt, tref = ttt.get(name), ttt.get(ref)
            ratio = round(tt / tref, 2) if tt is not None and tref else ""
            print(f"| {size} | {name} | {solve_s:.2f} | {round(tt, 2) if tt is not None else 'not reached'} | "
                  f"{ratio} | {statistics.median(r['cost_final'] for r in rs):.6g} | "
                  f"{statistics.median(r['iterations'] for r in rs)} | "
                  f"{max(r.get('peak_rss_mb', 0) for r in rs):.0f} | "
                  f"{'' if 'lunarmap' not in med else round(solve_s / med['lunarmap'], 2)} | "
                  f"{round(statistics.median(prec), 2) if prec else ''} | "
                  f"{round(statistics.median(prec) / solve_s, 2) if prec else ''} |")


if __name__ == "__main__":
    main()
