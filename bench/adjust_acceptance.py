"""Acceptance figures of the simulated adjustment blocks (``python bench/adjust_acceptance.py``).

* LROC-like RFM block: RFMs fitted to NAC-like navigation cameras (``lrolrocnac`` distortion) of 7
  images of one site, affine corrections (``seeds/001`` Eq. 13): check-point RMS along-track /
  cross-track / height before and after, and the noise-only expectation from the posterior covariance.
* Clementine-like navigation block (:func:`lunarmap.simulate.frame_block`: rigorous frame cameras
  with ``radial`` OD_K distortion, DLR paper set-up): sigma0, normalised errors of points, image
  parameters and offsets/drifts, for one block and pooled over 12 blocks.

Problems are built with the public API from the simulations' plain data (``tests/blockhelp.py``).
"""

from __future__ import annotations

import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))

from blockhelp import check_errors, frame_case, rfm_case  # noqa: E402
from lunarmap.adjust import SolverOptions, solve  # noqa: E402

__all__ = ["rfm_block_figures", "navigation_block_figures"]


def rfm_block_figures(seed: int = 0) -> dict:
    """Check-point RMS (metres; along, cross, height) before/after and expected, sigma0, z RMS."""
    case = rfm_case(seed=seed)
    pb = case.problem
    before = check_errors(case.true_points, case.check, pb.points)
    res = solve(pb, SolverOptions(ftol=1e-10))
    after = check_errors(case.true_points, case.check, res.points, res.precision().pt_cov)
    return {"sigma0": res.sigma0, "before_rms_m": before["rms"], "after_rms_m": after["rms"],
            "expected_rms_m": after["expected"], "check_z_rms": float(np.sqrt(np.mean(after["z"] ** 2))),
            "n_check": int(case.check.size)}


def navigation_block_figures(seed: int = 1) -> dict:
    """sigma0 and normalised errors of one Clementine-like block (dimensionless)."""
    case = frame_case(orbits=4, per_orbit=12, points=1500, seed=seed)
    res = solve(case.problem, SolverOptions(ftol=1e-9))
    prec = res.precision()
    e_c = res.cam_params - case.true_params
    e_x = res.extra - np.concatenate([case.true_offsets.ravel(), case.true_drifts.ravel()])
    e_p = res.points - case.true_points
    nc = e_c.size
    joint = float(np.sqrt(e_c.ravel() @ np.linalg.solve(prec.Q_red[:nc, :nc] * res.sigma0 ** 2, e_c.ravel()) / nc))
    z_c = e_c / np.sqrt(np.diagonal(prec.cam_cov, axis1=1, axis2=2))
    nav = case.navigation
    free = nav.extra_free()
    z_x = e_x[free] / np.sqrt(np.diag(prec.extra_cov))[free]
    z_p = e_p / np.sqrt(np.diagonal(prec.pt_cov, axis1=1, axis2=2))
    se = np.sqrt(np.diag(prec.extra_cov))
    with np.errstate(divide="ignore", invalid="ignore"):
        off_ratio = (nav.offsets(se) / nav.offset_sigma).mean(axis=0)
        dr_ratio = (nav.drifts(se) / nav.drift_sigma).mean(axis=0)
    return {"sigma0": res.sigma0, "points_z_rms": float(np.sqrt(np.mean(z_p ** 2))),
            "images_z_rms_marginal": float(np.sqrt(np.mean(z_c ** 2))), "images_z_rms_whitened": joint,
            "offdrift_z_rms": float(np.sqrt(np.mean(z_x ** 2))), "offdrift_max_abs_z": float(np.max(np.abs(z_x))),
            "offdrift_within_2sigma": float(np.mean(np.abs(z_x) < 2)), "_z": (z_c.ravel(), z_x),
            "_posterior_over_prior": (off_ratio, dr_ratio),
            "_block": {"images": case.problem.n_images, "points": case.problem.n_points,
                       "observations": case.problem.obs.n, "iterations": res.iterations, "rms_px": res.rms_px(),
                       "point_error_median_m": float(np.median(np.linalg.norm(e_p, axis=1)))}}


def _main() -> None:
    np.set_printoptions(precision=3, suppress=True)
    r = rfm_block_figures()
    print("LROC-like RFM block (7 NAC-like images, 0.3 px tie noise, seed 0):")
    print(f"  sigma0 {r['sigma0']:.3f}; {r['n_check']} check points, RMS along/cross/height (m)")
    print(f"  before {r['before_rms_m']}  after {r['after_rms_m']}  noise-only expected {r['expected_rms_m']}"
          f"  (z RMS {r['check_z_rms']:.2f})")
    n = navigation_block_figures()
    print("Clementine-like navigation block (4 orbits x 12 images, seed 1, observed offsets/drifts):")
    print("  " + ", ".join(f"{k} {v:.3f}" for k, v in n.items() if not k.startswith("_")))
    off_r, dr_r = n["_posterior_over_prior"]
    print(f"  posterior/prior sigma (w_x w_y w_z c_x c_y c_z): offsets {off_r}, drifts {dr_r}")
    zc, zx = [], []
    for seed in range(12):
        f = navigation_block_figures(seed)
        zc.append(f["_z"][0])
        zx.append(f["_z"][1])
    zc, zx = np.concatenate(zc), np.concatenate(zx)
    print(f"  pooled over 12 blocks: images z RMS {np.sqrt(np.mean(zc ** 2)):.3f}, offsets/drifts z RMS "
          f"{np.sqrt(np.mean(zx ** 2)):.3f}, max |z| {np.max(np.abs(zx)):.2f}, within 2 sigma "
          f"{np.mean(np.abs(zx) < 2):.3f}")


if __name__ == "__main__":
    _main()
