#!/usr/bin/env python3
"""Adjustment time of a frame block through the rigorous camera models vs the same block in the BAL model.

The block: :func:`lunarmap.simulate.frame_block` (Clementine-like frame cameras on parallel orbits, the
DLR paper's set-up), by default 20 orbits x 25 images = 500 images and 20,000 points, 20 control points
(1 m), navigation observations with per-orbit offsets and drifts. Three problems of the same block, solved
in the same run, interleaved over rounds (medians reported):

* ``rigorous``: :class:`lunarmap.adjust.SensorImageModel` over :class:`~lunarmap.camera.FrameCamera`\\ s with
  the ``radial`` OD_K distortion (measurements made by the distorted true cameras);
* ``rigorous-nodist``: the same cameras without distortion;
* ``bal``: the BAL collinearity :class:`~lunarmap.adjust.FrameModel` (compiled kernel, no distortion) of the
  distortion-free cameras, converted exactly (BAL axes: x = sample, y = -line, z = -boresight).

Same noise draws, same stochastic model (image sigma, control priors, navigation observations with the
same sigmas), same solver options; the table gives solve seconds, iterations, seconds per iteration and
the ratios to ``bal``.

Usage::

    python bench/bench_rigorous_frame.py [--orbits 20 --per-orbit 25 --points 20000 --rounds 3]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import numpy as np

from lunarmap.adjust import (BALData, BundleProblem, ImageObservations, NavigationObservations, PointPriors,
                             SensorImageModel, SolverOptions, bal_to_problem, intersect_points, solve)
from lunarmap.orientation.rotation import matrix_to_rotvec
from lunarmap.simulate import frame_block
from lunarmap.simulate.blocks import clementine_interior

HERE = os.path.dirname(os.path.abspath(__file__))


def _nav(sb, p, observed):
    n = len(sb.nav_cameras)
    obs = np.zeros((n, p))
    obs[:, :observed.shape[1]] = observed
    return NavigationObservations(obs, np.broadcast_to(sb.nav_sigma, (n, p)), sb.orbit, sb.times,
                                  offset="observed", drift="observed", offset_sigma=sb.offset_sigma,
                                  drift_sigma=sb.drift_sigma)


def rigorous_problem(sb):
    m = sb.measurements
    model = SensorImageModel(sb.nav_cameras)
    x0 = intersect_points(model, model.initial_params(), m.cam_idx, m.pt_idx, m.xy, m.sigma,
                          n_pt=sb.true_points.shape[0]).xyz
    pri = PointPriors(sb.control, sb.control_xyz, np.full((sb.control.size, 3), sb.control_sigma))
    return BundleProblem(model, model.initial_params(), x0, ImageObservations(m.cam_idx, m.pt_idx, m.xy, m.sigma),
                         pri, terms=[_nav(sb, 6, np.zeros((len(sb.nav_cameras), 6)))])


def bal_problem(sb, x0):
    m = sb.measurements
    cams, centres = [], []
    for c in sb.nav_cameras:
        R = np.diag([1.0, -1.0, -1.0]) @ c.eo.rotation_at(c.time).T
        C = c.eo.position_at(c.time)
        io = c.interior
        cams.append(np.concatenate([matrix_to_rotvec(R), -R @ C, [io.focal_length / io.pixel_pitch, 0.0, 0.0]]))
        centres.append(C)
    io = sb.nav_cameras[0].interior
    xy = np.column_stack([m.xy[:, 1] - io.detector_center_sample, io.detector_center_line - m.xy[:, 0]])
    pb = bal_to_problem(BALData(np.array(cams), x0, m.cam_idx, m.pt_idx, xy), control=np.zeros(0, np.int64),
                        sigma_px=m.sigma)
    pri = PointPriors(sb.control, sb.control_xyz, np.full((sb.control.size, 3), sb.control_sigma))
    observed = np.column_stack([np.zeros((len(centres), 3)), np.array(centres)])
    return BundleProblem(pb.model, pb.cam_params, pb.points, pb.obs, pri, terms=[_nav(sb, 6, observed)])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--orbits", type=int, default=20)
    ap.add_argument("--per-orbit", type=int, default=25)
    ap.add_argument("--points", type=int, default=20000)
    ap.add_argument("--control", type=int, default=20)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--seed", type=int, default=3)
    args = ap.parse_args()
    kw = dict(orbits=args.orbits, per_orbit=args.per_orbit, points=args.points, n_control=args.control,
              control_sigma=1.0, seed=args.seed)
    t = time.perf_counter()
    dist = frame_block(**kw)
    plain = frame_block(interior=clementine_interior(odk=None), **kw)
    print(f"blocks simulated in {time.perf_counter() - t:.1f} s: {len(dist.nav_cameras)} images, "
          f"{dist.true_points.shape[0]} points, {dist.measurements.cam_idx.size} observations (distorted), "
          f"{plain.measurements.cam_idx.size} (undistorted)")
    problems = {"rigorous": rigorous_problem(dist), "rigorous-nodist": rigorous_problem(plain)}
    problems["bal"] = bal_problem(plain, problems["rigorous-nodist"].points)
    opts = SolverOptions(ftol=1e-8)
    for pb in problems.values():   # compile and warm up every path once
        solve(pb, SolverOptions(max_iterations=1))
    runs: dict[str, list] = {k: [] for k in problems}
    for r in range(args.rounds):
        for name, pb in problems.items():
            res = solve(pb, opts)
            runs[name].append((res.solve_seconds, res.iterations, res.sigma0, res.converged))
    rows = {}
    for name, rs in runs.items():
        sec = statistics.median(x[0] for x in rs)
        it = rs[0][1]
        rows[name] = {"solve_s": round(sec, 3), "iterations": it, "s_per_iteration": round(sec / it, 4),
                      "sigma0": round(rs[0][2], 4), "converged": bool(rs[0][3])}
    for name in rows:
        rows[name]["ratio_to_bal"] = round(rows[name]["solve_s"] / rows["bal"]["solve_s"], 3)
        rows[name]["per_iteration_ratio_to_bal"] = round(rows[name]["s_per_iteration"]
                                                         / rows["bal"]["s_per_iteration"], 3)
    print(f"{'problem':<16} {'solve s':>8} {'iter':>5} {'s/iter':>8} {'sigma0':>7} {'x BAL':>6} {'x BAL/iter':>10}")
    for name, r in rows.items():
        print(f"{name:<16} {r['solve_s']:8.3f} {r['iterations']:5d} {r['s_per_iteration']:8.4f} {r['sigma0']:7.4f} "
              f"{r['ratio_to_bal']:6.2f} {r['per_iteration_ratio_to_bal']:10.2f}")
    os.makedirs(os.path.join(HERE, "results"), exist_ok=True)
    with open(os.path.join(HERE, "results", "rigorous_frame.jsonl"), "a") as fh:
        fh.write(json.dumps({"date": time.strftime("%Y-%m-%d %H:%M"), "machine": platform.node(),
                             "args": vars(args), "rows": rows}) + "\n")


if __name__ == "__main__":
    main()
