"""Figures of the historical-mission tools (issue 13): ``python bench/historical_missions.py [--seeds N]``.

1. Five rotations: random orientations (tilts up to ~45 deg) -> flight parameters -> orientation.
2. Ranger-like triplet 435-437-439 and pair 435-439 (the paper's Table I base-height ratios), monoscopic
   (0.33 mm) and stereoscopic (0.296 mm) point transfer: S0, mean sigma X'Y'Z', true RMS, normalised RMS,
   pair/triplet ratios, pooled over ``--seeds`` runs of 600 points; next to the paper's Table IV.
3. Reseau: a 5 x 5 reseau with a known film distortion, per-cell projective and bilinear corrections.
4. A reconstructed 5-photo sequence written as kernels and reloaded: differences from the flight-parameter
   cameras; writing and loading times.
5. Lunar Orbiter 3 and Apollo 15 metric (shared kernel sets, skipped if absent): ISD time, image_to_ground vs
   pinhole SPICE, round trip over the image.
6. Clementine multi-orbit block through the real UVVIS IK (shared set): normalised errors pooled over
   ``--seeds`` blocks of 4 orbits x 12 images.

Timings are wall-clock seconds on the machine it runs on; say how loaded it was (``os.getloadavg``).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SHARED = Path(os.environ.get("LUNARMAP_SHARED_KERNELS", HERE.parent.parent / "shared" / "data" / "kernels"))


def five_rotations(n: int = 20000) -> None:
    from lunarmap.missions import flight_parameters_from_orientation
    from lunarmap.orientation.rotation import rotvec_to_matrix

    rng = np.random.default_rng(0)
    R = 1736600.0
    lat, lon, alt = rng.uniform(-89, 89, n), rng.uniform(-180, 180, n), rng.uniform(3e3, 400e3, n)
    up = np.column_stack([np.cos(np.radians(lat)) * np.cos(np.radians(lon)),
                          np.cos(np.radians(lat)) * np.sin(np.radians(lon)), np.sin(np.radians(lat))])
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east, axis=1)[:, None]
    rot = np.stack([east, -np.cross(up, east), -up], axis=-1) @ rotvec_to_matrix(rng.normal(0, np.radians(10), (n, 3)))
    t0 = time.perf_counter()
    table = flight_parameters_from_orientation([str(i) for i in range(n)], (R + alt)[:, None] * up, rot, radius=R)
    back = table.sensor_rotations()
    dt = time.perf_counter() - t0
    d = back @ np.swapaxes(rot, 1, 2)
    s = (d - np.swapaxes(d, 1, 2)) / 2
    err = np.linalg.norm(np.stack([s[:, 2, 1], s[:, 0, 2], s[:, 1, 0]], -1), axis=1)
    print(f"1. five rotations, {n} orientations (tilt {table.tilt.min():.2f}-{table.tilt.max():.1f} deg): "
          f"max {err.max():.1e} rad, position {np.abs(table.positions - (R + alt)[:, None] * up).max():.1e} m; "
          f"{dt:.2f} s both ways")


def ranger(seeds: int) -> None:
    from lunarmap.missions import base_height_ratio, intersect_photos
    from lunarmap.missions.ranger_simulation import ranger_sequence, simulate_measurements

    seq = ranger_sequence()
    c = seq.cameras
    bh = [base_height_ratio(c["435"], c["437"]), base_height_ratio(c["437"], c["439"]),
          base_height_ratio(c["435"], c["439"])]
    print(f"2. Ranger-like descent (tilt {seq.table.tilt.mean():.1f} deg, ranges "
          f"{', '.join(f'{r / 1e3:.1f}' for r in seq.table.Range)} km): B/H 435-437 {bh[0]:.4f}, 437-439 {bh[1]:.4f}, "
          f"435-439 {bh[2]:.4f} (paper: 0.032, 0.054, 0.081)")
    paper = {("mono", "triplet"): (0.330, 94, 59, 21), ("mono", "pair"): (0.478, 178, 114, 43),
             ("stereo", "triplet"): (0.296, 99, 60, 20), ("stereo", "pair"): (0.431, 154, 93, 33)}
    acc: dict = {}
    t0 = time.perf_counter()
    for seed in range(seeds):
        rng = np.random.default_rng(100 + seed)
        pts = seq.ground_points(600, rng)
        for mode, sigma in (("mono", 0.33), ("stereo", 0.296)):
            for name, photos in (("triplet", ("435", "437", "439")), ("pair", ("435", "439"))):
                m = simulate_measurements(seq, pts, photos, rng, mode=mode, sigma=sigma, reference="439")
                r = intersect_photos({p: c[p] for p in photos}, m.point, m.photo, m.xy, ranger_camera=seq.camera,
                                     mode=mode, reference="439")
                order = {p: i for i, p in enumerate(m.point_ids)}
                e = r.xyz - m.truth[[order[p] for p in r.point_id]]
                a = acc.setdefault((mode, name), {"e": [], "z": [], "s0": [], "sig": [], "sigp": [], "sigma": sigma})
                a["e"].append(e)
                a["z"].append(e / r.sigma_pooled())
                a["s0"].append(r.s0_pooled)
                a["sig"].append(r.sigma.mean(axis=0))
                a["sigp"].append(r.sigma_pooled().mean(axis=0))
    dt = time.perf_counter() - t0
    print(f"   {seeds} runs x 600 points per case, {dt:.1f} s; sigmas in metres along X'Y'Z', S0 in print mm")
    print("   case              S0 pooled  mean sigma X'/Y'/Z'   true RMS X'/Y'/Z'   errors/sigma RMS     paper S0, sigma")
    for key, a in acc.items():
        e, z = np.concatenate(a["e"]), np.concatenate(a["z"])
        rms, zr = np.sqrt(np.mean(e ** 2, axis=0)), np.sqrt(np.mean(z ** 2, axis=0))
        sig = np.mean(a["sig"], axis=0)
        p = paper[key]
        print(f"   {key[0]:6s} {key[1]:7s}   {np.mean(a['s0']):.3f} ({a['sigma']})  {sig[0]:5.0f}/{sig[1]:4.0f}/{sig[2]:4.0f}"
              f"      {rms[0]:5.0f}/{rms[1]:4.0f}/{rms[2]:4.0f}      {zr[0]:.3f}/{zr[1]:.3f}/{zr[2]:.3f}     "
              f"{p[0]:.3f}, {p[1]}/{p[2]}/{p[3]}")
    for mode in ("mono", "stereo"):
        rp = np.mean(acc[mode, "pair"]["sigp"], axis=0) / np.mean(acc[mode, "triplet"]["sigp"], axis=0)
        re = np.sqrt(np.mean(np.concatenate(acc[mode, "pair"]["e"]) ** 2, axis=0)) / \
            np.sqrt(np.mean(np.concatenate(acc[mode, "triplet"]["e"]) ** 2, axis=0))
        pp, pt = paper[mode, "pair"], paper[mode, "triplet"]
        print(f"   {mode}: pair/triplet sigma (pooled S0) {rp.round(2)}, true RMS {re.round(2)}; paper "
              f"{np.round(np.array(pp[1:]) / np.array(pt[1:]), 2)} with S0 ratio {pp[0] / pt[0]:.2f}, i.e. "
              f"{np.round(np.array(pp[1:]) / np.array(pt[1:]) / (pp[0] / pt[0]), 2)} at equal S0")


def reseau() -> None:
    from lunarmap.missions import ReseauCorrection, ReseauGrid

    def film(x, y):
        u, v = 1.02 * x + 0.006 * y + 0.3, -0.004 * x + 0.985 * y - 0.2
        w = 1 + 2e-4 * x - 1e-4 * y
        r2 = (x * x + y * y) / (2 * 85.0 ** 2)
        return u / w + 0.010 * x / 85 * r2, v / w + 0.010 * y / 85 * r2

    g = ReseauGrid.regular(5, 5, 42.5)
    marks = np.stack(film(g.calibrated[..., 0], g.calibrated[..., 1]), axis=-1)
    X, Y = np.meshgrid(np.linspace(-85, 85, 171), np.linspace(-85, 85, 171))
    u, v = film(X, Y)
    out = []
    for method in ("projective", "bilinear"):
        corr = ReseauCorrection(g, marks, method)
        cx, cy = corr.apply(u, v)
        err = np.hypot(cx - X, cy - Y)
        out.append(f"{method} RMS {np.sqrt(np.mean(err ** 2)) * 1e3:.2f} um / max {err.max() * 1e3:.2f} um")
    rep = ReseauCorrection(g, marks).report().attrs
    print(f"3. reseau 5 x 5 (42.5 mm), film distortion up to {np.hypot(u - X, v - Y).max():.2f} mm (global affine leaves "
          f"{rep['rms_affine_mm'] * 1e3:.0f} um RMS at the marks, global projective {rep['rms_projective_mm'] * 1e3:.1f} um); "
          f"per cell, noise-free marks: {'; '.join(out)}; mark noise 10 um")


def ranger_kernels() -> None:
    from lunarmap.missions.ranger_kernels import load_ranger_cameras, write_ranger_kernels
    from lunarmap.missions.ranger_simulation import ranger_sequence

    photos = tuple(str(p) for p in range(425, 441, 2))
    seq = ranger_sequence(photos=photos)
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        ks = write_ranger_kernels(seq.table, seq.camera, d)
        t1 = time.perf_counter()
        cams = load_ranger_cameras(ks)
        t2 = time.perf_counter()
        n = seq.camera.size
        L = np.array([0.5, n - 0.5, n / 2, 100.0])
        dp = max(float(np.linalg.norm(cams[p].sensor_position(0, 0) - seq.cameras[p].sensor_position(0, 0))) for p in photos)
        da = 0.0
        for p in photos:
            a, b = cams[p].look_vector(L, L[::-1]), seq.cameras[p].look_vector(L, L[::-1])
            da = max(da, float(np.max(np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.sum(a * b, axis=1)))))
    print(f"4. {len(photos)} photos -> kernels + labels in {t1 - t0:.2f} s, reloaded in {t2 - t1:.2f} s: position "
          f"{dp * 1e3:.1e} mm, look vectors {np.degrees(da) * 3600:.1e} arcsec from the flight-parameter cameras")


def film_cameras() -> None:
    import lunarmap
    from lunarmap.camera.factory import camera_from_isd

    for name, label in (("lunar_orbiter_3133_high_res_1", "3133_high_res_1_isis.lbl"),
                        ("apollo15_metric_AS15-M-1450", "AS15-M-1450_isis3.lbl")):
        folder = SHARED / name
        if not folder.is_dir():
            print(f"5. {name}: shared kernel set absent, skipped")
            continue
        t0 = time.perf_counter()
        isd = lunarmap.image_support(folder / label, folder / f"{name}.tm")
        t1 = time.perf_counter()
        cam = camera_from_isd(isd)
        rng = np.random.default_rng(0)
        lines, samples = rng.uniform(0, isd.image_lines, 20000), rng.uniform(0, isd.image_samples, 20000)
        worst = 0.0
        for h in (-2000.0, 0.0, 2000.0):
            g = cam.image_to_ground(lines, samples, height=h, on_miss="nan")
            ok = np.isfinite(g[:, 0])
            l2, s2 = cam.ground_to_image(g[ok], within_image=False)
            worst = max(worst, float(np.abs(l2 - lines[ok]).max()), float(np.abs(s2 - samples[ok]).max()))
        print(f"5. {isd.name_sensor}: ISD {t1 - t0:.2f} s; {isd.image_lines} x {isd.image_samples} px, "
              f"{100 * ok.mean():.0f} % of the pixels see the Moon; round trip over 20,000 pixels x 3 heights: "
              f"{worst:.1e} px")


def clementine(seeds: int) -> None:
    folder = SHARED / "clementine_uvvis_LUA3107H161"
    if not folder.is_dir():
        print("6. Clementine: shared kernel set absent, skipped")
        return
    from lunarmap.missions.clementine import adjust_multi_orbit, clementine_multi_orbit, uvvis_interior

    io = uvvis_interior(folder / "LUA3107H.161_isis3.lbl", folder / "clementine_uvvis_LUA3107H161.tm")
    figs = []
    t0 = time.perf_counter()
    for seed in range(seeds):
        figs.append(adjust_multi_orbit(clementine_multi_orbit(io, seed=seed))[1])
    dt = (time.perf_counter() - t0) / seeds
    f0 = figs[0]
    print(f"6. Clementine multi-orbit, real UVVIS IK ({io.focal_length} mm, OD_K {io.distortion_coefficients['coefficients']}):"
          f" {f0['images']} images, {f0['points']} points, {f0['observations']} observations, {dt:.1f} s per block")
    print(f"   seed 0: sigma0 {f0['sigma0']:.3f}; check points E/N/U RMS {np.round(f0['check_rms_before_m'])} m -> "
          f"{np.round(f0['check_rms_after_m'])} m, errors/sigma {f0['check_z_rms']:.2f}")
    keys = ("sigma0", "points_z_rms", "images_z_rms", "offsets_drifts_z_rms", "offsets_drifts_within_2_sigma")
    print("   over {} blocks: ".format(seeds) + ", ".join(
        f"{k} {np.mean([f[k] for f in figs]):.3f} ({min(f[k] for f in figs):.3f}-{max(f[k] for f in figs):.3f})"
        for k in keys))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=5, help="Monte Carlo runs of the Ranger and Clementine figures")
    args = p.parse_args(argv)
    print(f"load average at start: {', '.join(f'{v:.2f}' for v in os.getloadavg())}")
    five_rotations()
    ranger(args.seeds)
    reseau()
    ranger_kernels()
    film_cameras()
    clementine(args.seeds)
    print(f"load average at end: {', '.join(f'{v:.2f}' for v in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
