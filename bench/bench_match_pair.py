#!/usr/bin/env python3
"""Time and profile the matching of one image pair (``match_step``), and compare two code versions in one run.

Cases:

* ``example``: the overlapping pairs of the embedded example (``lunarmap.workflows.write_example``,
  ~0.3 Mpixel images, read by window through their stored pyramids, DTM prediction), exactly as
  ``lunarmap run`` matches them: the arguments of every ``match_step`` of one serial run are recorded
  once (``<folder>/match_calls.pkl``) and replayed without writing to the store;
* ``nac``: a full-size NAC-like window pair (0.5 m pixels, 10 deg convergence, ``--nac-size`` pixels
  square, noise sigma 2), read by window, with the full-size example's search (256 px, so the
  prediction offset is measured first) and a navigation error of (37, -23) px added to the prediction
  by shifting image 2.

Modes::

    python bench/bench_match_pair.py --profile [--case example|nac]     # cProfile breakdown by stage
    git worktree add ../lunarmap-base <old commit>
    python bench/bench_match_pair.py --base ../lunarmap-base [--rounds 3]  # old/new per-pair ratio

With ``--base`` two worker processes are started, one importing lunarmap from this checkout and one from
``--base`` (a worktree of the old commit); every pair is matched by both in turn (the order alternates),
so both see the same machine load; each worker times its own ``match_pair`` (region cache emptied first,
numba compiled by a warm-up). Reported: the median over pairs of the per-pair ratio old / new, and how
far the new matches lie from the old ones. The machine is shared: only the ratios mean anything.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import pickle  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
NAC_SHIFT = (37, -23)        # navigation error of the NAC-like case, image-2 pixels (line, sample)


# -- the cases ---------------------------------------------------------------------------------

def record_example(folder: Path) -> Path:
    """Write the example and run it once serially, recording every ``match_step``'s arguments."""
    calls = folder / "match_calls.pkl"
    if calls.exists():
        return calls
    import lunarmap.workflows.steps as st
    from lunarmap.workflows import run, write_example

    cfg = write_example(folder)
    seen = []
    real = st.match_step

    def capture(*a, **k):
        seen.append((a, k))
        return real(*a, **k)

    st.match_step = capture
    try:
        run(cfg, scheduler="sync", report=False)
    finally:
        st.match_step = real
    with open(calls, "wb") as fh:
        pickle.dump(seen, fh)
    return calls


def example_pairs(folder: Path) -> list:
    """The recorded ``match_step`` calls whose pairs overlap enough to be matched."""
    import lunarmap.workflows.steps as st

    with open(record_example(folder), "rb") as fh:
        calls = pickle.load(fh)
    out = []
    for a, _ in calls:
        (_store, _key, pair, pixels, isds, pyramids, points, dtm, params, min_overlap, *rest) = a
        cam_a, cam_b = st._camera(isds[0]), st._camera(isds[1])
        mean_h = st._dtm_sampler(dtm)[1] if dtm is not None else 0.0
        if st._overlap(cam_a, cam_b, mean_h) >= min_overlap:
            out.append(a)
    return out


def nac_images(size: int, folder: Path) -> Path:
    """Render (once) the NAC-like window pair; image 2 is shifted by :data:`NAC_SHIFT`."""
    path = folder / f"nac_pair_{size}.npz"
    if path.exists():
        return path
    from lunarmap.simulate import render_image, stereo_pair, synthetic_scene

    c1, c2 = stereo_pair("linescan", 10.0, n_lines=size, n_samples=size)
    dtm, alb = synthetic_scene(30.0, 0.0, size * 0.5 * 1.3, 0.5, seed=5)
    i1 = render_image(c1, dtm, alb, supersample=2, noise_sigma=2.0, sun="eo", seed=1).values
    i2 = render_image(c2, dtm, alb, supersample=2, noise_sigma=2.0, sun="eo", seed=2).values
    # image 2 content moved by NAC_SHIFT: the cameras' predictions are off by that much
    i2 = np.roll(i2, NAC_SHIFT, axis=(0, 1))
    folder.mkdir(parents=True, exist_ok=True)
    np.savez(path, i1=i1.astype(np.float32), i2=i2.astype(np.float32), dtm=dtm.values,
             lat=dtm["lat"].values, lon=dtm["lon"].values)
    return path


