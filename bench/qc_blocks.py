"""Random frame blocks with the DLR paper's gross-error mix, for held-out-style QC testing (issue 27 item 6).

Geometry comes from :func:`lunarmap.simulate.blocks.frame_block` with randomised parameters (not from
:func:`lunarmap.simulate.dlr.dlr_block`): 2-6 orbits, 6-16 images per orbit, 1-3 cameras, side overlap
0.2-0.7 (weak to strong cross-orbit geometry), forward overlap 0.55-0.8, along-track tilts 0-15 degrees,
random focal length / principal point / radial distortion, 0 or 4-12 control points, 30-80 points.

Error mix (lunarmap.simulate.dlr.inject_blunders, the paper's Tables 2-3): half large image errors
(500-3000 px) and half small ones (10-40 px) on distinct points, one navigation position error (2 km on
x0/y0), one attitude error (0.2 deg on phi/omega, another image), one control error (2 km, one axis) when
there is control. The 20 image errors of the paper's 344-observation block are scaled to each block's
number of image observations (at least 4, at most one per point).

The containers (``DlrSimulation``, ``Blunders``) are reused so that tests/qchelp.py's problem builder and
scorer apply; the injection here is its own code.

Every error's detectability on the clean block (its minimal detectable bias) is :func:`error_reliability`.

Limitations: every camera of a block shares one interior (frame_block takes one); no line-scan blocks yet.
"""

from __future__ import annotations

import dataclasses
import os
import sys

import numpy as np

from lunarmap.simulate.blocks import clementine_interior, frame_block
from lunarmap.simulate.dlr import PAPER_AXES, PX_PER_MM, Blunders, DlrSimulation, _keep_points

__all__ = ["random_block", "inject_mix", "error_reliability", "DELTA0"]

#: non-centrality a w-test with limit 4 detects with 80 % power (4 + z_0.80 = 4 + 0.84): an error whose expected
#: |w| on the clean block is below it is below the observation's minimal detectable bias (MDB)
DELTA0 = 4.84

#: the paper's "blunders" sigmas: image (mm), position (m), attitude (deg), control (m)
IMAGE_MM, POSITION_M, ATTITUDE_DEG, CONTROL_M = 0.02, 100.0, 0.01, 200.0


