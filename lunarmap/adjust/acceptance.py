"""Acceptance figures of the simulated blocks (``python -m lunarmap.adjust.acceptance``).

* LROC-like RFM block (:mod:`.simulate_rfm_block`): check-point RMS along-track / cross-track /
  height before and after the affine adjustment, and the noise-only expectation from the
  posterior covariance.
* Clementine-like navigation block (:mod:`.simulate_block`): sigma0, whitened and marginal
  normalised errors of points, image parameters and offsets/drifts, for one block and pooled
  over a Monte Carlo of blocks.
"""

from __future__ import annotations

import numpy as np

from .simulate_block import simulate_frame_block
from .simulate_rfm_block import check_point_errors, simulate_rfm_block
from .solver import SolverOptions, solve

__all__ = ["rfm_block_figures", "navigation_block_figures"]


def rfm_block_figures(seed: int = 0, **kw) -> dict:
    """Check-point RMS (metres; along, cross, height) before/after and expected, sigma0, z RMS."""
    sb = simulate_rfm_block(seed=seed, **kw)
    before = check_point_errors(sb, sb.problem.points)
    res = solve(sb.problem, SolverOptions(ftol=1e-10))
    after = check_point_errors(sb, res.points, res.precision().pt_cov)
    return {"sigma0": res.sigma0, "before_rms_m": before["rms"], "after_rms_m": after["rms"],
            "expected_rms_m": after["expected"], "check_z_rms": float(np.sqrt(np.mean(after["z"] ** 2))),
            "n_check": int(sb.check.size)}


def navigation_block_figures(seed: int = 1, **kw) -> dict:
    """sigma0 and normalised errors of one Clementine-like block (dimensionless)."""
    sb = simulate_frame_block(orbits=4, per_orbit=12, points=1500, seed=seed, **kw)
    res = solve(sb.problem, SolverOptions(ftol=1e-9))
    prec = res.precision()
    e_c = res.cam_params - sb.true_params
    e_x = res.extra - np.concatenate([sb.true_offsets.ravel(), sb.true_drifts.ravel()])
    e_p = res.points - sb.true_points
    nc = e_c.size
    joint = float(np.sqrt(e_c.ravel() @ np.linalg.solve(prec.Q_red[:nc, :nc] * res.sigma0 ** 2, e_c.ravel()) / nc))
    z_c = e_c / np.sqrt(np.diagonal(prec.cam_cov, axis1=1, axis2=2))
    free = sb.navigation.extra_free()
    z_x = e_x[free] / np.sqrt(np.diag(prec.extra_cov))[free]
    z_p = e_p / np.sqrt(np.diagonal(prec.pt_cov, axis1=1, axis2=2))
    # How much the images (not the offset/drift priors) determine the offsets and drifts:
    # posterior / prior sigma per parameter (w_x, w_y, w_z, C_x, C_y, C_z), mean over orbits.
    nav = sb.navigation
    se = np.sqrt(np.diag(prec.extra_cov))
    with np.errstate(divide="ignore", invalid="ignore"):
        off_ratio = (nav.offsets(se) / nav.offset_sigma).mean(axis=0)
        dr_ratio = (nav.drifts(se) / nav.drift_sigma).mean(axis=0)
    return {"sigma0": res.sigma0, "points_z_rms": float(np.sqrt(np.mean(z_p ** 2))),
            "images_z_rms_marginal": float(np.sqrt(np.mean(z_c ** 2))), "images_z_rms_whitened": joint,
            "offdrift_z_rms": float(np.sqrt(np.mean(z_x ** 2))), "offdrift_max_abs_z": float(np.max(np.abs(z_x))),
            "offdrift_within_2sigma": float(np.mean(np.abs(z_x) < 2)), "_z": (z_c.ravel(), z_x),
            "_posterior_over_prior": (off_ratio, dr_ratio),
            "_block": {"images": sb.problem.n_images, "points": sb.problem.n_points, "observations": sb.problem.obs.n,
                       "control_points": 0 if sb.problem.priors is None else int(sb.problem.priors.idx.size),
                       "iterations": res.iterations, "rms_px": res.rms_px(),
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
    print(f"  posterior/prior sigma (w_x w_y w_z C_x C_y C_z): offsets {off_r}, drifts {dr_r}")
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
