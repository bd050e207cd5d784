"""The example of several sites end to end: write, render, run the whole chain (a script, not a test).

1. :func:`lunarmap.workflows.write_example` with ``sites`` (default 4: 48 images in one kernel
   set) - the rendering time of :func:`lunarmap.simulate.render_block` is reported apart;
2. :func:`lunarmap.workflows.run` of its ``run.toml`` (``--scheduler sync`` by default);
3. the scene layout (per site: latitude, rolls per orbit, cross-orbit convergence), the match
   steps (pairs skipped across sites, matches per pair), the check points before / after per site.

    python bench/multisite_example.py [--folder multisite_output] [--sites 4] [--seed 0]
                                      [--scheduler sync | --workers 2] [--reuse] [--resume]

``--reuse`` keeps an example already in the folder (no rendering); the run folder is emptied
first unless ``--resume`` (then the steps already in its store are not recomputed).

Prints a summary and one JSON line. The machine may be shared: the load average is printed
with every time.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import time
from pathlib import Path

import numpy as np
import xarray as xr

import lunarmap.simulate as simulate
from lunarmap.workflows import run, write_example


def _load() -> str:
    return "/".join(f"{v:.1f}" for v in os.getloadavg())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--folder", default="multisite_output")
    ap.add_argument("--sites", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scheduler", default="sync", help="'sync', 'threads' or 'cluster' (a LocalCluster)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--reuse", action="store_true", help="keep the example already written in --folder")
    ap.add_argument("--resume", action="store_true", help="keep the run's store (no timing of reused steps)")
    args = ap.parse_args()
    root = Path(args.folder)

    rendered: dict[str, float] = {}
    real = simulate.render_block

    def timed(*a, **k):  # write_example imports render_block from lunarmap.simulate when called
        out = real(*a, **k)
        rendered.update(seconds=out.seconds, images=len(out.images),
                        mpixel=sum(img.size for img in out.images.values()) / 1e6)
        return out

    load0 = _load()
    t_example = 0.0
    if args.reuse and (root / "run.toml").is_file():
        cfg = root / "run.toml"
        rendered.update(seconds=float("nan"), images=len(json.loads(
            (root / "mission" / "block_mission.json").read_text())["images"]), mpixel=float("nan"))
        print(f"example reused: {cfg}")
    else:
        simulate.render_block = timed
        t = time.perf_counter()
        cfg = write_example(root, seed=args.seed, sites=args.sites)
        t_example = time.perf_counter() - t
        simulate.render_block = real
        print(f"example: {rendered['images']} images ({rendered['mpixel']:.1f} Mpixel) rendered in "
              f"{rendered['seconds']:.1f} s; example written in {t_example:.1f} s (load {load0} -> {_load()})")
    if not args.resume:
        shutil.rmtree(root / "run", ignore_errors=True)

    load1 = _load()
    t = time.perf_counter()
    res = run(cfg, scheduler=None if args.scheduler == "cluster" else args.scheduler, workers=args.workers)
    t_run = time.perf_counter() - t
    s = res.summary
    print(f"run ({args.scheduler}): {t_run:.1f} s (load {load1} -> {_load()}); stages ends "
          + ", ".join(f"{k} {v:.0f} s" for k, v in res.stage_seconds.items()))

    man = json.loads((root / "mission" / "block_mission.json").read_text())
    conv = man["convergence_deg"]
    matched = [d for d in res.done if d.step == "match" and not d.note.startswith("skipped")]
    skipped = sum(d.step == "match" and d.note.startswith("skipped") for d in res.done)
    with xr.open_dataset(res.outputs["adjustment"] / "check_points.nc") as cp:
        names = cp["check"].values.astype(str)
        before, after, z = (cp[k].values for k in ("error_before", "error_after", "normalized_after"))
    sites = man.get("sites", [{"site": 1, "latitude_deg": man["site"]["latitude_deg"]}])
    per_site = []
    for st in sites:
        k = st["site"]
        prefix = f"s{k}_" if len(sites) > 1 else ""
        passes = man.get("passes", man["orbits"])
        rolls = [p["roll_deg"] for p in passes if p.get("site", 1) == k]
        mine = {key: v for key, v in conv.items() if key.startswith(prefix)}
        cross = [v for key, v in mine.items() if len({re.search(r"orbit\d", n).group() for n in key.split("|")}) == 2]
        counts = []
        for d in matched:
            a, b = d.item.split(" -> ")
            if a.startswith(prefix) and b.startswith(prefix):
                counts.append(int(d.note.split("/")[0]))
        sel = np.char.startswith(names, f"{prefix}K")
        rms = [float(np.sqrt(np.mean(np.sum(e[sel] ** 2, axis=1)))) for e in (before, after)]
        per_site.append({"site": k, "latitude_deg": st["latitude_deg"], "rolls_deg": [round(r, 1) for r in rolls],
                         "cross_orbit_convergence_deg": [round(min(cross), 1), round(max(cross), 1)],
                         "pairs": len(counts), "matches_min_median": [min(counts), float(np.median(counts))],
                         "check_rms_3d_before_after_m": [round(rms[0], 2), round(rms[1], 3)],
                         "check_normalized_rms": round(float(np.sqrt(np.mean(z[sel] ** 2))), 2)})
        print(f"site {k}: {st['latitude_deg']:.1f} deg, rolls {per_site[-1]['rolls_deg']}, cross-orbit convergence "
              f"{min(cross):.1f}-{max(cross):.1f} deg, {len(counts)} pairs ({min(counts)}-{max(counts)} matches), "
              f"check 3-D RMS {rms[0]:.1f} -> {rms[1]:.3f} m")
    b3 = float(np.linalg.norm(s["check_rms_before_m"]))
    a3 = float(np.linalg.norm(s["check_rms_after_m"]))
    print(f"{s['n_points']} tie points, {s['n_observations']} observations, sigma0 {s['sigma0']:.3f}; {skipped} pairs "
          f"skipped (no overlap); check 3-D RMS {b3:.1f} -> {a3:.3f} m ({b3 / a3:.0f}x), errors/sigma RMS "
          f"{s['check_normalized_rms']:.2f}")
    print(json.dumps({"sites": args.sites, "images": rendered["images"], "render_s": rendered["seconds"],
                      "example_s": t_example, "run_s": t_run, "scheduler": args.scheduler, "load_start": load0,
                      "load_end": _load(), "stage_end_s": res.stage_seconds, "pairs_skipped": skipped,
                      "n_points": s["n_points"], "sigma0": s["sigma0"], "check_rms_3d_m": [b3, a3],
                      "check_normalized_rms": s["check_normalized_rms"], "per_site": per_site}))


if __name__ == "__main__":
    main()