def random_block(seed: int) -> tuple[DlrSimulation, dict]:
    """A clean random frame block and the parameters it was drawn with."""
    rng = np.random.default_rng(seed)
    for attempt in range(20):
        cams = int(rng.integers(1, 4))
        p = dict(orbits=int(rng.integers(2, 7)), per_orbit=cams * int(rng.integers(max(2, 6 // cams), 16 // cams + 1)),
                 cameras=cams, side_overlap=float(rng.uniform(0.2, 0.7)),
                 forward_overlap=float(rng.uniform(0.55, 0.8)),
                 tilt=[float(t) for t in rng.uniform(-15, 15, cams)],
                 focal_mm=float(rng.uniform(60.0, 120.0)), pp_px=[float(v) for v in rng.uniform(-10, 10, 2)],
                 k1=float(rng.uniform(-5e-5, 5e-5)), n_control=int(rng.choice([0, 4, 8, 12])),
                 n_points=int(rng.integers(30, 81)), attempt=attempt)
        io = clementine_interior(focal_mm=p["focal_mm"], odk=(0.0, p["k1"], 0.0))
        io = dataclasses.replace(io, detector_center_line=io.detector_center_line + p["pp_px"][0],
                                 detector_center_sample=io.detector_center_sample + p["pp_px"][1])
        sig_px = IMAGE_MM * PX_PER_MM
        try:
            sb = frame_block(orbits=p["orbits"], per_orbit=p["per_orbit"], cameras=cams, tilt_deg=p["tilt"],
                             forward_overlap=p["forward_overlap"], side_overlap=p["side_overlap"],
                             points=4 * p["n_points"], n_control=p["n_control"], n_check=0, sigma_px=sig_px,
                             altitude=150.0 * p["focal_mm"] / 0.023, interior=io,
                             nav_sigma_pos=POSITION_M, nav_sigma_att=np.radians(ATTITUDE_DEG),
                             offsets=np.zeros((p["orbits"], 6)), drifts=np.zeros((p["orbits"], 6)),
                             control_sigma=CONTROL_M, min_rays=3, seed=seed * 31 + attempt)
        except Exception:            # noqa: BLE001 -- a geometry frame_block cannot build: draw again
            continue
        others = np.setdiff1d(np.arange(sb.true_points.shape[0]), sb.control)
        k = min(others.size, p["n_points"] - sb.control.size)
        if k < 10:
            continue
        keep = np.sort(np.concatenate([sb.control, rng.choice(others, k, replace=False)]))
        _keep_points(sb, keep)
        n = len(sb.nav_cameras)
        nav_sigma = np.column_stack([np.full((n, 3), np.radians(ATTITUDE_DEG)), np.full((n, 3), POSITION_M)])
        sim = DlrSimulation(sb, np.zeros((n, 6)), nav_sigma,
                            np.broadcast_to(np.asarray(sb.measurements.sigma, float), (sb.measurements.xy.shape[0],)).copy(),
                            CONTROL_M, sb.times * 1600.0 / 1000.0, sb.measurements.xy.copy())
        p.update(images=n, points=int(sb.true_points.shape[0]), observations=int(sb.measurements.xy.shape[0]),
                 control=int(sb.control.size))
        return sim, p
    raise RuntimeError(f"no block for seed {seed}")


def inject_mix(sim: DlrSimulation, seed: int) -> DlrSimulation:
    """A copy of ``sim`` with the paper's error mix scaled to its size (module docstring)."""
    from lunarmap.simulate.blocks import Measurements, SimulatedBlock

    rng = np.random.default_rng(seed)
    sb = sim.block
    m = sb.measurements
    n_pt = sb.true_points.shape[0]
    n_img_err = int(np.clip(round(20 * m.xy.shape[0] / 344), 4, n_pt))
    large = n_img_err // 2
    small = n_img_err - large
    pts = rng.choice(n_pt, n_img_err, replace=False)
    obs = np.array([rng.choice(np.flatnonzero(m.pt_idx == j)) for j in pts], np.int64)
    mag = np.concatenate([rng.uniform(500.0, 3000.0, large), rng.uniform(10.0, 40.0, small)])
    ang = rng.uniform(0.0, 2.0 * np.pi, n_img_err)
    vec = mag[:, None] * np.column_stack([np.cos(ang), np.sin(ang)])
    xy = sim.clean_xy.copy()
    xy[obs] += vec
    bl = Blunders(obs, vec, np.r_[np.ones(large, np.int64), np.full(small, 2, np.int64)])
    nav = np.zeros_like(sim.nav_observed)
    n_img = nav.shape[0]
    j, k = int(rng.integers(n_img)), PAPER_AXES[("x0", "y0")[int(rng.integers(2))]]
    nav[j, k] = rng.choice([-1.0, 1.0]) * 2000.0
    bl.position, bl.position_value = (j, k), float(nav[j, k])
    j2 = int(rng.choice([i for i in range(n_img) if i != j]))
    k2 = PAPER_AXES[("phi", "omega")[int(rng.integers(2))]]
    nav[j2, k2] = rng.choice([-1.0, 1.0]) * np.radians(0.2)
    bl.attitude, bl.attitude_value = (j2, k2), float(nav[j2, k2])
    ctl = sb.control_xyz.copy()
    if sb.control.size:
        c, a = int(rng.integers(sb.control.size)), int(rng.integers(3))
        v = float(rng.choice([-1.0, 1.0]) * 2000.0)
        ctl[c, a] += v
        bl.control, bl.control_value = (c, a), v
    new = SimulatedBlock(**{**sb.__dict__, "measurements": Measurements(m.cam_idx, m.pt_idx, xy, m.sigma),
                            "control_xyz": ctl})
    return DlrSimulation(new, nav, sim.nav_sigma, sim.image_sigma, sim.control_sigma, sim.along_km,
                         sim.clean_xy, bl)


def error_reliability(clean: DlrSimulation, bl: Blunders, delta0: float = DELTA0) -> list[dict]:
    """Detectability of the injected errors ``bl`` (:func:`inject_mix`) from the clean block ``clean``'s own
    reliability.

    The clean block (no errors) is adjusted by least squares; each erroneous observation's redundancy number
    ``r`` there gives the expected w-test of its error ``e`` (a-priori sigma ``s``): ``|e| sqrt(r) / s`` (the
    largest over an image observation's two coordinates), and its minimal detectable bias
    ``MDB = delta0 s / sqrt(r)`` (Baarda). An error with expected ``|w| < delta0`` is below its MDB: no test at
    the limit 4 finds it with 80 % power, whatever the snooping does. Judged on the clean block, not on the
    state a QC run leaves (whose removals can strip an image or point of the redundancy it was built with).

    Returns
    -------
    list of dict
        One per error, in :func:`score`'s order of counting (image errors, position, attitude, control):
        ``kind``, ``index``, ``expected_w``, ``r``, ``mdb`` (pixels, metres, radians), ``error``, ``below_mdb``.
    """
    tests = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests")
    if tests not in sys.path:       # tests/qchelp.py builds the problem the benchmark's QC runs on
        sys.path.append(tests)
    from qchelp import dlr_problem

    from lunarmap.adjust import SolverOptions, solve

    res = solve(dlr_problem(clean), SolverOptions(ftol=1e-8))
    pr = res.precision()
    out: list[dict] = []

    def row(kind, index, e, s, r):
        r = float(max(r, 0.0)) if np.isfinite(r) else 0.0
        ew = float(abs(e) * np.sqrt(r) / s)
        out.append({"kind": kind, "index": index, "error": float(e), "r": r, "expected_w": ew,
                    "mdb": float(delta0 * s / np.sqrt(r)) if r > 0 else float("inf"), "below_mdb": ew < delta0})

    for i, e in zip(bl.image_obs, bl.image_px):
        rr = pr.redundancy_numbers[i]
        k = int(np.argmax(np.abs(e) * np.sqrt(np.clip(rr, 0, None))))
        row("image", int(i), float(e[k]), float(clean.image_sigma[i]), float(rr[k]))
    nav = res.problem.terms[0].row_table()
    for kind, b, v in (("position", bl.position, bl.position_value), ("attitude", bl.attitude, bl.attitude_value)):
        if b is None:
            continue
        j, k = b
        rows = np.flatnonzero((nav["image"] == j) & (nav["param"] == k) & (nav["kind"] == 0))
        r = float(np.asarray(pr.term_redundancy[0])[rows[0]]) if rows.size else 0.0
        row(kind, (int(j), int(k)), v, float(clean.nav_sigma[j, k]), r)
    if bl.control is not None:
        c, a = bl.control
        row("control", (int(c), int(a)), bl.control_value, float(clean.control_sigma),
            float(pr.control_redundancy[c, a]))
    return out
