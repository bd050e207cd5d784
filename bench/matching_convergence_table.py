"""Matching error against truth versus stereo convergence angle (a script, not a test).

Re-runs the simulation of the LROC multi-image study (seeds/001, section 3.4,
Fig. 7) on synthetic terrain: for each convergence angle a symmetric stereo
pair (equal emission angles on opposite sides of nadir) is rendered from one
synthetic DTM + albedo map with 3 x 3 supersampling, Lambert shading and
independent Gaussian noise (sigma grey levels) in each image; Förstner points
of image 1 are matched into image 2 (prediction at height 0, pyramid NCC,
LSM with 6 affine + 2 radiometric parameters, RANSAC); every surviving match
is compared with its true conjugate
``image2.ground_to_image(image1.image_to_ground(l1, s1, dtm=DTM))``.

    python bench/matching_convergence_table.py [--cameras linescan frame] [--noise 2] [--size 300]

Prints one table per camera (RMS error in pixels: total, line, sample; match
count; median LSM sigma; RANSAC on the same matches with 20 % of them displaced
by 4-40 px: fraction of those removed and of the others kept) and a JSON line per row.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from lunarmap.camera import DtmSampler
from lunarmap.matching import STATUS, MatchParams, TiePointParams, foerstner, match_pair, ransac_local_affine
from lunarmap.matching.predict import predict_conjugates
from lunarmap.simulate import matching_errors, render_image, stereo_pair, synthetic_scene

SETUPS = {
    # NAC-like line scanner: 0.5 m pixels at 50 km; Clementine UVVIS-like frame: 12.8 m pixels at 50 km.
    "linescan": dict(gsd=0.5, extent_px=800),
    "frame": dict(gsd=12.8, extent_px=640),
}


def run_case(kind: str, convergence: float, noise: float, size: int, seed: int) -> dict:
    gsd = SETUPS[kind]["gsd"]
    extent = SETUPS[kind]["extent_px"] * gsd
    kw = dict(n_lines=size, n_samples=size) if kind == "linescan" else {}
    cam1, cam2 = stereo_pair(kind, convergence, **kw)
    dtm, alb = synthetic_scene(30.0, 0.0, extent, gsd, seed=seed)
    img1 = render_image(cam1, dtm, alb, noise_sigma=noise, sun="eo", seed=2 * seed + 1).values
    img2 = render_image(cam2, dtm, alb, noise_sigma=noise, sun="eo", seed=2 * seed + 2).values
    pts = foerstner(img1, cell=16, per_cell=1)
    # Search radius: the parallax of the largest height in the scene, plus a margin.
    n_l, n_s = img1.shape
    e = predict_conjugates(cam1, cam2, [n_l / 2], [n_s / 2], 0.0).epipolar[0]
    search = float(np.hypot(*e) * np.nanmax(np.abs(dtm.values)) + 4.0)
    params = TiePointParams(match=MatchParams(search=search))
    m = match_pair(img1, img2, cam1, cam2, pts, 0.0, params, f"{kind} {convergence} deg")
    ok = m.ok
    dl, ds = matching_errors(cam1, cam2, m.line1[ok], m.sample1[ok], m.line2[ok], m.sample2[ok], DtmSampler(dtm))
    removed, kept = _ransac_with_mismatches(m, seed)
    return dict(ransac20_removed=removed, ransac20_kept=kept, camera=kind, convergence_deg=convergence, noise_sigma=noise, points=int(len(pts)),
                matches=int(ok.sum()), outliers_removed=int(np.sum(m.status == STATUS["outlier"])),
                rms_px=float(np.sqrt(np.mean(dl ** 2 + ds ** 2))), rms_line_px=float(np.sqrt(np.mean(dl ** 2))),
                rms_sample_px=float(np.sqrt(np.mean(ds ** 2))),
                max_px=float(np.max(np.hypot(dl, ds))) if ok.any() else float("nan"),
                median_sigma_px=float(np.median(np.hypot(m.sigma_line[ok], m.sigma_sample[ok]))),
                search_px=search)


def _ransac_with_mismatches(m, seed: int) -> tuple[float, float]:
    """RANSAC on this pair's accepted matches with 20 % of them displaced by 4-40 px in any direction.

    Returns the fractions of injected mismatches removed and of the other matches kept.
    """
    ok = m.ok
    p = m.prediction
    dl, ds = m.line2[ok] - p.line[ok], m.sample2[ok] - p.sample[ok]
    rng = np.random.default_rng(seed + 100)
    bad = rng.random(dl.size) < 0.2
    ang = rng.uniform(0, 2 * np.pi, bad.sum())
    mag = rng.uniform(4.0, 40.0, bad.sum())
    dl[bad] += mag * np.cos(ang)
    ds[bad] += mag * np.sin(ang)
    inl = ransac_local_affine(m.line1[ok], m.sample1[ok], dl, ds, p.epipolar[ok])
    return float(np.mean(~inl[bad])), float(np.mean(inl[~bad]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cameras", nargs="+", default=["linescan", "frame"], choices=sorted(SETUPS))
    ap.add_argument("--noise", type=float, default=2.0, help="noise sigma, grey levels")
    ap.add_argument("--size", type=int, default=300, help="line-scan image size, pixels")
    ap.add_argument("--angles", type=float, nargs="+", default=[float(a) for a in range(0, 55, 5)])
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    rows = []
    for kind in args.cameras:
        print(f"\n{kind}: noise sigma {args.noise} grey levels")
        print(f"{'conv deg':>8} {'matches':>8} {'RMS px':>8} {'line':>8} {'sample':>8} {'max':>7} {'med sig':>8}"
              f" {'RANSAC 20% mismatches: removed, kept':>38}")
        for conv in args.angles:
            t = time.perf_counter()
            r = run_case(kind, conv, args.noise, args.size, args.seed)
            r["seconds"] = time.perf_counter() - t
            rows.append(r)
            print(f"{conv:8.0f} {r['matches']:5d}/{r['points']:<4d}{r['rms_px']:8.3f} {r['rms_line_px']:8.3f} "
                  f"{r['rms_sample_px']:8.3f} {r['max_px']:7.3f} {r['median_sigma_px']:8.3f}"
                  f" {r['ransac20_removed']:19.3f} {r['ransac20_kept']:6.3f}", flush=True)
    for r in rows:
        print(json.dumps(r))


if __name__ == "__main__":
    main()
