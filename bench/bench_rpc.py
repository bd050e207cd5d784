"""RPC fitting speed (a script, not a test): one full-length NAC-like image, and 20 images on dask.

Prints one JSON line. Every speed figure comes with a baseline measured in
the same run, because the machine is shared and timings drift:

* ``single``: ``fit_rpc`` on the synthetic 52,224 x 5,064 NAC-like line-scan
  camera (rigorous fit grid included; with and without the independent
  check), median of ``--repeat`` runs; the ratio is against the rigorous
  model's own ``ground_to_image`` of 20,000 random ground points, timed
  alongside, so "the fit costs X rigorous back-projections of 20k points".
* ``many``: 20 images (NAC-like, varied latitude, longitude and yaw flip),
  ``fit_rpc`` one after the other in this process vs ``fit_many`` on a
  ``distributed.LocalCluster`` with 2 worker processes x 1 thread (cluster
  start-up reported separately, not in the speed-up). Serial and cluster
  runs alternate ``--many-repeat`` times; the speed-up is the median of the
  per-pair ratios. The serial runs fit cache-less copies of the cameras, as
  the workers receive them. CPU seconds are reported too (serial: the fitting
  thread's; cluster: each worker process's, client's apart): on a shared
  machine they move far less than wall time, and ``speedup_if_cores_free`` =
  serial CPU / the busier worker's CPU is the speed-up to expect when each
  worker has a core to itself. Both paths run BLAS
  single-threaded (``fit_rpc`` does internally; workers get
  ``lunarmap.rpc.parallel.WORKER_ENVIRON``, which also drops distributed's
  ``MALLOC_TRIM_THRESHOLD_`` -- measured to double a fit's CPU time).

    python bench/bench_rpc.py [--images 20] [--repeat 5] [--many-repeat 3] [--no-cluster]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import numpy as np

from lunarmap.camera import LineScanCamera, Shape
from lunarmap.rpc import fit_many, fit_rpc
from lunarmap.simulate.orbits import NAC_LINE_TIME, NAC_LINES, nac_like_interior, polar_orbit_eo


def nac_camera(lat: float = 0.0, lon: float = 30.0, flip: bool = False) -> LineScanCamera:
    eo = polar_orbit_eo(lat_center=lat, lon=lon, altitude=50_000.0, half_span=12.0, step=0.05, flip=flip)
    return LineScanCamera(nac_like_interior(), eo, Shape.moon(), line_times=(-NAC_LINES * NAC_LINE_TIME / 2.0,
                                                                             NAC_LINE_TIME))


def _timed(func) -> float:
    t = time.perf_counter()
    func()
    return time.perf_counter() - t


def bench_single(repeat: int) -> dict:
    cam = nac_camera()
    rng = np.random.default_rng(0)
    pts = cam.image_to_ground(rng.uniform(0, NAC_LINES, 20_000), rng.uniform(0, 5064, 20_000),
                              height=rng.uniform(-5000, 5000, 20_000))
    fit_rpc(cam, check=False)  # warm-up (imports, caches)
    base, nocheck, check = [], [], []
    fit = None
    for _ in range(repeat):
        base.append(_timed(lambda: cam.ground_to_image(pts)))
        nocheck.append(_timed(lambda: fit_rpc(cam, check=False)))
        t = time.perf_counter()
        fit = fit_rpc(cam)
        check.append(time.perf_counter() - t)
    b, n, c = statistics.median(base), statistics.median(nocheck), statistics.median(check)
    return {
        "image": f"{NAC_LINES} x 5064 NAC-like line scan", "grid_points": fit.fit.n_points,
        "check_points": fit.check.n_points,
        "fit_s": round(n, 3), "fit_and_check_s": round(c, 3),
        "baseline": "rigorous ground_to_image of 20,000 points", "baseline_s": round(b, 3),
        "fit_over_baseline": round(n / b, 2), "fit_and_check_over_baseline": round(c / b, 2),
        "check_rms_px": fit.check.rms, "check_max_px": fit.check.max, "target_fit_s": 2.0,
    }


def _cold_copies(cams: list) -> list:
    """Bit-exact copies without the cameras' caches, as a worker receives them (fair serial baseline)."""
    import pickle

    from lunarmap.rpc.parallel import ExactCamera

    return [pickle.loads(pickle.dumps(ExactCamera(c))).camera for c in cams]


