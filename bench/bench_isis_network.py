"""ISIS control network read/write speed (a script, not a test): 100,000 points, ~1,000,000 measures.

Prints one JSON line: write and read times of the binary network (version 5, what ISIS writes)
for a random network with every field in use (tests/isisnet_help.py), medians of ``--repeat``
runs after one warm-up run (the warm-up includes numba's compilation of the wire codec, or
its loading from the on-disk cache; reported apart). The baseline measured in the same run is
the time to write and read the same network's core variables as netCDF (the project's own
control-network format), so the ratios say what ISIS's format costs next to ours.

    python bench/bench_isis_network.py [--points 100000] [--per-point 10] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from isisnet_help import random_network  # noqa: E402
from lunarmap.io.isis_network import read_isis_network, write_isis_network  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--points", type=int, default=100_000)
    ap.add_argument("--per-point", type=int, default=10)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    ds = random_network(args.points, per_point=args.per_point, n_img=2000, seed=2)
    images = list(ds["image_id"].values)
    core = ds[["point_id", "point_type", "xyz", "xyz_cov", "measure_point", "measure_image", "line", "sample",
               "sigma_line", "sigma_sample", "image_id"]]
    with tempfile.TemporaryDirectory() as tmp:
        path, nc = Path(tmp) / "net.net", Path(tmp) / "net.nc"
        t0 = time.perf_counter()
        write_isis_network(ds, path)
        t1 = time.perf_counter()
        read_isis_network(path, images=images)
        warm = {"write_s": round(t1 - t0, 3), "read_s": round(time.perf_counter() - t1, 3)}
        w, r, nw, nr = [], [], [], []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            write_isis_network(ds, path)
            t1 = time.perf_counter()
            back = read_isis_network(path, images=images)
            t2 = time.perf_counter()
            core.to_netcdf(nc, engine="netcdf4")
            t3 = time.perf_counter()
            import xarray as xr

            with xr.open_dataset(nc, engine="netcdf4") as d:
                d.load()
            t4 = time.perf_counter()
            w.append(t1 - t0)
            r.append(t2 - t1)
            nw.append(t3 - t2)
            nr.append(t4 - t3)
        size = path.stat().st_size
    med = statistics.median
    print(json.dumps({
        "points": int(ds.sizes["point"]), "measures": int(ds.sizes["measure"]), "file_mb": round(size / 1e6, 1),
        "write_s": round(med(w), 3), "read_s": round(med(r), 3), "first_run": warm,
        "netcdf_core_write_s": round(med(nw), 3), "netcdf_core_read_s": round(med(nr), 3),
        "write_vs_netcdf": round(med(w) / med(nw), 2), "read_vs_netcdf": round(med(r) / med(nr), 2),
        "measures_read": int(back.sizes["measure"]), "load_average": os.getloadavg()[0],
    }))


if __name__ == "__main__":
    main()
