"""The synthetic imaging block end to end: write, render, match with the navigation cameras (a script, not a test).

1. :func:`lunarmap.synthetic.write_block_mission` (3 orbits, 12 images) into a folder;
2. :func:`lunarmap.simulate.render_block` of every image (supersample 2, threads) - the
   rendering time is the figure the block was sized for (<= about 60 s on 2 cores);
3. :func:`lunarmap.matching.find_tiepoints` on one image per orbit (NAC-like orbit 1,
   TC-like orbit 2, frame orbit 3) with the NAVIGATION cameras as sensors, and the
   matched positions against the truth (image-1 point through its truth camera onto
   the truth DTM, into image 2 through the truth camera).

    python bench/bench_block.py [--folder block_output] [--supersample 2] [--seed 0]

Prints a summary and one JSON line. The machine is shared: the load average is printed
with the rendering time.
"""

from __future__ import annotations

import argparse
import json
import os
import time
import warnings

import numpy as np

from lunarmap.matching import MatchParams, TiePointParams, find_tiepoints
from lunarmap.simulate import block_cameras, matching_errors, render_block
from lunarmap.synthetic import write_block_mission

MATCHED = ("orbit1_nac", "orbit2_tc", "orbit3_frame_a")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--folder", default="block_output")
    ap.add_argument("--supersample", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    t = time.perf_counter()
    bm = write_block_mission(args.folder, seed=args.seed)
    t_write = time.perf_counter() - t
    load0 = os.getloadavg()[0]
    t = time.perf_counter()
    rb = render_block(bm, supersample=args.supersample)
    t_total = time.perf_counter() - t
    n_px = sum(img.size for img in rb.images.values())
    print(f"wrote {len(bm.image_names)} labels and both kernel sets in {t_write:.2f} s -> {bm.folder}")
    print(f"rendered {len(rb.images)} images ({n_px / 1e6:.2f} Mpixel, {args.supersample}x{args.supersample} rays "
          f"per pixel) in {rb.seconds:.1f} s (with scene and cameras {t_total:.1f} s; load average "
          f"{load0:.1f} -> {os.getloadavg()[0]:.1f})")

    truth = block_cameras(bm, "truth", MATCHED)
    nav = block_cameras(bm, "navigation", MATCHED)
    params = TiePointParams(match=MatchParams(search=128.0))
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        tp = find_tiepoints({n: rb.images[n] for n in MATCHED}, nav, params=params, scheduler="sync")
    t_match = time.perf_counter() - t
    names = list(tp["image"].values)
    pid, iid = tp["point_id"].values, tp["image_id"].values
    line, sample = tp["line"].values, tp["sample"].values
    first: dict[int, int] = {}
    rows: dict[tuple[str, str], list[tuple[int, int]]] = {}
    for k in np.argsort(pid, kind="stable"):
        if pid[k] in first:
            rows.setdefault((names[iid[first[pid[k]]]], names[iid[k]]), []).append((first[pid[k]], k))
        else:
            first[pid[k]] = k
    report: dict[str, object] = {"render_s": rb.seconds, "render_total_s": t_total, "megapixels": n_px / 1e6,
                                 "supersample": args.supersample, "match_s": t_match, "pairs": {}}
    errs = []
    print(f"tie points with the navigation cameras ({t_match:.1f} s): {tp.attrs['matches_per_pair']}")
    for (a, b), rr in sorted(rows.items()):
        r0, r1 = np.array(rr).T
        dl, ds = matching_errors(truth[a], truth[b], line[r0], sample[r0], line[r1], sample[r1], rb.dtm)
        e = np.hypot(dl, ds)
        errs.append(e)
        report["pairs"][f"{a}|{b}"] = {"n": int(e.size), "median_px": float(np.median(e)),
                                       "p95_px": float(np.percentile(e, 95)), "max_px": float(e.max())}
        print(f"  {a} -> {b}: {e.size} matches vs truth: median {np.median(e):.3f} px, "
              f"95 % {np.percentile(e, 95):.3f} px, max {e.max():.3f} px")
    e = np.concatenate(errs)
    print(f"  all: median {np.median(e):.3f} px, 95 % {np.percentile(e, 95):.3f} px")
    print(json.dumps(report))


if __name__ == "__main__":
    main()
