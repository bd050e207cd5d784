#!/usr/bin/env python3
"""Accuracy and cost of a run against ``[tiepoints] max_points``: the curve behind its default.

The example (``lunarmap.workflows.write_example``, written once) is run serially for each value of
``max_points`` in one run folder, so the per-image steps are computed once and every value recomputes
exactly its matching, tracks and adjustment. Per value: tie observations, matching seconds (sum over
pairs), adjustment seconds, check points' 3-D RMS after the adjustment and errors / posterior sigma.
Prints a table and appends JSON lines to ``bench/results/thinning.jsonl``. Usage::

    python bench/bench_thinning.py [--folder bench/data/thinning_example] [--values 25 50 100 200 400 0]
        [--sites 1] [--full-size]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--folder", default=str(HERE / "data" / "thinning_example"))
    ap.add_argument("--values", type=int, nargs="+", default=[25, 50, 100, 200, 400, 0])
    ap.add_argument("--full-size", action="store_true", help="the full-size example (write_example(full_size=True))")
    args = ap.parse_args()
    from lunarmap.workflows import load_config, run, write_example

    folder = Path(args.folder)
    toml = folder / "run.toml"
    if not toml.exists():
        write_example(folder, **({"full_size": True} if args.full_size else {}))
    text = toml.read_text()
    rows = []
    for v in args.values:
        cfg_text = re.sub(r"max_points = \d+\n", "", text)
        cfg_text = cfg_text.replace("[tiepoints]\n", f"[tiepoints]\nmax_points = {v}\n", 1)
        path = folder / f"run_max{v}.toml"
        path.write_text(cfg_text)
        t = time.perf_counter()
        res = run(load_config(path), scheduler="sync", report=False)
        wall = time.perf_counter() - t
        s = res.summary
        match_s = sum(d.seconds for d in res.done if d.step == "match" and d.computed)
        adj_s = sum(d.seconds for d in res.done if d.step == "adjust" and d.computed)
        after = float(np.sqrt(np.sum(np.square(s["check_rms_after_m"]))))
        row = {"max_points": v, "observations": s["n_observations"], "points": s["n_points"], "match_s": match_s,
               "adjust_s": adj_s, "wall_s": wall, "check_rms_after_m": after,
               "check_normalized_rms": s["check_normalized_rms"], "sigma0": s["sigma0"],
               "load": os.getloadavg()[0], "images": len(res.config.images)}
        rows.append(row)
        print(f"max_points {v:5d}: {row['observations']:7d} obs, matching {match_s:7.1f} s, adjust {adj_s:6.1f} s, "
              f"check 3-D RMS {after:.3f} m, errors/sigma {row['check_normalized_rms']:.2f} (load {row['load']:.1f})",
              flush=True)
    (HERE / "results").mkdir(exist_ok=True)
    with open(HERE / "results" / "thinning.jsonl", "a") as fh:
        for r in rows:
            fh.write(json.dumps({"date": time.strftime("%Y-%m-%d %H:%M"), **r}) + "\n")


if __name__ == "__main__":
    main()
