"""Issue 30, acceptance item 1 (altimetry, no control points): how far LOLA-like tracks fix a block's datum.

For many seeds: the fore/aft frame block of ``tests/test_adjust_altimetry.py`` (no control points, check
points, navigation with per-orbit errors) adjusted with navigation alone and with simulated altimetry tracks;
the check and tie points' errors against the simulation's truth split into radial (up) and horizontal
(east/north) parts, their normalised errors ``e^T C^-1 e`` with the posterior covariance ``C`` of each part, the
posterior sigmas (the prediction) and the track offsets' recovery.

Statistics: with per-orbit navigation errors on 2 orbits a block's horizontal error is a few independent
draws, so a per-block errors / sigma RMS scatters like ``sqrt(chi2_k / k)`` with small ``k``. Per component
the script reports the pooled errors / sigma (RMS over all seeds' points), the per-seed spread and the
effective degrees of freedom ``k_eff = 2 m^2 / var`` of the per-seed mean ``z^2`` (``m`` its mean; for
``chi2_k / k``: ``var = 2 / k``).

Terrain: ``--terrain sines`` (the test's: ``--relief`` m of long-wavelength sines) or ``cratered``
(:func:`lunarmap.simulate.synthetic_dtm`: craters 2-20 km over rolling terrain, ``--relief`` its rolling
part's sigma). ``--points`` sets the tie-point density; ``--slopes`` the altimetry's recomputed barycentric
weights; ``--slopes-after`` a first adjustment with fixed weights, then one with recomputed ones from there.

    PYTHONPATH=. python bench/altimetry_datum.py --seeds 1-20 --json out.json --md out.md
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import dataclass

import numpy as np

import lunarmap
from lunarmap.adjust import (
    LaserAltimetry,
    SolverOptions,
    intersect_points,
)
from lunarmap.camera.geodesy import enu_basis, xyz_to_lonlat_height
from lunarmap.camera.shape import MOON_RADIUS
from lunarmap.simulate import altimetry_tracks, frame_block_height

# the test block of tests/test_adjust_altimetry.py, with this script's size and terrain
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))
import test_adjust_altimetry as T  # noqa: E402


@dataclass
class Config:
    relief: float = 50.0
    terrain: str = "sines"
    points: int = 300
    n_check: int = 15
    tracks: int = 24
    along_m: float = 1140.0
    shot_sigma: float = 0.5
    interp_sigma: float = 1.0
    offset_sigma: float = 30.0
    slopes: bool = False
    slopes_after: bool = False
    per_orbit: int = 8
    apriori: bool = True


def cratered_height(seed: int, relief: float):
    """A cratered terrain's interpolant ``h(lon, lat)`` (m, degrees) over the test block's extent."""
    from scipy.interpolate import RegularGridInterpolator

    from lunarmap.simulate import synthetic_dtm

    dtm = synthetic_dtm(0.0, 0.0, (90e3, 140e3), 250.0, relief=relief, wavelength=20e3, crater_density=0.3,
                        d_min=2e3, d_max=20e3, seed=1000 + seed)
    f = RegularGridInterpolator((dtm.lat.values, dtm.lon.values), dtm.values, bounds_error=False, fill_value=None)
    return lambda lon, lat: f(np.column_stack([np.ravel(lat), np.ravel(lon)])).reshape(np.shape(lon))


def build(seed: int, cfg: Config):
    height = (cratered_height(seed, cfg.relief) if cfg.terrain == "cratered"
              else (lambda lo, la: frame_block_height(lo, la, cfg.relief)))
    sb, net, sensors, spec, times, truth = T._block(seed, per_orbit=cfg.per_orbit, points=cfg.points,
                                                     n_check=cfg.n_check, relief=cfg.relief, height=height)
    lon, lat, _ = xyz_to_lonlat_height(sb.true_points, MOON_RADIUS)
    sim = altimetry_tracks(height, (lon.min(), lon.max()), (lat.min(), lat.max()), cfg.tracks,
                           along_track_m=cfg.along_m, sigma=cfg.shot_sigma, offset_sigma=cfg.offset_sigma,
                           heading_deg=20.0, seed=seed)
    return sb, net, sensors, spec, times, truth, sim, height


def components(err: np.ndarray, cov: np.ndarray, truth: np.ndarray):
    """Radial and horizontal errors, their z^2 (normalised by the posterior covariance of each part) and sigmas."""
    lon, lat, _ = xyz_to_lonlat_height(truth, MOON_RADIUS)
    E = enu_basis(lon, lat)                                   # rows east, north, up
    e = np.einsum("kij,kj->ki", E, err)
    C = np.einsum("kij,kjl,kml->kim", E, cov, E)
    z2_r = e[:, 2] ** 2 / C[:, 2, 2]
    Ch = C[:, :2, :2]
    z2_h = np.einsum("ki,kij,kj->k", e[:, :2], np.linalg.inv(Ch), e[:, :2])
    z2_3 = np.einsum("ki,kij,kj->k", err, np.linalg.inv(cov), err)
    return {"e_r": e[:, 2], "e_h": np.hypot(e[:, 0], e[:, 1]), "e_3": np.linalg.norm(err, axis=1),
            "s_r": np.sqrt(C[:, 2, 2]), "s_h": np.sqrt(C[:, 0, 0] + C[:, 1, 1]), "s_3": np.sqrt(np.trace(cov, axis1=1, axis2=2)),
            "z2_r": z2_r, "z2_h": z2_h, "z2_3": z2_3}


def _rms(a) -> float:
    return float(np.sqrt(np.mean(np.square(a))))


def run_seed(seed: int, cfg: Config) -> dict:
    t0 = time.time()
    sb, net, sensors, spec, times, truth, sim, height = build(seed, cfg)
    opts = SolverOptions(ftol=1e-10)
    b0 = lunarmap.build_block(sensors, net, navigation=spec, times=times)
    r0 = lunarmap.solve(b0, opts).result
    p0 = r0.precision()

    interp_true = interpolation_error(truth, net, sim)
    # "auto": the true surface's interpolation error (what the altimeter's variance component would find)
    interp = interp_true if cfg.interp_sigma < 0 else cfg.interp_sigma

    def alt(slopes: bool) -> LaserAltimetry:
        return LaserAltimetry(sim.shots, sigma_m=cfg.shot_sigma, interpolation_sigma_m=interp,
                              offset_sigma_m=cfg.offset_sigma, slopes=slopes)

    b1 = lunarmap.build_block(sensors, net, navigation=spec, times=times, altimetry=[alt(cfg.slopes)])
    r1 = lunarmap.solve(b1, opts).result
    if cfg.slopes_after:
        # settle the points with fixed weights, then triangulate / weight from the settled positions
        from lunarmap.adjust import altimetry_observations

        pr = b1.problem
        cand = np.isin(net.point_type, ["tie"])
        new = altimetry_observations(alt(True), r1.points, b1.model.n_images * b1.model.n_params, b1.model.n_images,
                                     cand)
        pr.terms[pr.terms.index(b1.altimetry[0])] = new
        b1.altimetry[0] = new
        pr.points = np.array(r1.points, float)
        pr.cam_params = np.array(r1.state.cam_params, float)
        r1 = lunarmap.solve(b1, opts).result
    p1 = r1.precision()
    term = b1.altimetry[0]
    out: dict = {"seed": seed, "sigma0": float(r1.sigma0), "sigma0_nav": float(r0.sigma0), "shots": int(term.n_shots), "tracks": int(term.n_tracks)}
    for kind in ("check", "tie"):
        sel = net.point_type == kind
        for tag, r, p in (("nav", r0, p0), ("alt", r1, p1)):
            # a-priori cofactors (the simulation's noise is the a-priori's): the posterior covariances are
            # scaled by sigma0^2, which the altimeter's pessimistic interpolation sigma pulls below 1
            cov = p.pt_cov[sel] / (r.sigma0 ** 2 if cfg.apriori else 1.0)
            c = components((r.points - truth)[sel], cov, truth[sel])
            for comp in ("r", "h", "3"):
                out[f"{kind}_{tag}_rms_{comp}"] = _rms(c[f"e_{comp}"])
                out[f"{kind}_{tag}_sigma_{comp}"] = _rms(c[f"s_{comp}"])        # predicted RMS
                dof = {"r": 1, "h": 2, "3": 3}[comp]
                out[f"{kind}_{tag}_msz2_{comp}"] = float(np.mean(c[f"z2_{comp}"]) / dof)   # mean z^2 per dof
    # the block's orientation error at the check points, free of their own measurement noise: the true points'
    # noise-free projections intersected with the adjusted images; predicted by the images' part of the
    # check points' posterior covariance (C_pt minus the intersection's own N^-1)
    chk = np.flatnonzero(net.point_type == "check")
    obs = b1.problem.obs
    use = np.isin(obs.pt_idx, chk)
    loc = np.searchsorted(chk, obs.pt_idx[use])
    xy_true = b1.model.project(sb.true_params, obs.cam_idx[use], truth[obs.pt_idx[use]])
    sig_px = float(np.median(np.atleast_1d(sb.measurements.sigma)))
    for tag, r, p in (("nav", r0, p0), ("alt", r1, p1)):
        ix = intersect_points(b1.model, r.state.cam_params, obs.cam_idx[use], loc, xy_true, sig_px,
                              n_pt=chk.size, x0=truth[chk])
        cov = p.pt_cov[chk] / (r.sigma0 ** 2 if cfg.apriori else 1.0) - ix.cov_apriori
        c = components(ix.xyz - truth[chk], cov, truth[chk])
        for comp, dof in (("r", 1), ("h", 2), ("3", 3)):
            out[f"datum_{tag}_rms_{comp}"] = _rms(c[f"e_{comp}"])
            out[f"datum_{tag}_sigma_{comp}"] = _rms(c[f"s_{comp}"])
            out[f"datum_{tag}_msz2_{comp}"] = float(np.mean(c[f"z2_{comp}"]) / dof)
    s = sum(t.n_extra for t in b1.problem.terms[:-1])
    off = r1.state.extra[s:s + term.n_tracks]
    sig = np.sqrt(np.diag(p1.extra_cov)[s:s + term.n_tracks]) / (r1.sigma0 if cfg.apriori else 1.0)
    true_off = sim.offsets[np.searchsorted(sim.track_names, term.track_names)]
    out["offsets_within_2sigma"] = float(np.mean(np.abs(off - true_off) <= 2.0 * sig))
    out["offset_mean_error"] = float(np.mean(off - true_off))
    out["offset_sigma_median"] = float(np.median(sig))
    out["interp_error_rms"] = interp_true
    out["interp_sigma_used"] = float(interp)
    # the offsets relative to their mean (the block's common radius taken out): o_i - mean(o), its sigma from
    # the offsets' covariance
    Co = p1.extra_cov[s:s + term.n_tracks, s:s + term.n_tracks] / (r1.sigma0 ** 2 if cfg.apriori else 1.0)
    n_tr = term.n_tracks
    Pm = np.eye(n_tr) - 1.0 / n_tr
    sig_rel = np.sqrt(np.diag(Pm @ Co @ Pm))
    d_rel = Pm @ (off - true_off)
    out["offsets_rel_within_2sigma"] = float(np.mean(np.abs(d_rel) <= 2.0 * sig_rel))
    out["offset_common_z"] = float(np.mean(off - true_off) / np.sqrt(np.mean(Co)))
    # terrain slope at the tie points (central differences over 100 m), degrees
    tie = net.point_type == "tie"
    lon, lat, _ = xyz_to_lonlat_height(truth[tie], MOON_RADIUS)
    d = np.degrees(100.0 / MOON_RADIUS)
    gx = (height(lon + d, lat) - height(lon - d, lat)) / (200.0 * np.cos(np.radians(lat)))
    gy = (height(lon, lat + d) - height(lon, lat - d)) / 200.0
    out["slope_rms_deg"] = float(np.degrees(np.arctan(_rms(np.hypot(gx, gy)))))
    out["tie_spacing_m"] = float(np.sqrt(_area_m2(truth[tie]) / tie.sum()))
    out["seconds"] = time.time() - t0
    return out


def interpolation_error(truth: np.ndarray, net, sim) -> float:
    """RMS of the true tie points' triangulated surface minus the true terrain at the shots, metres."""
    from lunarmap.adjust import altimetry_observations

    term = altimetry_observations(LaserAltimetry(sim.shots, 1.0, slopes=True), truth, 0, 1, net.point_type == "tie")
    zero = np.zeros(term.n_tracks)
    return _rms(term.residuals_m(truth, zero) + term.radius - sim.terrain_radius[term.shot_index])