def bench_many(n_images: int, use_cluster: bool, repeat: int = 3) -> dict:
    rng = np.random.default_rng(1)
    cams = [nac_camera(lat=float(rng.uniform(-60, 60)), lon=float(rng.uniform(-180, 180)), flip=bool(i % 2))
            for i in range(n_images)]
    copies = _cold_copies(cams)
    t, c0 = time.perf_counter(), time.thread_time()
    serial = [fit_rpc(c) for c in copies]
    t_serial = [time.perf_counter() - t]
    cpu_serial = [time.thread_time() - c0]  # this thread's CPU: the client's other threads are not the fit
    out = {"images": n_images, "serial_s": round(t_serial[0], 3),
           "worst_check_rms_px": max(f.check.rms for f in serial),
           "worst_check_max_px": max(f.check.max for f in serial)}
    if not use_cluster:
        return out
    import dask
    import distributed

    from lunarmap.rpc.parallel import WORKER_ENVIRON

    t = time.perf_counter()
    with dask.config.set({"distributed.nanny.pre-spawn-environ": WORKER_ENVIRON}), \
            distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                                     silence_logs=40) as cluster, distributed.Client(cluster) as client:
        t_start = time.perf_counter() - t
        fit_many(cams[:2], client=client)  # warm the workers' imports
        # Serial and cluster runs alternate, so a change of machine load hits both alike.
        t_par: list[float] = []
        cpu_workers, cpu_client = [], []
        for k in range(repeat):
            if k:
                copies = _cold_copies(cams)
                t, c0 = time.perf_counter(), time.thread_time()
                for c in copies:
                    fit_rpc(c)
                t_serial.append(time.perf_counter() - t)
                cpu_serial.append(time.thread_time() - c0)
            w0 = client.run(time.process_time)
            t, c0 = time.perf_counter(), time.process_time()
            par = fit_many(cams, client=client)
            t_par.append(time.perf_counter() - t)
            cpu_client.append(time.process_time() - c0)
            w1 = client.run(time.process_time)
            cpu_workers.append(sorted(w1[w] - w0[w] for w in w1))
    same = all(np.array_equal(p.model.coefficients, s.model.coefficients) and p.check == s.check
               for p, s in zip(par, serial))
    ratios = [a / b for a, b in zip(t_serial, t_par)]
    out.update({"cluster": "LocalCluster 2 processes x 1 thread", "cluster_start_s": round(t_start, 3),
                "serial_s": round(statistics.median(t_serial), 3), "dask_s": round(statistics.median(t_par), 3),
                "speedup": round(statistics.median(ratios), 2), "speedup_runs": [round(r, 2) for r in ratios],
                "speedup_best_of": round(min(t_serial) / min(t_par), 2), "identical_to_serial": same,
                # CPU seconds, which a busy machine inflates far less than wall time: the speed-up to expect
                # when each worker gets a core of its own is serial CPU / the busier worker's CPU.
                "cpu_serial_s": round(statistics.median(cpu_serial), 3),
                "cpu_workers_s": [[round(x, 3) for x in w] for w in cpu_workers],
                "cpu_client_during_cluster_s": [round(x, 3) for x in cpu_client],
                "speedup_if_cores_free": round(statistics.median(cpu_serial) / statistics.median(
                    w[-1] for w in cpu_workers), 2),
                "target_speedup": 1.6})
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--images", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--many-repeat", type=int, default=3, help="alternating serial/cluster runs of the 20 images")
    ap.add_argument("--no-cluster", action="store_true")
    args = ap.parse_args()
    result = {
        "bench": "rpc", "host": platform.node(), "cpus": os.cpu_count(),
        "load_avg_start": os.getloadavg(),
        "single": bench_single(args.repeat),
        "many": bench_many(args.images, not args.no_cluster, args.many_repeat),
        "load_avg_end": os.getloadavg(),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
