#!/usr/bin/env python3
"""The example's quality control against the simulator's truth (issue 27): precision, recall, false removals.

Reads a finished ``lunarmap run --example --output DIR`` (its ``mission/`` and ``run/outputs/adjustment/
residuals.nc``), computes every tie observation's true error from the truth cameras and the true DTM
(:func:`lunarmap.evaluate.qc_truth.true_tie_errors`) and prints, for each threshold of what counts as
wrong, the removed / wrong / good counts, precision (wrong among the removed), recall (removed among the
wrong) and false removals as a share of the good observations. Every line is also a JSON record.

    python bench/example_qc_truth.py DIR [--limits 0.5 1 2 3 5 10] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("example", type=Path, help="the --output folder of lunarmap run --example")
    ap.add_argument("--limits", type=float, nargs="+", default=None, help="thresholds of a wrong observation (px)")
    ap.add_argument("--json", type=Path, help="write the records here too")
    args = ap.parse_args(argv)

    import numpy as np
    import xarray as xr

    from lunarmap.evaluate.qc_truth import QC_TRUTH_LIMITS_PX, qc_against_truth
    from lunarmap.simulate import block_cameras
    from lunarmap.simulate.mission import block_dtm_file
    from lunarmap.synthetic import open_block_mission

    t0 = time.process_time()
    bm = open_block_mission(args.example / "mission")
    with xr.open_dataset(args.example / "run" / "outputs" / "adjustment" / "residuals.nc") as ds:
        resid = ds.load()
    # image index -> name as the run wrote them (not assumed to be the mission's order)
    idx, first = np.unique(resid["image"].values, return_index=True)
    names = [""] * (int(idx.max()) + 1)
    for i, f in zip(idx, first):
        names[int(i)] = str(resid["image_name"].values[f])
    truth = block_cameras(bm, "truth", names=sorted(set(names) - {""}))
    with xr.open_dataarray(bm.folder / block_dtm_file(bm)) as da:
        dtm = da.load()
    q = qc_against_truth(resid, truth, names, dtm, limits_px=args.limits or QC_TRUTH_LIMITS_PX)
    records = []
    for c in q["curve"]:
        rec = {"part": "qc-truth", **{k: (round(v, 4) if isinstance(v, float) else v) for k, v in c.items()}}
        records.append(rec)
        print(json.dumps(rec), flush=True)
    for c in q.get("curve_others", []):
        rec = {"part": "qc-truth-others", **{k: (round(v, 4) if isinstance(v, float) else v) for k, v in c.items()}}
        records.append(rec)
        print(json.dumps(rec), flush=True)
    for key, part in (("curve_sigma", "qc-truth-sigma"), ("curve_sigma_others", "qc-truth-sigma-others")):
        for c in q.get(key, []):
            rec = {"part": part, **{k: (round(v, 4) if isinstance(v, float) else v) for k, v in c.items()}}
            records.append(rec)
            print(json.dumps(rec), flush=True)
    tail = {"part": "qc-truth-summary", "sigma_px_median": round(q.get("sigma_px_median", float("nan")), 4), "removed_median_px": round(q["removed_median_px"], 3),
            "kept_median_px": round(q["kept_median_px"], 3),
            "removed_median_others_px": round(q["removed_median_others_px"], 3),
            "kept_median_others_px": round(q["kept_median_others_px"], 3), "orphaned_kept": q["orphaned_kept"],
            "no_partner": q["no_partner"], "by_status_at_1px": q.get("by_status"),
            "cpu_s": round(time.process_time() - t0, 1)}
    records.append(tail)
    print(json.dumps(tail), flush=True)
    print(f"{'limit':>14} {'removed':>8} {'wrong':>7} {'good':>7} {'rem.wrong':>9} {'rem.good':>8} "
          f"{'precision':>9} {'recall':>7} {'false/good':>10}")
    rows = [("nearest", c) for c in q["curve"] + q.get("curve_sigma", [])] + \
        [("others", c) for c in q.get("curve_others", []) + q.get("curve_sigma_others", [])]
    for how, c in rows:
        lim = (f"{c['limit_sigma']:g} sig" if "limit_sigma" in c else f"{c['limit_px']:g}") + \
            (" (others)" if how == "others" else "")
        print(f"{lim:>14} {c['removed']:8d} {c['wrong']:7d} {c['good']:7d} {c['removed_wrong']:9d} "
              f"{c['removed_good']:8d} {c['precision']:9.3f} {c['recall']:7.3f} {100 * c['false_removal_share']:9.2f}%")
    if args.json:
        args.json.write_text("\n".join(json.dumps(r) for r in records) + "\n")


if __name__ == "__main__":
    main()