def _area_m2(X: np.ndarray) -> float:
    from scipy.spatial import ConvexHull

    lon, lat, _ = xyz_to_lonlat_height(X, MOON_RADIUS)
    P = np.column_stack([np.radians(lon) * np.cos(np.radians(lat.mean())), np.radians(lat)]) * MOON_RADIUS
    return float(ConvexHull(P).volume)


def summarise(rows: list[dict]) -> dict:
    out: dict = {"seeds": len(rows)}
    for kind in ("check", "tie", "datum"):
        for comp in ("r", "h", "3"):
            for tag in ("nav", "alt"):
                rms = np.array([r[f"{kind}_{tag}_rms_{comp}"] for r in rows])
                sig = np.array([r[f"{kind}_{tag}_sigma_{comp}"] for r in rows])
                msz = np.array([r[f"{kind}_{tag}_msz2_{comp}"] for r in rows])
                k = f"{kind}_{tag}_{comp}"
                out[k] = {"rms_pooled": _rms(rms), "sigma_pooled": _rms(sig),
                          "ratio_pooled": _rms(rms) / _rms(sig),
                          "z_pooled": float(np.sqrt(np.mean(msz))),            # pooled errors / sigma RMS
                          "z_seed_min": float(np.sqrt(msz.min())), "z_seed_median": float(np.sqrt(np.median(msz))),
                          "z_seed_max": float(np.sqrt(msz.max())),
                          "z_seed_in_band": float(np.mean(np.abs(np.sqrt(msz) - 1.0) <= 0.2)),
                          "k_eff": float(2.0 * np.mean(msz) ** 2 / np.var(msz, ddof=1)) if len(rows) > 1 else None}
            nav = np.array([r[f"{kind}_nav_rms_{comp}"] for r in rows])
            alt = np.array([r[f"{kind}_alt_rms_{comp}"] for r in rows])
            out[f"{kind}_gain_{comp}"] = {"pooled": _rms(nav) / _rms(alt), "seed_min": float(np.min(nav / alt)),
                                          "seed_median": float(np.median(nav / alt))}
    for key in ("offsets_within_2sigma", "offsets_rel_within_2sigma"):
        w = np.array([r[key] for r in rows])
        out[key] = {"pooled": float(np.mean(w)), "seed_min": float(w.min()), "seeds_ge_0.9": float(np.mean(w >= 0.9))}
    z = np.array([r["offset_common_z"] for r in rows])
    out["offset_common_z"] = {"rms": _rms(z), "within_2": float(np.mean(np.abs(z) <= 2.0))}
    for key in ("sigma0", "sigma0_nav", "interp_error_rms", "interp_sigma_used", "slope_rms_deg", "tie_spacing_m",
                "seconds", "offset_sigma_median"):
        out[key] = float(np.mean([r[key] for r in rows]))
    return out