class NacCase:
    def __init__(self, path: Path) -> None:
        import xarray as xr

        from lunarmap.camera import DtmSampler
        from lunarmap.matching import TiePointParams, foerstner
        from lunarmap.matching.windowed import WindowedImage
        from lunarmap.simulate import stereo_pair

        z = np.load(path)
        self.i1, self.i2 = z["i1"].astype(float), z["i2"].astype(float)
        size = self.i1.shape[0]
        self.c1, self.c2 = stereo_pair("linescan", 10.0, n_lines=size, n_samples=size)
        self.w1, self.w2 = WindowedImage(self.i1), WindowedImage(self.i2)
        dtm = xr.DataArray(z["dtm"], coords={"lat": z["lat"], "lon": z["lon"]}, dims=("lat", "lon"))
        self.height = DtmSampler(dtm)
        self.points = foerstner(self.i1, cell=64, per_cell=1, border=10)
        self.params = TiePointParams()
        self.params.match.search = 256.0

    def match(self):
        from lunarmap.matching.tiepoints import match_pair

        return match_pair(self.w1, self.w2, self.c1, self.c2, self.points, self.height, self.params, "nac")


def example_match(args):
    """``match_step`` without its store: cameras, windowed images, points, DTM, ``match_pair``."""
    import lunarmap.workflows.steps as st
    from lunarmap.matching.tiepoints import match_pair

    (store, _key, pair, pixels, isds, pyramids, points, dtm, params, _min_overlap, *rest) = args
    digests = rest[0] if rest else ("", "")
    cam_a, cam_b = st._camera(isds[0]), st._camera(isds[1])
    height = st._dtm_sampler(dtm)[0] if dtm is not None else 0.0
    img_a = st._windowed(store, pair[0], pixels[0], digests[0], params, pyramids[0])
    img_b = st._windowed(store, pair[1], pixels[1], digests[1], params, pyramids[1])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return match_pair(img_a, img_b, cam_a, cam_b, st._load_points(points), height, params, " -> ".join(pair))


def _fresh_cache() -> None:
    from lunarmap.matching.windowed import CACHE_BYTES, set_cache_bytes

    set_cache_bytes(0)
    set_cache_bytes(CACHE_BYTES)


# -- profile -----------------------------------------------------------------------------------

STAGES = {  # a function's file and name -> stage (cumulative time of the outermost hit)
    "detection": [("interest.py", "foerstner")],
    "prediction (camera models)": [("predict.py", "predict_conjugates"), ("thinning.py", "thin_points")],
    "NCC search": [("ncc.py", "ncc_match")],
    "bilinear resampling (NCC, LSM template)": [("resample.py", "bilinear"), ("ncc_compiled.py", "affine_windows")],
    "  NCC surface": [("ncc.py", "_ncc_surface"), ("ncc_compiled.py", "ncc_surface")],
    "LSM": [("lsm.py", "lsm_match")],
    "  LSM resampling (bicubic)": [("resample.py", "bicubic_with_gradient")],
    "  LSM covariance": [("lsm.py", "_covariance")],
    "  LSM smoothing": [("lsm.py", "_smooth"), ("windowed.py", "fill")],
    "pixels read (regions, pyramid levels)": [("windowed.py", "_compute"), ("windowed.py", "_lazy")],
    "RANSAC": [("ransac.py", "ransac_local_affine")],
    "overlap / cameras": [("steps.py", "_overlap"), ("steps.py", "_camera")],
}


def _jobs(case: str, folder: Path, size: int) -> list:
    """One callable per pair of the case: the example's pairs, or the NAC-like window pair."""
    if case == "example":
        return [lambda a=a: example_match(a) for a in example_pairs(folder)]
    return [NacCase(nac_images(size, folder)).match]


def profile(case: str, folder: Path, size: int) -> None:
    import cProfile
    import pstats

    jobs = _jobs(case, folder, size)
    jobs[0]()                                   # numba compilation, imports
    pr = cProfile.Profile()
    t = time.perf_counter()
    for job in jobs:
        _fresh_cache()
        pr.enable()
        job()
        pr.disable()
    wall = time.perf_counter() - t
    st = pstats.Stats(pr)
    total = sum(v[3] for k, v in st.stats.items() if k[2] == "match_pair")  # type: ignore[attr-defined]
    print(f"\n{case}: {len(jobs)} pairs, {wall:.2f} s wall, match_pair {total:.2f} s (cProfile)")
    for stage, keys in STAGES.items():
        cum = 0.0
        for k, v in st.stats.items():  # type: ignore[attr-defined]
            if any(k[0].endswith(f) and k[2] == fn for f, fn in keys):
                cum += v[3]
        print(f"  {stage:40s} {cum:8.3f} s  {100 * cum / total:5.1f} %")
    st.sort_stats("cumulative").print_stats(30)
    st.sort_stats("tottime").print_stats(30)


# -- compare two versions ----------------------------------------------------------------------

