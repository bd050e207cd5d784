"""A WAC-like push-frame block through the public API: render, match, adjust (issue 26).

    python bench/wac_block.py [--seed 0]

Four LRO WAC UV-like push-frame images (the real UV filter-1 interior: 4.67 mm focal length, 16-line
framelets summed 4x, 128 samples, its radial distortion), two per orbit on two adjacent polar orbits,
50 km up; the two images of an orbit follow each other with a few framelets in common, so tie points
are matched across the orbits only (rays of one orbit are the same rays: no base). The framelets leave
small gaps, as the WAC's even/odd framelet images do (see ``tests/test_pushframe_block.py``). The truth
cameras render the images of a synthetic DTM and albedo (:func:`lunarmap.simulate.render_image`);
navigation cameras carry position (1 km) and attitude (5 mrad) errors and their rates (50 m, 0.5 mrad
over half an image) as degree-1 push-frame corrections. Tie points come from
:func:`lunarmap.find_tiepoints` (predicted through the navigation cameras), control and check points are
truth points measured in the true cameras (0.2 px), and :func:`lunarmap.build_block` / :func:`lunarmap.solve`
adjust the push-frame cameras with navigation observations of those sigmas. Prints the check-point errors
before and after (and normalised by the posterior sigma) and how far the navigation and the adjusted
cameras image the true points from where the true cameras do.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import lunarmap
from lunarmap.adjust import NavigationSpec, merge_networks, network_from_tiepoints
from lunarmap.simulate import render_image
from lunarmap.simulate.orbits import wac_like_camera
from lunarmap.simulate.terrain import synthetic_scene
from lunarmap.simulate.wac_block import measure_points

FRAMELETS = 60       # 240 image lines per image
DELAY = 1.0          # s between framelets: small gaps between them, as in the WAC's even/odd images


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    t_start = time.perf_counter()
    lat0, lon0 = 10.0, 30.0
    # two adjacent orbits (0.45 deg apart at 10 deg N, ~13 km), two images along each
    truth = {f"orbit{o}_img{k}": wac_like_camera(lon0 + 0.45 * o, lat0, (k - 0.5) * 0.95 * FRAMELETS * DELAY,
                                                  FRAMELETS, DELAY)
             for o in (0, 1) for k in (0, 1)}
    nav, true_params = {}, {}
    for name, cam in truth.items():
        p = np.concatenate([rng.normal(0, 5e-3, 3), rng.normal(0, 1000.0, 3), rng.normal(0, 5e-4, 3),
                            rng.normal(0, 50.0, 3)])
        nav[name] = cam.corrections(degree=1).apply(p)
        true_params[name] = p
    dtm, albedo = synthetic_scene(lon0 + 0.22, lat0, extent=220e3, gsd=400.0, seed=args.seed)
    t = time.perf_counter()
    images = {n: render_image(c, dtm, albedo, supersample=2, noise_sigma=1.0, seed=args.seed + i, sun="eo")
              for i, (n, c) in enumerate(truth.items())}
    t_render = time.perf_counter() - t
    t = time.perf_counter()
    pairs = [(a, b) for a in nav for b in nav if a.startswith("orbit0") and b.startswith("orbit1")]
    ties = lunarmap.find_tiepoints(images, nav, pairs=pairs, height=0.0)
    t_match = time.perf_counter() - t
    # control and check points: truth ground points measured in the true cameras
    g = np.concatenate([truth[n].image_to_ground(rng.uniform(2, 4 * FRAMELETS - 2, 60), rng.uniform(10, 118, 60),
                                                 dtm=dtm, on_miss="nan") for n in ("orbit0_img0", "orbit1_img1")])
    g = g[np.isfinite(g).all(axis=1)]
    seen = np.array([[np.isfinite(c.ground_to_image(x)[0]) for c in truth.values()] for x in g])
    g = g[seen[:, :2].any(axis=1) & seen[:, 2:].any(axis=1)]      # seen from both orbits
    g = g[rng.permutation(g.shape[0])]
    control = measure_points(truth, g[:8], "control", 0.2, rng)
    check = measure_points(truth, g[8:40], "check", 0.2, rng)
    net = merge_networks(network_from_tiepoints(ties), control, check)
    t = time.perf_counter()
    t_half = 0.5 * (FRAMELETS - 1) * DELAY
    spec = NavigationSpec(orbit={n: n.split("_")[0] for n in nav}, position_sigma=1000.0, attitude_sigma=5e-3,
                          position_rate_sigma=50.0 / t_half, attitude_rate_sigma=5e-4 / t_half)
    block = lunarmap.build_block(nav, net, degree=1, navigation=spec)
    result = lunarmap.solve(block)
    t_adjust = time.perf_counter() - t
    before = result.check_points(points=block.problem.points).attrs
    after = result.check_points().attrs
    types = {t: int(np.sum(net.point_type == t)) for t in ("tie", "control", "check")}
    print(f"{len(images)} push-frame images of {images['orbit0_img0'].shape} pixels, {FRAMELETS} framelets each; "
          f"points {types}, {net.measure_point.size} measurements")
    print(f"render {t_render:.1f} s, match {t_match:.1f} s, adjust {t_adjust:.1f} s, "
          f"total {time.perf_counter() - t_start:.1f} s; converged {result.converged}, sigma0 {result.sigma0:.3f}")
    print("check points RMS east/north/up (m): before", np.round(before["rms_m"], 1), "after",
          np.round(after["rms_m"], 1), f"; normalised RMS after {after['normalized_rms']:.2f}")
    adjusted = result.adjusted_sensors()

    def pixel_rms(cams: dict) -> float:
        d = [np.column_stack(cams[n].ground_to_image(g, within_image=False))
             - np.column_stack(truth[n].ground_to_image(g, within_image=False)) for n in truth]
        return float(np.sqrt(np.nanmean(np.concatenate(d) ** 2)))

    print(f"true points imaged by the navigation cameras {pixel_rms(nav):.3f} px RMS from the true cameras' "
          f"pixels, by the adjusted cameras {pixel_rms(adjusted):.3f} px")


if __name__ == "__main__":
    main()
