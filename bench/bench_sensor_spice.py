"""Line-scan sensor model throughput vs per-point SPICE loops (a script, not a test).

Writes the synthetic mission, builds the 52,224-line x 5,064-sample SIM_NAC
image ``sim_nac_equator`` through the driver (SPICE sampled once), then times,
in the same run:

* lunarmap ``image_to_ground`` and ``ground_to_image`` on ``--points`` points;
* baseline image-to-ground: one ``spiceypy.sincpt`` call per point;
* baseline ground-to-image: per point, secant iterations on the image line, each
  step one ``spkezr`` + one ``pxform`` (what a per-point SPICE implementation does).

Prints one JSON line with points/s and ratios. Usage::

    python bench/bench_sensor_spice.py [--points 1000000] [--baseline-points 2000]
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time

import numpy as np
import spiceypy

from lunarmap.camera.factory import camera_from_isd
from lunarmap.labels import load_label
from lunarmap.orientation.drivers import image_support
from lunarmap.spice import KernelSet, kernels
from lunarmap.synthetic import write_mission


def _ik(ikid, key):
    return np.asarray(spiceypy.gdpool(f"INS{ikid}_{key}", 0, 10), dtype=float)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--baseline-points", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    folder = tempfile.mkdtemp(prefix="lunarmap-bench-")
    mk = write_mission(folder)
    label = f"{folder}/sim_nac_equator.lbl"
    t = time.perf_counter()
    isd = image_support(label, mk)
    t_sample = time.perf_counter() - t
    cam = camera_from_isd(isd, distortion=False)  # pinhole, so both sides compute the same thing
    rng = np.random.default_rng(args.seed)
    n = args.points
    lines = rng.uniform(0, isd.image_lines, n)
    samples = rng.uniform(0, isd.image_samples, n)

    t = time.perf_counter()
    xyz = cam.image_to_ground(lines, samples)
    t_i2g = time.perf_counter() - t
    t = time.perf_counter()
    l2, s2 = cam.ground_to_image(xyz)
    t_g2i = time.perf_counter() - t
    rt = float(np.nanmax(np.hypot(l2 - lines, s2 - samples)))
    n_nan = int(np.isnan(l2).sum())

    inst = load_label(label)["IsisCube"]["Instrument"]
    m = args.baseline_points
    with kernels(KernelSet.from_metakernel(mk)):
        ikid = -990100
        f = _ik(ikid, "FOCAL_LENGTH")[0]
        itranss, itransl = _ik(ikid, "ITRANSS"), _ik(ikid, "ITRANSL")
        bs = _ik(ikid, "BORESIGHT_SAMPLE")[0] - 0.5
        start = spiceypy.scs2e(-990, str(inst["SpacecraftClockStartCount"]))
        dt = float(inst["LineExposureDuration"]) * 1e-3
        # focal plane of sample S on the detector line: solve the IK affine
        a = np.array([[itransl[1], itransl[2]], [itranss[1], itranss[2]]])

        # focal-plane coordinates for all baseline points at once: the loop then times SPICE only
        xy = np.linalg.solve(a, np.stack([np.full(m, -itransl[0]), samples[:m] - bs - itranss[0]]))
        dirs = np.column_stack([xy[0], xy[1], np.full(m, f)]).tolist()
        ets = (start + lines[:m] * dt).tolist()
        t = time.perf_counter()
        base_xyz = np.empty((m, 3))
        for i in range(m):
            base_xyz[i] = spiceypy.sincpt("ELLIPSOID", "MOON", ets[i], "IAU_MOON", "NONE",
                                          "LUNARMAP-SIM", "SIM_NAC", dirs[i])[0]
        t_base_i2g = time.perf_counter() - t
        i2g_agree_mm = float(np.abs(base_xyz * 1000.0 - xyz[:m]).max() * 1000.0)

        def residual(line, p):
            et = start + line * dt
            pos = spiceypy.spkezr("LUNARMAP-SIM", et, "IAU_MOON", "NONE", "MOON")[0][:3]
            v = np.asarray(spiceypy.pxform("IAU_MOON", "SIM_NAC", et)) @ (p - np.asarray(pos))
            x, y = f * v[0] / v[2], f * v[1] / v[2]
            return itransl[0] + itransl[1] * x + itransl[2] * y, itranss[0] + itranss[1] * x + itranss[2] * y + bs

        t = time.perf_counter()
        base_lines = np.empty(m)
        for i in range(m):
            p = xyz[i] / 1000.0
            l0, l1 = 0.0, float(isd.image_lines)
            r0, r1 = residual(l0, p)[0], residual(l1, p)[0]
            for _ in range(30):
                if r1 == r0 or abs(r1) < 1e-9:
                    break
                l2_ = l1 - r1 * (l1 - l0) / (r1 - r0)
                l0, r0 = l1, r1
                l1, r1 = l2_, residual(l2_, p)[0]
                if abs(l1 - l0) < 1e-6:
                    break
            base_lines[i] = l1
        t_base_g2i = time.perf_counter() - t
        g2i_agree_px = float(np.abs(base_lines - lines[:m]).max())

    out = {
        "image": "sim_nac_equator 52224x5064", "points": n, "spice_sampling_s": round(t_sample, 3),
        "image_to_ground_pts_per_s": round(n / t_i2g), "ground_to_image_pts_per_s": round(n / t_g2i),
        "round_trip_max_px": rt, "round_trip_nan": n_nan,
        "baseline_points": m,
        "baseline_sincpt_pts_per_s": round(m / t_base_i2g),
        "baseline_spkezr_pxform_g2i_pts_per_s": round(m / t_base_g2i),
        "ratio_image_to_ground": round((n / t_i2g) / (m / t_base_i2g), 1),
        "ratio_ground_to_image": round((n / t_g2i) / (m / t_base_g2i), 1),
        "baseline_agreement_i2g_mm": i2g_agree_mm, "baseline_agreement_g2i_px": g2i_agree_px,
        "python": platform.python_version(), "numpy": np.__version__, "spiceypy": spiceypy.__version__,
    }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
