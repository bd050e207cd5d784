"""Throughput of least-squares matching and dask speed-up of the tie-point chain (a script, not a test).

The machine is shared, so every figure is given as a ratio against a baseline
timed in the same run, next to the absolute rate:

1. ``lsm``: vectorised LSM (all matches in batched numpy) against the same
   code called one match at a time (the per-match Python loop it replaces);
   15 x 15 windows, one thread (BLAS/OpenMP pinned to 1), on a simulated
   NAC-like 10 deg stereo pair. Reports matches per second per core.
2. ``dask``: :func:`lunarmap.matching.find_tiepoints` on a 4-image set
   (6 pairs), serial (``scheduler="sync"``) against a 2-worker
   ``distributed.LocalCluster`` (1 thread per worker), with worker processes
   (started with :data:`lunarmap.matching.WORKER_ENVIRON`) and with in-process
   workers (threads; numpy releases the GIL). Cluster start-up and a warm-up
   run are not timed; serial and cluster runs alternate (best of
   ``--repeat`` each). CPU seconds are reported too (serial: the client
   thread's; cluster: the busier worker process's): a shared machine moves
   them far less than wall time, and their ratio is the speed-up to expect
   when each worker has a core to itself.

    python bench/bench_matching.py [--size 512] [--repeat 3]

Prints a summary and one JSON line.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402

import dask  # noqa: E402
import numpy as np  # noqa: E402

from lunarmap.matching import (  # noqa: E402
    WORKER_ENVIRON,
    TiePointParams,
    build_pyramid,
    find_tiepoints,
    foerstner,
    lsm_match,
    ncc_match,
    predict_conjugates,
)
from lunarmap.simulate import pointed_camera, render_image, stereo_pair, synthetic_scene  # noqa: E402


def best_of(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def bench_lsm(size: int, repeat: int) -> dict:
    dtm, alb = synthetic_scene(30.0, 0.0, size * 0.5 * 1.6, 0.5, seed=2)
    c1, c2 = stereo_pair("linescan", 10.0, n_lines=size, n_samples=size)
    i1 = render_image(c1, dtm, alb, supersample=2, noise_sigma=2.0, sun="eo", seed=1).values.astype(float)
    i2 = render_image(c2, dtm, alb, supersample=2, noise_sigma=2.0, sun="eo", seed=2).values.astype(float)
    pts = foerstner(i1, cell=8, per_cell=1)
    p = predict_conjugates(c1, c2, pts.line, pts.sample, 0.0)
    ncc = ncc_match(build_pyramid(i1, 4), build_pyramid(i2, 4), pts.line, pts.sample, p.line, p.sample, p.affine,
                    half=7, search=12.0)
    ok = np.isfinite(ncc.correlation)
    l1, s1, l2, s2, aff = pts.line[ok], pts.sample[ok], ncc.line[ok], ncc.sample[ok], p.affine[ok]
    n = l1.size
    t_vec = best_of(lambda: lsm_match(i1, i2, l1, s1, l2, s2, aff, half=7), repeat)
    res = lsm_match(i1, i2, l1, s1, l2, s2, aff, half=7)
    k = min(n, 150)

    def loop() -> None:
        for q in range(k):
            lsm_match(i1, i2, l1[q:q + 1], s1[q:q + 1], l2[q:q + 1], s2[q:q + 1], aff[q:q + 1], half=7)
    t_loop = best_of(loop, repeat)
    rate_vec = n / t_vec
    rate_loop = k / t_loop
    return dict(matches=int(n), converged=int(res.converged.sum()),
                mean_iterations=float(res.iterations[res.converged].mean()),
                lsm_matches_per_s_per_core=rate_vec, per_match_loop_matches_per_s=rate_loop,
                speedup_vs_per_match_loop=rate_vec / rate_loop)


def bench_dask(size: int, repeat: int) -> dict:
    from distributed import Client, LocalCluster

    dtm, alb = synthetic_scene(30.0, 0.0, size * 0.5 * 1.6, 0.5, seed=4)
    cams = {f"img{k}": pointed_camera("linescan", 30.0, 0.0, e, n_lines=size, n_samples=size)
            for k, e in enumerate((-7.0, -2.0, 3.0, 8.0))}
    imgs = {k: render_image(c, dtm, alb, supersample=2, noise_sigma=2.0, sun="eo", seed=i).compute()
            for i, (k, c) in enumerate(cams.items())}
    params = TiePointParams()
    # 2 x 2 tiles per image: a 128-px tile (16 per image) is ~2 ms of detection, less than the per-task
    # overhead of a distributed worker (measured: worker CPU +35% over serial with 128-px tiles, +18% with 256).
    params.detect.tile = max(64, size // 2)
    params.detect.cell = 16
    params.detect.per_cell = 1
    params.match.search = 16.0
    out: dict = {}

    def serial() -> tuple[float, float]:
        t, c = time.perf_counter(), time.thread_time()
        out["s"] = find_tiepoints(imgs, cams, params=params, scheduler="sync")
        return time.perf_counter() - t, time.thread_time() - c

    res: dict = {}
    for label, procs in (("processes", True), ("threads", False)):
        # Worker processes without distributed's MALLOC_TRIM_THRESHOLD_ (see lunarmap.matching.parallel):
        # with it, the matching tasks ran 2-7x slower in the workers than in the client.
        with dask.config.set({"distributed.nanny.pre-spawn-environ": WORKER_ENVIRON}), \
                LocalCluster(n_workers=2, threads_per_worker=1, processes=procs, dashboard_address=":0") as cluster, \
                Client(cluster) as client:
            find_tiepoints(imgs, cams, params=params, scheduler=client)  # warm-up: imports on the workers
            # Serial and cluster runs alternate, so a change of machine load hits both alike.
            ts, tc, cs, cw = [], [], [], []
            for _ in range(repeat):
                t, c = serial()
                ts.append(t)
                cs.append(c)
                w0 = client.run(time.process_time) if procs else None
                t = time.perf_counter()
                out["c"] = find_tiepoints(imgs, cams, params=params, scheduler=client)
                tc.append(time.perf_counter() - t)
                if procs:
                    w1 = client.run(time.process_time)
                    cw.append(max(w1[w] - w0[w] for w in w1))
            res[label] = dict(serial=min(ts), cluster=min(tc), cpu_serial=min(cs), cpu_busier_worker=cw)
    P, T = res["processes"], res["threads"]
    same = bool(out["s"].sizes == out["c"].sizes and np.allclose(out["s"].line, out["c"].line))
    return dict(images=4, pairs=6, image_size=size, observations=int(out["s"].sizes["observation"]),
                tie_points=int(out["s"].point_id.max() + 1), serial_s=P["serial"], cluster_2_workers_s=P["cluster"],
                speedup_2_workers=P["serial"] / P["cluster"], serial_s_threads_run=T["serial"],
                cluster_2_workers_in_process_s=T["cluster"], speedup_2_workers_in_process=T["serial"] / T["cluster"],
                # CPU seconds move far less than wall time on a shared machine: serial CPU / the busier
                # worker's CPU is the speed-up to expect when each worker process has a core to itself.
                cpu_serial_s=P["cpu_serial"], cpu_busier_worker_s=P["cpu_busier_worker"],
                speedup_if_cores_free=P["cpu_serial"] / min(P["cpu_busier_worker"]),
                cluster_result_equals_serial=same)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=512, help="image size (lines = samples), pixels")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--skip-dask", action="store_true")
    args = ap.parse_args()
    r = {"cpu_count": os.cpu_count(), "python": platform.python_version(), "load_avg_start": os.getloadavg()}
    r["lsm"] = bench_lsm(args.size, args.repeat)
    L = r["lsm"]
    print(f"LSM 15x15: {L['lsm_matches_per_s_per_core']:.0f} matches/s/core vectorised vs "
          f"{L['per_match_loop_matches_per_s']:.0f}/s per-match loop (x{L['speedup_vs_per_match_loop']:.1f}); "
          f"{L['converged']}/{L['matches']} converged, {L['mean_iterations']:.1f} iterations", flush=True)
    if not args.skip_dask:
        r["dask"] = bench_dask(args.size, args.repeat)
        D = r["dask"]
        print(f"tie points, 4 images x {args.size}^2, 6 pairs: serial {D['serial_s']:.2f} s, 2-worker LocalCluster "
              f"{D['cluster_2_workers_s']:.2f} s -> speed-up x{D['speedup_2_workers']:.2f} "
              f"(same result: {D['cluster_result_equals_serial']}); in-process 2-worker cluster "
              f"{D['cluster_2_workers_in_process_s']:.2f} s -> x{D['speedup_2_workers_in_process']:.2f}; CPU: serial "
              f"{D['cpu_serial_s']:.2f} s, busier worker {min(D['cpu_busier_worker_s']):.2f} s -> "
              f"x{D['speedup_if_cores_free']:.2f} with free cores")
    r["load_avg_end"] = os.getloadavg()
    print(json.dumps(r))


if __name__ == "__main__":
    main()
