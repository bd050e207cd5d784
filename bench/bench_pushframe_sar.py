"""Throughput of the push-frame (LRO WAC) and SAR (LRO Mini-RF) models: vectorised vs one point at a time.

    python bench/bench_pushframe_sar.py [--points 200000] [--loop 2000]

Both cameras come from the real kernel sets in ../shared/data/kernels (one SPICE pass each). The baseline
is the same model called per point in a Python loop (what a CSM-style per-point API costs from Python),
measured in the same run; speed is reported as the ratio. Also the round trip of the vectorised calls.
"""

from __future__ import annotations

import argparse
import os
import resource
import time
from pathlib import Path

import numpy as np

import lunarmap
from lunarmap.orientation.drivers import image_support

KERNELS = Path(os.environ.get("LUNARMAP_SHARED_KERNELS", Path(__file__).resolve().parents[2] / "shared" / "data" / "kernels"))
SETS = {"LRO WAC UV (push frame)": ("lro_wac_uv_wac0000a1c4", "wac0000a1c4.uv.even_isis3.lbl"),
        "LRO Mini-RF (SAR)": ("lro_minirf_03821_16N196_S1", "03821_16N196_S1_isis3.lbl")}


def _rate(fn, n: int) -> tuple[float, object]:
    t0 = time.perf_counter()
    out = fn()
    return n / (time.perf_counter() - t0), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=200_000)
    ap.add_argument("--loop", type=int, default=2_000)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    print(f"load average {os.getloadavg()[0]:.2f}")
    for title, (folder, label) in SETS.items():
        cam = lunarmap.camera_from_isd(image_support(KERNELS / folder / label, KERNELS / folder / f"{folder}.tm"))
        n = args.points
        L, S = rng.uniform(0, cam.n_lines, n), rng.uniform(0, cam.n_samples, n)
        h = rng.uniform(-2000, 2000, n)
        i2g, G = _rate(lambda: cam.image_to_ground(L, S, h), n)
        g2i, (line, sample) = _rate(lambda: cam.ground_to_image(G, within_image=False), n)
        m = args.loop
        i2g_loop, _ = _rate(lambda: [cam.image_to_ground(L[i], S[i], h[i]) for i in range(m)], m)
        g2i_loop, _ = _rate(lambda: [cam.ground_to_image(G[i], within_image=False) for i in range(m)], m)
        back = np.hypot(line - L, sample - S)
        print(f"{title}: image_to_ground {i2g:,.0f} points/s = {i2g / i2g_loop:.0f}x the per-point loop "
              f"({i2g_loop:,.0f}/s); ground_to_image {g2i:,.0f} points/s = {g2i / g2i_loop:.0f}x ({g2i_loop:,.0f}/s); "
              f"round trip median {np.median(back):.1e} px, {np.mean(back > 1e-4):.1%} of points beyond 1e-4 px "
              f"(push frame: the framelet-overlap strips)")
    print(f"peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")


if __name__ == "__main__":
    main()
