#!/usr/bin/env python3
"""Quality control of the adjustment (issue 11): the DLR paper's experiments and the large-block timings.

Parts (``--part``, several allowed):

* ``blunders`` -- the paper's Tables 2-3 over ``--draws`` random draws of the gross errors
  (``simulate.dlr``: 10 image errors of 500-3000 px, 10 of 10-40 px, a 2 km position, a 0.2 degree
  attitude and a 2 km control error): what Sequent -> Baarda, Baarda alone, Robust (Danish) alone
  and Sequent -> Robust find, and what good observations they take;
* ``variance`` -- Tables 4-5: variance components of examples I and II from starting values x100,
  x0.01 and mixed, estimated sigma / simulated sigma per group (and / the realised noise RMS);
* ``offsets`` -- Tables 6-7: the paper's offset/drift examples 1 and 2 over draws, every round;
* ``scale`` -- posterior precision and redundancy numbers (supernodal selected inversion) vs the
  solve on the shared generator's blocks (500, 2,000, 4,000 images), the column-solve method it
  replaces (``--old``), w-tests of every observation, and a full QC run (robust + data snooping)
  with injected gross errors vs one plain solve, all ratios within one run;
* ``qc-cost`` -- that full QC run vs plain solves of the same dirty block in CPU time, alternating in one
  process (``--repeat`` QC runs, each between two plain solves);
* ``mismatches`` -- the synthetic block mission (rendered images, tie points from the matcher,
  check points measured at 0.3 px): check-point errors of the clean adjustment vs quality-controlled
  adjustments with 20 % and 50 % of the tie-point observations displaced by 4-40 px;
* ``clean`` -- the blunder blocks without their errors: what ``--steps`` removes there (type-I rate);
* ``misses`` -- for the image errors a run of ``--steps`` leaves in the block (``--draw-list``): the
  leave-one-out fits of the error's point, to tell an undecidable error from a miss of the method.

Every line of output is also a JSON record (``--json FILE``). The machine is shared: report the load
average with any timing (printed).

    python bench/bench_qc.py --part blunders variance offsets --draws 20
    python bench/bench_qc.py --part scale --sizes medium large1m xl4000 [--old]
    python bench/bench_qc.py --part qc-cost --sizes large1m --repeat 1
    python bench/bench_qc.py --part mismatches
    python bench/bench_qc.py --part misses --draw-list 8 13 --steps sequent baarda
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))
SHARED = os.environ.get("LUNARMAP_SHARED_BENCH", os.path.join(HERE, "..", "..", "shared", "bench"))
DATA = os.path.join(HERE, "data")
SIZES = {"medium": ["--preset", "medium"], "large1m": ["--preset", "large1m"],
         "xl4000": ["--strips", "40", "--per-strip", "100", "--points", "400000"],
         "large1000": ["--strips", "20", "--per-strip", "50", "--points", "140000"]}

RECORDS: list[dict] = []


def emit(kind: str, **kw) -> None:
    rec = {"part": kind, **kw}
    RECORDS.append(rec)
    print(json.dumps(rec, default=lambda x: x.item() if hasattr(x, "item") else str(x)), flush=True)


def load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


# --- Tables 2-3 --------------------------------------------------------------------------------------

def dlr_qc(sim, steps):
    """Quality control of a DLR simulation with the settings of every blunder experiment here."""
    from qchelp import dlr_problem

    from lunarmap.adjust import SolverOptions
    from lunarmap.adjust.qc import QCOptions, quality_control

    return quality_control(dlr_problem(sim), steps, image_group=sim.block.camera,
                           options=QCOptions(solver=SolverOptions(ftol=1e-8)))


def part_blunders(draws: int) -> None:
    from qchelp import score

    from lunarmap.simulate import dlr_block, inject_blunders

    strategies = {"sequent->baarda": ("sequent", "baarda"), "baarda": ("baarda",), "robust": ("robust",),
                  "sequent->robust": ("sequent", "robust"), "sequent->robust->baarda": ("sequent", "robust", "baarda")}
    table: dict[str, list[dict]] = {k: [] for k in strategies}
    for d in range(draws):
        sim = inject_blunders(dlr_block(seed=d, example="blunders"), seed=1000 + d)
        for name, steps in strategies.items():
            t0 = time.perf_counter()
            qc = dlr_qc(sim, steps)
            s = score(sim, qc)
            s["seconds"] = round(time.perf_counter() - t0, 2)
            s["sigma0"] = round(qc.result.sigma0, 3)
            table[name].append(s)
            emit("blunders", draw=d, strategy=name, **s)
    for name, rows in table.items():
        def dist(key, rows=rows):
            v = np.array([r[key] for r in rows], float)
            return f"{v.min():.0f}/{np.median(v):.0f}/{v.max():.0f}"
        emit("blunders-summary", strategy=name, draws=len(rows),
             large_min_med_max=dist("large"), small_min_med_max=dist("small"),
             all_23=int(sum(r["found"] == 23 for r in rows)),
             position=int(sum(bool(r["position"]) for r in rows)), position_exact=int(sum(bool(r["position_exact"])
                                                                                      for r in rows)),
             attitude=int(sum(bool(r["attitude"]) for r in rows)), attitude_exact=int(sum(bool(r["attitude_exact"])
                                                                                      for r in rows)),
             control=int(sum(bool(r["control"]) for r in rows)),
             false_images_min_med_max=dist("false_images"), false_navigation_min_med_max=dist("false_navigation"),
             false_control_min_med_max=dist("false_control"),
             withdrawn_good_min_med_max=dist("withdrawn_good"),
             draws_with_a_point_withdrawn=int(sum(r["withdrawn_good"] > 0 for r in rows)),
             no_false=int(sum(r["false_images"] + r["false_navigation"] + r["false_control"] == 0 for r in rows)),
             median_seconds=float(np.median([r["seconds"] for r in rows])), load=load())


# --- Tables 4-5 --------------------------------------------------------------------------------------

def part_misses(draws: list[int], steps: tuple) -> None:
    """For every image error a run of ``steps`` leaves in the block: the leave-one-out fits of its point's rays
    (each ray left out in turn, the point intersected from the others through the adjusted images; RMS of the
    others' whitened residuals: the snooping's own check of stripped points). An error whose leave-out is not
    clearly the best one cannot be told from a good ray by the data."""
    from qchelp import score

    from lunarmap.adjust.qc.snooping import _point_fits
    from lunarmap.simulate import dlr_block, inject_blunders

    for d in draws:
        sim = inject_blunders(dlr_block(seed=d, example="blunders"), seed=1000 + d)
        qc = dlr_qc(sim, steps)
        out = set(qc.removed_image_observations.tolist())
        o = qc.ledger.base.obs
        for i, g in zip(sim.blunders.image_obs, sim.blunders.image_group):
            if int(i) in out:
                continue
            rays = np.flatnonzero(o.pt_idx == o.pt_idx[i])
            (rms, _, _), = _point_fits(qc.ledger, [int(o.pt_idx[i])], [rays])
            emit("misses", draw=d, strategy="->".join(steps), observation=int(i), size="large" if g == 1 else "small",
                 point=int(o.pt_idx[i]), rays=rays.tolist(), removed_instead=[int(k) for k in rays if int(k) in out],
                 leave_one_out_rms=np.round(rms, 2).tolist(), score=score(sim, qc))


def part_clean(draws: int, steps: tuple) -> None:
    """The blunder blocks without their errors: what ``steps`` removes or down-weights there (the type-I rate
    of the tests at their limit)."""
    from lunarmap.simulate import dlr_block

    empty = 0
    for d in range(draws):
        qc = dlr_qc(dlr_block(seed=d, example="blunders"), steps)
        acted = [dict(kind=x.kind, index=int(x.index), action=x.action, value=round(float(x.value), 3))
                 for x in qc.report.decisions if x.action in ("removed", "downweighted", "flagged", "withdrawn")]
        empty += not acted
        emit("clean", draw=d, strategy="->".join(steps), acted=acted)
    emit("clean-summary", strategy="->".join(steps), draws=draws, nothing_removed=empty)


def part_variance(draws: int) -> None:
    from qchelp import dlr_problem

    from lunarmap.adjust import SolverOptions
    from lunarmap.adjust.variance import estimate_variance_components, observation_groups
    from lunarmap.simulate import dlr_block

    starts = {"x100": 100.0, "x0.01": 0.01, "mixed": (100.0, 0.01, 0.01, 100.0)}
    for ex in ("I", "II"):
        rows = []
        for d in range(draws):
            sim = dlr_block(seed=d, example=ex)
            sb = sim.block
            e = sb.true_params / sim.nav_sigma
            realised = {"control": np.sqrt(np.mean(((sb.control_xyz - sb.true_points[sb.control]) /
                                                    sim.control_sigma) ** 2))}
            for o in (0, 1):
                m = sb.orbit == o
                realised[f"navigation attitude orbit {o}"] = np.sqrt(np.mean(e[m, :3] ** 2))
                realised[f"navigation position orbit {o}"] = np.sqrt(np.mean(e[m, 3:] ** 2))
            ests = {}
            for sname, start in starts.items():
                t0 = time.perf_counter()
                pb = dlr_problem(sim, start)
                groups = observation_groups(pb, image_group=sb.camera)
                vc = estimate_variance_components(pb, groups, SolverOptions(ftol=1e-10), rounds=150, on_weak="freeze")
                f = np.broadcast_to(np.asarray(start, float), (4,))
                of = {"image": f[0], "control": f[3], "position": f[1], "attitude": f[2]}
                est = np.array([s * of[next(k for k in of if k in n)] for n, s in zip(vc.names, vc.scale)])
                ests[sname] = est
                emit("variance", example=ex, draw=d, start=sname, names=vc.names, estimate=np.round(est, 4).tolist(),
                     sigma=np.round(vc.scale_sigma * est / vc.scale, 4).tolist(),
                     sigma_joint=np.round(vc.scale_sigma_joint * est / vc.scale, 4).tolist(),
                     correlation_pos_att=[round(float(vc.correlation[vc.names.index(f"navigation attitude orbit {o}"),
                                                                     vc.names.index(f"navigation position orbit {o}")]), 3)
                                          for o in (0, 1)],
                     realised=[round(float(realised.get(n, np.nan)), 4) for n in vc.names],
                     estimated=vc.estimated.tolist(), redundancy=np.round(vc.redundancy, 1).tolist(),
                     rounds=len(vc.history), converged=vc.converged, seconds=round(time.perf_counter() - t0, 2))
                rows.append((vc.names, est, vc.estimated, [realised.get(n, np.nan) for n in vc.names],
                             vc.scale_sigma_joint * est / vc.scale))
            spread = max(np.max(np.abs(ests[a] - ests["x100"]) / ests["x100"]) for a in ests)
            emit("variance-starts", example=ex, draw=d, max_relative_difference_between_starts=round(float(spread), 5))
        names = rows[0][0]
        E = np.array([r[1] for r in rows])
        M = np.array([r[2] for r in rows])
        R = np.array([r[3] for r in rows], float)
        S = np.array([r[4] for r in rows], float)
        for i, n in enumerate(names):
            ok = M[:, i]
            emit("variance-summary", example=ex, group=n, runs=int(len(E)), estimated=int(ok.sum()),
                 within_10pct_of_simulated=int(np.sum(ok & (np.abs(E[:, i] - 1) <= 0.1))),
                 within_10pct_of_realised=int(np.sum(ok & (np.abs(E[:, i] / R[:, i] - 1) <= 0.1))) if n in
                 (rows[0][0][2:]) else None,
                 # every estimate, frozen ones too, against its joint sigma (the trade-off with other groups)
                 within_2_joint_sigma=int(np.sum(np.abs(E[:, i] - 1) <= 2 * S[:, i])),
                 median_joint_sigma=round(float(np.nanmedian(S[:, i])), 4),
                 median_estimate=round(float(np.median(E[ok, i])), 4) if ok.any() else None,
                 rms_relative_error=round(float(np.sqrt(np.mean((E[ok, i] - 1) ** 2))), 4) if ok.any() else None)


# --- Tables 6-7 --------------------------------------------------------------------------------------

def part_offsets(draws: int) -> None:
    from qchelp import dlr_problem

    from lunarmap.adjust import SolverOptions
    from lunarmap.adjust.qc import QCOptions, quality_control
    from lunarmap.simulate import dlr_block
    from lunarmap.simulate.dlr import OFFSET_EXAMPLES, PAPER_AXES

    names = ["w_x", "w_y", "w_z", "c_x", "c_y", "c_z"]
    for example in (1, 2):
        ok_all = 0
        for d in range(draws):
            sim = dlr_block(seed=d, example="offsets", offsets=example)
            t0 = time.perf_counter()
            qc = quality_control(dlr_problem(sim), ("offsets",), options=QCOptions(solver=SolverOptions(ftol=1e-10)))
            truth = {(o, PAPER_AXES[a]): (c, dd) for o, a, c, dd in OFFSET_EXAMPLES[example]}
            want = {(o, PAPER_AXES[a], "offset") for o, a, c, dd in OFFSET_EXAMPLES[example]} | \
                {(o, PAPER_AXES[a], "drift") for o, a, c, dd in OFFSET_EXAMPLES[example] if dd}
            rounds = {}
            good = True
            found = set()
            for r in qc.report.offsets:
                rows = []
                for i in range(r.sizes.get("row", 0)):
                    o, j, kind = int(r.orbit[i]), names.index(str(r.param.values[i])), str(r.kind.values[i])
                    unit = np.degrees(1.0) if j < 3 else 1.0
                    v, s = float(r.value[i]) * unit, float(r.sigma[i]) * unit
                    t = truth.get((o, j), (0.0, 0.0))[0 if kind == "offset" else 1]
                    rows.append(f"o{o} {names[j]} {kind} {v:.4g}+-{s:.3g} (true {t:g}){' *' if r.significant[i] else ''}")
                    if r.attrs["round"] == "results":
                        found.add((o, j, kind))
                        good &= (t != 0.0) and abs(v - t) < 2 * s
                rounds[r.attrs["round"]] = rows
            good &= found == want
            ok_all += int(good)
            emit("offsets", example=example, draw=d, within_2sigma_no_false=good,
                 seconds=round(time.perf_counter() - t0, 2), **{k.replace(" ", "_"): v for k, v in rounds.items()})
        emit("offsets-summary", example=example, draws=draws, within_2sigma_no_false=ok_all)


# --- large blocks --------------------------------------------------------------------------------------

def ensure_data(size: str) -> str:
    bal = os.path.join(DATA, f"{size}.bal.txt")
    if not os.path.exists(bal):
        os.makedirs(DATA, exist_ok=True)
        subprocess.run([sys.executable, os.path.join(SHARED, "make_block.py"), *SIZES[size], "--out", bal], check=True)
    return bal


def part_scale_one(size: str, old: bool, qc_run: bool) -> None:
    """One block in this process: solve, precision + redundancy, w-tests, (old method), (QC run)."""
    from lunarmap.adjust import SolverOptions, bal_to_problem, read_bal, solve
    from lunarmap.adjust.precision import posterior_precision
    from lunarmap.adjust.qc import Ledger, QCOptions, quality_control, w_tests

    data = read_bal(ensure_data(size))
    pb = bal_to_problem(data, sigma_px=0.3)
    t0 = time.perf_counter()
    res = solve(pb, SolverOptions())
    t_solve = time.perf_counter() - t0
    t0 = time.perf_counter()
    pr = posterior_precision(res, redundancy=True)
    res._precision = pr
    t_prec = time.perf_counter() - t0
    led = Ledger(pb)
    led.result = res
    t0 = time.perf_counter()
    t = w_tests(led)
    t_w = time.perf_counter() - t0
    n_tests = int(np.isfinite(t["image"]).sum())
    rec = dict(size=size, images=pb.n_images, points=pb.n_points, observations=pb.obs.n, solve_s=round(t_solve, 2),
               iterations=res.iterations, precision_s=round(t_prec, 2), precision_over_solve=round(t_prec / t_solve, 3),
               precision_method=pr.method, wtests_s=round(t_w, 2), tests=n_tests,
               redundancy_sum=round(float(np.nansum(pr.redundancy_numbers)), 1), redundancy=res.redundancy,
               max_abs_w=round(float(np.nanmax(np.abs(t["image"]))), 2), load=load())
    if old:
        t0 = time.perf_counter()
        posterior_precision(res, redundancy=True, inverse_method="chunks")
        rec["old_precision_s"] = round(time.perf_counter() - t0, 2)
        rec["old_precision_over_solve"] = round(rec["old_precision_s"] / t_solve, 3)
    if qc_run:
        # 0.1 % of the observations with gross errors of 5-50 pixels (about 1,000 at 2,000 images)
        rng = np.random.default_rng(7)
        bad = rng.choice(pb.obs.n, pb.obs.n // 1000, replace=False)
        ang = rng.uniform(0, 2 * np.pi, bad.size)
        xy = pb.obs.xy.copy()
        xy[bad] += rng.uniform(5, 50, bad.size)[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
        dirty = bal_to_problem(read_bal(ensure_data(size)), sigma_px=0.3)
        dirty.obs.xy = xy
        t0 = time.perf_counter()
        plain = solve(dirty, SolverOptions())
        t_plain = time.perf_counter() - t0
        t0 = time.perf_counter()
        qc = quality_control(dirty, ("robust", "baarda"), options=QCOptions(
            units_per_km=1.0, baarda=dict(per_round="point", limit=5.0)))
        t_qc = time.perf_counter() - t0
        out = set(qc.removed_image_observations.tolist())
        rec.update(qc_blunders=int(bad.size), qc_found=int(len(out & set(bad.tolist()))),
                   qc_false=int(len(out - set(bad.tolist()))), qc_s=round(t_qc, 2), plain_dirty_solve_s=round(t_plain, 2),
                   qc_over_plain_solve=round(t_qc / t_plain, 2), qc_over_clean_solve=round(t_qc / t_solve, 2),
                   qc_baarda_rounds=qc.report.summary.get("baarda_rounds"), qc_sigma0=round(qc.result.sigma0, 4),
                   plain_sigma0=round(plain.sigma0, 3),
                   # of the good ones out: withdrawn with points whose error no ray could be singled out for
                   qc_withdrawn_good=int(len({d.index for d in qc.report.decisions if d.kind == "image"
                                              and d.action == "withdrawn"} - set(bad.tolist()))),
                   qc_points_withdrawn=int(sum(d.kind == "point" and d.action == "withdrawn"
                                               for d in qc.report.decisions)))
    emit("scale", **rec)


def part_scale(sizes: list[str], old: bool, qc_sizes: list[str]) -> None:
    for size in sizes:
        ensure_data(size)
        # one process per block: memory, and no JIT or cache effects across sizes
        cmd = [sys.executable, __file__, "--part", "scale-one", "--sizes", size] + (["--old"] if old else []) + \
            (["--qc"] if size in qc_sizes else [])
        subprocess.run(cmd, check=True)


def part_qc_cost(size: str, repeat: int, bal: str | None = None) -> None:
    """Full QC (robust + Baarda) vs a plain solve of the same dirty block, CPU time, runs alternating in one
    process (plain, QC, plain, QC, ..., plain): each QC run is compared with the mean of the plain solves
    either side of it, so a load that changes during the measurement moves both alike. CPU time of the
    process (every thread: BLAS and the solver's), not wall time: the machine is shared at nice 19."""
    from lunarmap.adjust import SolverOptions, bal_to_problem, read_bal, solve
    from lunarmap.adjust.qc import QCOptions, quality_control

    data = read_bal(bal or ensure_data(size))
    pb = bal_to_problem(data, sigma_px=0.3)
    # the errors of part scale-one: 0.1 % of the observations displaced by 5-50 pixels
    rng = np.random.default_rng(7)
    bad = rng.choice(pb.obs.n, pb.obs.n // 1000, replace=False)
    ang = rng.uniform(0, 2 * np.pi, bad.size)
    xy = pb.obs.xy.copy()
    xy[bad] += rng.uniform(5, 50, bad.size)[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
    base = dict(size=size, images=pb.n_images, points=pb.n_points, observations=pb.obs.n, blunders=int(bad.size))

    def dirty():
        d = bal_to_problem(data, sigma_px=0.3)
        d.obs.xy = xy.copy()
        return d

    def plain_run(k: int) -> float:
        d = dirty()
        c0, w0 = time.process_time(), time.perf_counter()
        r = solve(d, SolverOptions())
        c, w = time.process_time() - c0, time.perf_counter() - w0
        emit("qc-cost", run="plain", k=k, cpu_s=round(c, 2), wall_s=round(w, 2), iterations=r.iterations,
             sigma0=round(r.sigma0, 4), load=load(), **base)
        return c

    def qc_run(k: int) -> float:
        d = dirty()
        c0, w0 = time.process_time(), time.perf_counter()
        qc = quality_control(d, ("robust", "baarda"), options=QCOptions(
            units_per_km=1.0, baarda=dict(per_round="point", limit=5.0)))
        c, w = time.process_time() - c0, time.perf_counter() - w0
        out = set(qc.removed_image_observations.tolist())
        emit("qc-cost", run="qc", k=k, cpu_s=round(c, 2), wall_s=round(w, 2), found=len(out & set(bad.tolist())),
             false=len(out - set(bad.tolist())), baarda_rounds=qc.report.summary.get("baarda_rounds"),
             sigma0=round(qc.result.sigma0, 4), clean=qc.report.clean, load=load(), **base)
        return c

    plain = [plain_run(0)]
    ratios = []
    for k in range(repeat):
        q = qc_run(k)
        plain.append(plain_run(k + 1))
        ratios.append(q / (0.5 * (plain[-2] + plain[-1])))
    emit("qc-cost-summary", qc_over_plain_cpu=[round(r, 3) for r in ratios],
         median=round(float(np.median(ratios)), 3), plain_cpu_s=[round(p, 2) for p in plain], **base)


# --- tie points from the matcher with mismatches --------------------------------------------------------

MISMATCH_VARIANTS = {
    "paper": [(("robust", "baarda"), "paper"), (("sequent", "robust", "baarda"), "paper")],
    "run": [(("baarda",), "run"), (("robust", "baarda"), "run")],
}


def part_mismatches(seed: int, fractions: list[float], variants=MISMATCH_VARIANTS["paper"]) -> None:
    import tempfile
    import warnings

    import lunarmap
    from lunarmap.adjust import NavigationSpec, SolverOptions, merge_networks, network_from_tiepoints
    from lunarmap.adjust.qc import QCOptions, block_result, quality_control
    from lunarmap.matching import DetectParams, MatchParams, TiePointParams
    from lunarmap.simulate import block_cameras, block_check_points, render_block
    from lunarmap.synthetic import write_block_mission
    from lunarmap.workflows.example import _points_network as _network_of

    tmp = tempfile.mkdtemp(prefix="qc_mismatch_")
    t0 = time.perf_counter()
    bm = write_block_mission(os.path.join(tmp, "mission"), seed=seed)
    names = list(bm.image_names)
    man = bm.manifest
    rendered = render_block(bm, supersample=2)
    cams = {n: lunarmap.load_camera(bm.label(n), bm.navigation_metakernel) for n in names}
    params = TiePointParams(detect=DetectParams(cell=48), match=MatchParams(search=128.0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ties = lunarmap.find_tiepoints(rendered.images, cams, params=params, scheduler="threads")
    truth = block_cameras(bm, "truth")
    rng = np.random.default_rng(seed + 1)
    control = block_check_points(bm, 6, sigma_px=0.3, seed=seed + 11, cameras=truth)
    check = block_check_points(bm, 20, sigma_px=0.3, seed=seed + 12, cameras=truth)
    ctl_net = _network_of(control, "control", "C", 0.5, rng)
    chk_net = _network_of(check, "check", "K")
    orbit = {n: f"{man['images'][n]['orbit']}-{man['images'][n]['kind']}" for n in names}
    spec = NavigationSpec(orbit=orbit, position_sigma=0.5, attitude_sigma=1e-6, position_rate_sigma=1.0,
                          attitude_rate_sigma=1e-6, offset="observed", drift="observed",
                          offset_sigma=[50e-6] * 3 + [50.0] * 3, drift_sigma=[1e-6] * 3 + [1.0] * 3)
    emit("mismatches-setup", tie_observations=int(ties.sizes["observation"]), seconds=round(time.perf_counter() - t0, 1),
         load=load())

    def run(frac: float, qc_steps, variant: str = "paper"):
        tp = ties.copy(deep=True)
        n = tp.sizes["observation"]
        r = np.random.default_rng(seed + 100 + int(frac * 100))
        bad = np.flatnonzero(r.random(n) < frac)
        ang = r.uniform(0, 2 * np.pi, bad.size)
        mag = r.uniform(4.0, 40.0, bad.size)
        line = tp["line"].values.copy()
        sample = tp["sample"].values.copy()
        line[bad] += mag * np.cos(ang)
        sample[bad] += mag * np.sin(ang)
        tp["line"].values[:] = line
        tp["sample"].values[:] = sample
        net = merge_networks(network_from_tiepoints(tp), ctl_net, chk_net)
        block = lunarmap.build_block(cams, net, degree=1, navigation=spec)
        tie = block.network.point_type[block.problem.obs.pt_idx] == "tie"
        t1 = time.perf_counter()
        if qc_steps:
            if variant == "run":      # what `lunarmap run` does with [adjust.qc] (its defaults)
                opts = QCOptions(solver=SolverOptions(ftol=1e-10), sequent_limit_km=0.05,
                                 robust=dict(scale="mad", observations=tie),
                                 baarda=dict(per_round="point", limit=4.0, sigma0="robust"))
            else:
                opts = QCOptions(solver=SolverOptions(ftol=1e-10), sequent_limit_km=0.02,
                                 baarda=dict(per_round="point", limit=4.0))
            qc = quality_control(block.problem, qc_steps, image_group=None, options=opts)
            result = block_result(qc, block)
            removed = set(qc.removed_image_observations.tolist())
            tie_idx = np.flatnonzero(tie)
            bad_obs = set(tie_idx[np.isin(np.arange(tie.sum()), bad)].tolist())
            found, false = len(removed & bad_obs), len(removed - bad_obs)
        else:
            result = lunarmap.solve(block, SolverOptions(ftol=1e-10))
            found = false = 0
        ck = result.check_points()
        return dict(fraction=frac, steps=list(qc_steps), variant=variant, mismatched=int(bad.size), found=found, false=false,
                    converged=bool(result.converged), sigma0=round(result.sigma0, 3),
                    check_rms_enu_m=np.round(ck.attrs["rms_m"], 3).tolist(),
                    check_rms_3d_m=round(float(np.sqrt(np.sum(ck.attrs["rms_m"] ** 2))), 3),
                    seconds=round(time.perf_counter() - t1, 1))

    clean = run(0.0, ())
    emit("mismatches", **clean)
    for frac in fractions:
        for steps, variant in variants:
            rec = run(frac, steps, variant)
            rec["ratio_to_clean"] = round(rec["check_rms_3d_m"] / clean["check_rms_3d_m"], 3)
            emit("mismatches", **rec, load=load())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--part", nargs="+", default=["blunders", "variance", "offsets"],
                    choices=["blunders", "variance", "offsets", "scale", "scale-one", "qc-cost", "mismatches", "misses",
                             "clean"])
    ap.add_argument("--draws", type=int, default=20)
    ap.add_argument("--draw-list", type=int, nargs="*", help="(misses) these draws instead of range(--draws)")
    ap.add_argument("--steps", nargs="+", default=["baarda"], help="(misses, clean) the QC steps run")
    ap.add_argument("--sizes", nargs="+", default=["medium", "large1m", "xl4000"], choices=sorted(SIZES))
    ap.add_argument("--old", action="store_true", help="also time the column-solve precision (slow at 4,000 images)")
    ap.add_argument("--qc", action="store_true", help="(scale-one) also time a full QC run")
    ap.add_argument("--qc-sizes", nargs="*", default=["large1m"], help="sizes with a full QC run timed")
    ap.add_argument("--repeat", type=int, default=1, help="(qc-cost) QC runs, each between two plain solves")
    ap.add_argument("--bal", help="(qc-cost) this BAL file instead of the size's generated block")
    ap.add_argument("--fractions", nargs="+", type=float, default=[0.2, 0.5])
    ap.add_argument("--variants", nargs="+", choices=sorted(MISMATCH_VARIANTS), default=["paper", "run"],
                    help="mismatch part: QC settings of the paper's simulation and/or of `lunarmap run`")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", help="append the records to this file")
    args = ap.parse_args(argv)
    for part in args.part:
        if part == "blunders":
            part_blunders(args.draws)
        elif part == "variance":
            part_variance(args.draws)
        elif part == "offsets":
            part_offsets(args.draws)
        elif part == "clean":
            part_clean(args.draws, tuple(args.steps))
        elif part == "misses":
            part_misses(args.draw_list or list(range(args.draws)), tuple(args.steps))
        elif part == "scale":
            part_scale(args.sizes, args.old, args.qc_sizes)
        elif part == "scale-one":
            part_scale_one(args.sizes[0], args.old, args.qc)
        elif part == "qc-cost":
            part_qc_cost(args.sizes[0], args.repeat, args.bal)
        elif part == "mismatches":
            part_mismatches(args.seed, args.fractions, [v for k in args.variants for v in MISMATCH_VARIANTS[k]])
    if args.json:
        with open(args.json, "a") as fh:
            for r in RECORDS:
                fh.write(json.dumps(r, default=str) + "\n")


if __name__ == "__main__":
    main()
