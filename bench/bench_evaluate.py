"""All image combinations of the simulated 7-image LROC NAC site, serial vs 2 dask workers (a script).

    python bench/bench_evaluate.py [--rounds 1] [--figures DIR] [--rigorous]

The site is :func:`lunarmap.simulate.lroc_site` with the study's Apollo-11 images (Table 2: seven
NAC images, slews -20..+18 degrees, incidences 43-75 degrees, 1.0-1.05 m pixels), 100 tie, 7
control and 15 check points measured in every image with the simulated NAC matching error as a
function of each image's emission angle (``NAC_MATCHING_ERROR.per_image_emission``), navigation
cameras with 20 m / 50 urad errors. As in the study, each combination is a block adjustment of
cubic RFMs (fitted once per image to the navigation cameras) with affine image corrections
(Eq. 13) and the control points; ``--rigorous`` adjusts the line-scan cameras themselves instead
(navigation observations, degree-1 corrections; about 10x slower).

Prints: the serial and the 2-worker times of all 120 combinations (same results required), the
load average, the progressive selection beside the exhaustive optimum at every k (Table 5), the
best pairs and the power law of the pairs' height error against the convergence (Fig. 3 / 9),
and, with ``--figures``, writes the figures there.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from lunarmap.adjust import NavigationSpec
from lunarmap.evaluate import (NAC_MATCHING_ERROR, best_combinations, compare_with_exhaustive, evaluate_combination,
                               evaluate_combinations, pair_geometry, power_law_fit, progressive_selection,
                               site_network)
from lunarmap.rpc import fit_rpc
from lunarmap.simulate import lroc_site


def _loadavg() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--figures", default=None, help="folder for the figures (PNG)")
    ap.add_argument("--rigorous", action="store_true", help="adjust the rigorous line-scan cameras")
    args = ap.parse_args()

    t0 = time.perf_counter()
    site = lroc_site(sigma_px=NAC_MATCHING_ERROR.per_image_emission, seed=args.seed)
    net = site_network(site)
    print(f"site: {len(site.names)} images, {net.n_points} points ({int(np.sum(net.point_type == 'tie'))} tie, "
          f"{int(np.sum(net.point_type == 'control'))} control, {int(np.sum(net.point_type == 'check'))} check), "
          f"per-image sigma {', '.join(f'{k} {v:.3f}' for k, v in site.image_sigma.items())} px "
          f"({time.perf_counter() - t0:.1f} s)")
    kw: dict = {}
    if args.rigorous:
        sensors = site.nav_cameras
        kw["navigation"] = NavigationSpec(orbit={n: n for n in site.names}, position_sigma=site.nav_sigma["position"],
                                          attitude_sigma=site.nav_sigma["attitude"],
                                          attitude_rate_sigma=site.nav_sigma["attitude_drift"], position_rate_sigma=0.01)
    else:
        t1 = time.perf_counter()
        sensors = {n: fit_rpc(c, (-300.0, 300.0), check=False).model for n, c in site.nav_cameras.items()}
        print(f"RFMs of the 7 navigation cameras: {time.perf_counter() - t1:.1f} s")
    evaluate_combination(site.names[:2], sensors, net, **kw)          # compile / warm up in this process

    from distributed import Client, LocalCluster

    serial, parallel = [], []
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        client.run(evaluate_combination, site.names[:2], sensors, net, **kw)   # warm up every worker
        for r in range(args.rounds):
            print(f"round {r + 1}: load average {_loadavg()}")
            ts = time.perf_counter()
            table = evaluate_combinations(sensors, net, **kw)
            serial.append(time.perf_counter() - ts)
            tp = time.perf_counter()
            table2 = evaluate_combinations(sensors, net, client=client, **kw)
            parallel.append(time.perf_counter() - tp)
            same = np.allclose(table.overall.values, table2.overall.values, rtol=1e-9, equal_nan=True)
            print(f"  {table.sizes['combination']} combinations: serial {serial[-1]:.1f} s, 2 workers "
                  f"{parallel[-1]:.1f} s, speed-up {serial[-1] / parallel[-1]:.2f}x; results identical: {same}")
    print(f"median: serial {np.median(serial):.1f} s, 2 workers {np.median(parallel):.1f} s, speed-up "
          f"{np.median(serial) / np.median(parallel):.2f}x (load average now {_loadavg()})")
    bad = [str(s) for s in table.status.values if s != "ok"]
    print(f"combinations not evaluated: {len(bad)} {bad[:3]}")

    prog = progressive_selection(sensors, net, table=table)
    cmp = compare_with_exhaustive(prog, table)
    print("\nTable 5: progressive selection vs exhaustive optimum (overall check-point RMS, m)")
    print(f"{'k':>2} {'progressive':>22} {'m':>6} {'optimum':>22} {'m':>6} {'runner-up':>22} {'m':>6} {'excess':>7}")
    for k in cmp.k.values:
        r = cmp.sel(k=k)
        print(f"{k:2d} {str(r.progressive.values):>22} {float(r.progressive_overall):6.3f} "
              f"{str(r.optimum.values):>22} {float(r.optimum_overall):6.3f} {str(r.second.values):>22} "
              f"{float(r.second_overall):6.3f} {float(r.excess):7.2%}")
    print(f"largest excess {float(cmp.excess.max()):.2%}; the study's stopping rule stops at k = {prog.attrs['stop_k']}, "
          f"best on the path k = {prog.attrs['best_k']}")
    print("\nTable 4: the progressive path (m)")
    for s in prog.step.values:
        r = prog.sel(step=s)
        print(f"{s:2d} {str(r.combination.values):>22} +{str(r.added.values):<6} along {float(r.along):.3f} cross "
              f"{float(r.cross):.3f} height {float(r.height):.3f} overall {float(r.overall):.3f} "
              f"(predicted {float(r.expected_along):.3f} / {float(r.expected_cross):.3f} / "
              f"{float(r.expected_height):.3f})")

    pairs = pair_geometry(site.true_cameras)
    t2 = table.where(table.k == 2, drop=True)
    conv = pairs.convergence.sel(pair=[c.replace("+", "/") for c in t2.combination.values]).values
    a, b = power_law_fit(conv, t2.height.values)
    a_p, b_p = power_law_fit(conv, t2.expected_height.values)
    print(f"\npairs: height error = {a:.2f} m * convergence^{b:.2f} (predicted sigma: {a_p:.2f} * c^{b_p:.2f}); "
          f"convergence {conv.min():.1f}-{conv.max():.1f} deg")
    best = best_combinations(table, 2)
    print("two best of every size (overall m):",
          "; ".join(f"{c} {float(o):.3f}" for c, o in zip(best.combination.values, best.overall.values)))

    if args.figures:
        from lunarmap.evaluate import (pair_precision, plot_error_vs_convergence, plot_footprints,
                                       plot_pair_quantity, plot_precision_vs_convergence, plot_precision_vs_images)

        out = args.figures
        os.makedirs(out, exist_ok=True)
        plot_error_vs_convergence(table, pairs, path=os.path.join(out, "fig3_pairs_error_vs_convergence.png"))
        plot_precision_vs_convergence(50e3, 99946.0, 0.3, NAC_MATCHING_ERROR,
                                      adjusted=pair_precision(np.arange(5.0, 65.0, 5.0), "linescan"),
                                      path=os.path.join(out, "fig9_eq15.png"))
        plot_pair_quantity(pairs, t2.overall.values, "shadow_tip_distance", "pair overall error (m)",
                           path=os.path.join(out, "fig4_error_vs_shadow_tip.png"))
        plot_pair_quantity(pairs, t2.overall.values, "aspect_ratio_ratio", "pair overall error (m)",
                           path=os.path.join(out, "fig5_error_vs_aspect_ratios.png"))
        plot_precision_vs_images(prog, cmp, path=os.path.join(out, "fig10_progressive.png"))
        plot_footprints(site.true_cameras, points=site.true_xyz, path=os.path.join(out, "footprints.png"))
        print(f"figures written to {out}")


if __name__ == "__main__":
    main()