def chi_band_probability(k: float, lo: float = 0.8, hi: float = 1.2) -> float:
    """P(lo <= sqrt(chi2_k / k) <= hi): how often a block with k independent draws lands in the band."""
    from scipy.stats import chi2

    return float(chi2.cdf(hi ** 2 * k, k) - chi2.cdf(lo ** 2 * k, k))


def markdown(cfg: Config, s: dict) -> str:
    lines = [f"## altimetry datum: {cfg.terrain} terrain, relief {cfg.relief} m, {cfg.points} points, "
             f"slopes={cfg.slopes}, slopes_after={cfg.slopes_after}, {s['seeds']} seeds",
             f"tie spacing {s['tie_spacing_m']:.0f} m, terrain slope RMS at tie points {s['slope_rms_deg']:.2f} deg, "
             f"true-surface interpolation error at shots {s['interp_error_rms']:.2f} m RMS "
             f"(interpolation sigma used {s['interp_sigma_used']:.2f} m), "
             f"{s['seconds']:.0f} s per seed; sigma0 {s['sigma0']:.2f} (navigation alone {s['sigma0_nav']:.2f}), "
             f"covariances {'a-priori' if cfg.apriori else 'a-posteriori'}", "",
             "| points | part | nav RMS (m) | alt RMS (m) | alt predicted sigma (m) | gain | pooled err/sigma | "
             "per-seed err/sigma min / median / max | seeds in 1 +- 0.2 | k_eff | P(band | k_eff) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for kind in ("check", "tie", "datum"):
        for comp, name in (("r", "radial"), ("h", "horizontal"), ("3", "3-D")):
            a = s[f"{kind}_alt_{comp}"]
            n = s[f"{kind}_nav_{comp}"]
            g = s[f"{kind}_gain_{comp}"]
            k = a["k_eff"]
            lines.append(f"| {kind} | {name} | {n['rms_pooled']:.1f} | {a['rms_pooled']:.1f} | {a['sigma_pooled']:.1f} | "
                         f"{g['pooled']:.1f} | {a['z_pooled']:.2f} | {a['z_seed_min']:.2f} / {a['z_seed_median']:.2f} / "
                         f"{a['z_seed_max']:.2f} | {a['z_seed_in_band']:.2f} | {k if k is not None else float('nan'):.1f} | "
                         f"{chi_band_probability(k) if k else float('nan'):.2f} |")
    o, q, z = s["offsets_within_2sigma"], s["offsets_rel_within_2sigma"], s["offset_common_z"]
    lines += ["", f"offsets within 2 sigma: pooled {o['pooled']:.3f}, worst seed {o['seed_min']:.2f}, "
              f"seeds >= 90 %: {o['seeds_ge_0.9']:.2f}; median offset sigma {s['offset_sigma_median']:.1f} m",
              f"offsets relative to their mean within 2 sigma: pooled {q['pooled']:.3f}, worst seed {q['seed_min']:.2f}, "
              f"seeds >= 90 %: {q['seeds_ge_0.9']:.2f}; common offset error / sigma: RMS {z['rms']:.2f} over seeds, "
              f"within 2: {z['within_2']:.2f}"]
    return "\n".join(lines) + "\n"


def _seeds(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b) + 1)) if b else [int(a)]
    return out


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1-20", help="e.g. 1-20 or 1,2,5")
    ap.add_argument("--terrain", choices=("sines", "cratered"), default="sines")
    ap.add_argument("--relief", type=float, default=50.0)
    ap.add_argument("--points", type=int, default=300)
    ap.add_argument("--tracks", type=int, default=24)
    ap.add_argument("--along", type=float, default=1140.0, help="shot spacing along track, m")
    ap.add_argument("--interp-sigma", type=float, default=1.0,
                    help="m; negative: the true surface's interpolation error RMS")
    ap.add_argument("--slopes", action="store_true")
    ap.add_argument("--slopes-after", action="store_true")
    ap.add_argument("--aposteriori", action="store_true", help="covariances scaled by sigma0^2 (default a-priori)")
    ap.add_argument("--json")
    ap.add_argument("--md")
    a = ap.parse_args(argv)
    cfg = Config(relief=a.relief, terrain=a.terrain, points=a.points, tracks=a.tracks, along_m=a.along,
                 interp_sigma=a.interp_sigma, slopes=a.slopes, slopes_after=a.slopes_after,
                 apriori=not a.aposteriori)
    rows = []
    for seed in _seeds(a.seeds):
        rows.append(run_seed(seed, cfg))
        r = rows[-1]
        print(f"seed {seed}: check 3-D {r['check_nav_rms_3']:.1f} -> {r['check_alt_rms_3']:.1f} m "
              f"(r {r['check_alt_rms_r']:.1f}, h {r['check_alt_rms_h']:.1f}; sigma r {r['check_alt_sigma_r']:.1f}, "
              f"h {r['check_alt_sigma_h']:.1f}), datum 3-D {r['datum_nav_rms_3']:.1f} -> {r['datum_alt_rms_3']:.1f} "
              f"(r {r['datum_alt_rms_r']:.1f} h {r['datum_alt_rms_h']:.1f}), tie r {r['tie_nav_rms_r']:.1f} -> {r['tie_alt_rms_r']:.1f}, "
              f"z2/dof r {r['check_alt_msz2_r']:.2f} h {r['check_alt_msz2_h']:.2f}, {r['seconds']:.0f} s", flush=True)
    s = summarise(rows)
    md = markdown(cfg, s)
    print(md)
    res = {"config": cfg.__dict__, "summary": s, "seeds": rows}
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(res, fh, indent=1)
    if a.md:
        with open(a.md, "w") as fh:
            fh.write(md)
    return res


if __name__ == "__main__":
    main()