def worker(case: str, folder: Path, size: int) -> None:
    """Serve ``{"i": k, "out": path}`` requests on stdin: match pair k, save it, print the time."""
    import lunarmap

    jobs = _jobs(case, folder, size)
    jobs[0]()
    print(json.dumps({"ready": len(jobs), "lunarmap": lunarmap.__file__}), flush=True)
    for line in sys.stdin:
        req = json.loads(line)
        _fresh_cache()
        t0 = time.process_time()
        t = time.perf_counter()
        m = jobs[req["i"]]()
        wall = time.perf_counter() - t
        cpu = time.process_time() - t0
        np.savez(req["out"], line2=m.line2, sample2=m.sample2, sigma_line=m.sigma_line, sigma_sample=m.sigma_sample,
                 ok=m.ok)
        print(json.dumps({"wall": wall, "cpu": cpu, "ok": int(m.ok.sum())}), flush=True)


def compare(case: str, folder: Path, size: int, base: str, rounds: int) -> dict:
    env_new = dict(os.environ, PYTHONPATH=str(HERE.parent))
    env_old = dict(os.environ, PYTHONPATH=str(base))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--case", case, "--folder", str(folder),
           "--nac-size", str(size)]
    if case == "example":
        record_example(folder)
    else:
        nac_images(size, folder)
    procs = {v: subprocess.Popen(cmd, env=e, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
             for v, e in (("new", env_new), ("old", env_old))}
    n = 0
    for v, p in procs.items():
        hello = json.loads(p.stdout.readline())  # type: ignore[union-attr]
        n = hello["ready"]
        print(f"{v}: {hello['lunarmap']}, {n} pairs", flush=True)
    tmp = Path(tempfile.mkdtemp())
    ratios, cpu_ratios, rows = [], [], []
    dpos, dsig, nok = [], [], []
    for r in range(rounds):
        for i in range(n):
            res = {}
            order = ("old", "new") if (i + r) % 2 == 0 else ("new", "old")
            for v in order:
                out = tmp / f"{v}_{i}.npz"
                procs[v].stdin.write(json.dumps({"i": i, "out": str(out)}) + "\n")  # type: ignore[union-attr]
                procs[v].stdin.flush()  # type: ignore[union-attr]
                res[v] = json.loads(procs[v].stdout.readline())  # type: ignore[union-attr]
            ratios.append(res["old"]["wall"] / res["new"]["wall"])
            cpu_ratios.append(res["old"]["cpu"] / res["new"]["cpu"])
            rows.append({"round": r, "pair": i, **{f"{v}_{k}": res[v][k] for v in res for k in res[v]}})
            if r == 0:
                a, b = np.load(tmp / f"old_{i}.npz"), np.load(tmp / f"new_{i}.npz")
                both = a["ok"] & b["ok"]
                nok.append((int(a["ok"].sum()), int(b["ok"].sum()), int(both.sum())))
                if both.any():
                    dpos.append(float(np.max(np.hypot(a["line2"][both] - b["line2"][both],
                                                      a["sample2"][both] - b["sample2"][both]))))
                    dsig.append(float(np.max(np.abs(b["sigma_line"][both] / a["sigma_line"][both] - 1.0))))
            print(f"round {r} pair {i}: old {res['old']['wall']:.3f} s, new {res['new']['wall']:.3f} s, "
                  f"ratio {ratios[-1]:.2f} (cpu {cpu_ratios[-1]:.2f}); ok {res['old']['ok']} / {res['new']['ok']}",
                  flush=True)
    for p in procs.values():
        p.stdin.close()  # type: ignore[union-attr]
        p.wait()
    old_t = statistics.median(r["old_wall"] for r in rows)
    new_t = statistics.median(r["new_wall"] for r in rows)
    summary = {"case": case, "pairs": n, "rounds": rounds, "median_ratio_wall": statistics.median(ratios),
               "median_ratio_cpu": statistics.median(cpu_ratios), "median_old_s": old_t, "median_new_s": new_t,
               "matched_old": sum(k[0] for k in nok), "matched_new": sum(k[1] for k in nok),
               "matched_both": sum(k[2] for k in nok),
               "max_position_change_px": max(dpos) if dpos else None,
               "max_rel_sigma_change": max(dsig) if dsig else None}
    print(json.dumps(summary))
    return summary


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=["example", "nac"], default="example")
    ap.add_argument("--folder", default=str(HERE / "data" / "match_example"))
    ap.add_argument("--nac-size", type=int, default=2048, help="side of the NAC-like windows, pixels")
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--base", help="checkout of the old code to compare against")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    folder = Path(a.folder)
    if a.worker:
        worker(a.case, folder, a.nac_size)
    elif a.profile:
        profile(a.case, folder, a.nac_size)
    elif a.base:
        compare(a.case, folder, a.nac_size, a.base, a.rounds)
    else:
        ap.error("give --profile or --base")


if __name__ == "__main__":
    main()
