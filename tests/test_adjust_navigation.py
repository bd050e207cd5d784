"""Clementine-like block with navigation observations, per-orbit offset and drift (simulation with known truth)."""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.adjust import SolverOptions, solve
from lunarmap.adjust.simulate_block import simulate_frame_block
from lunarmap.adjust.solver import _Terms, linearize


@pytest.mark.slow
def test_block_with_navigation_recovers_truth_consistently_with_sigma():
    sb = simulate_frame_block(orbits=4, per_orbit=12, points=1500, seed=1)
    pb = sb.problem
    res = solve(pb, SolverOptions(ftol=1e-9))
    assert res.converged
    assert abs(res.sigma0 - 1.0) < 0.05            # image noise 0.3 px given as sigma 0.3 px
    # whitened errors: z = L^T (x_hat - x_true), N = L L^T; independent N(0, 1) if sigmas are right
    lin = linearize(pb, res.state, res.structure, _Terms(pb), pb.point_fixed())
    e_c = (res.cam_params - sb.true_params)
    e_x = res.extra - np.concatenate([sb.true_offsets.ravel(), sb.true_drifts.ravel()])
    e_p = res.points - sb.true_points
    # ||J e||^2 = e^T N e without forming N: image part + navigation part + control part
    Je_img = np.einsum("nki,ni->nk", lin.Ac, e_c[pb.obs.cam_idx]) + np.einsum("nki,ni->nk", lin.Ap,
                                                                              e_p[pb.obs.pt_idx])
    Je_nav = lin.Jx @ np.concatenate([e_c.ravel(), e_x])
    pr_ = pb.priors
    Je_ctl = e_p[pr_.idx] / pr_.sigma
    u = pb.n_unknowns()
    chi2 = (np.sum(Je_img ** 2) + np.sum(Je_nav ** 2) + np.sum(Je_ctl ** 2)) / res.sigma0 ** 2
    rms_z = np.sqrt(chi2 / u)
    assert abs(rms_z - 1.0) < 0.1
    prec = res.precision()
    nav = sb.navigation
    se = np.sqrt(np.diag(prec.extra_cov))
    z_off = (nav.offsets(res.extra) - sb.true_offsets) / nav.offsets(se)
    z_dr = (nav.drifts(res.extra) - sb.true_drifts) / nav.drifts(se)
    z = np.concatenate([z_off.ravel(), z_dr.ravel()])
    assert abs(z.mean()) < 0.5
    assert np.mean(np.abs(z) < 2) >= 0.8
    # points: per-coordinate normalised errors
    zp = (e_p / np.sqrt(np.diagonal(prec.pt_cov, axis1=1, axis2=2))).ravel()
    assert abs(np.sqrt(np.mean(zp ** 2)) - 1) < 0.15
    # group quadratic forms add up to the total cost
    q = res.group_quadratic_forms()
    assert sum(v for v, _ in q.values()) == pytest.approx(2 * res.cost, rel=1e-9)
