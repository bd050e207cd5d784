"""Clementine-like block with navigation observations, per-orbit offset and drift (simulation with known truth).

Statistics used (errors ``e = estimate - truth``, posterior covariance ``C = sigma0^2 Q``):

* whitened RMS ``sqrt(e^T C^-1 e / n)`` of a group of n unknowns: a chi-square with n degrees of
  freedom, so its RMS has a standard deviation of ``1 / sqrt(2 n)`` (0.042 for the 288 image
  parameters, 0.01 for all unknowns) whatever the correlations;
* marginal normalised errors ``e_i / sigma_i``: each N(0, 1), but the 288 image parameters of a
  block are driven by a few dozen per-orbit offsets/drifts and each attitude offset is almost
  perfectly correlated with a position offset (rotation about north ~ shift east at 400 km), so
  a single block holds only ~24 independent offset/drift values.  Their RMS and extremes are
  therefore tested over a Monte Carlo of blocks, with thresholds argued below.
"""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.adjust import SolverOptions, solve
from lunarmap.adjust.navigation import NavigationObservations
from blockhelp import frame_case
from lunarmap.errors import AdjustmentInputError

POSITION_ONLY = dict(offset_mode=("fixed",) * 3 + ("free",) * 3, drift_mode=("fixed",) * 3 + ("free",) * 3,
                     offset_att=0.0, drift_att=0.0)


def _errors(sb, res):
    e_c = res.cam_params - sb.true_params
    e_x = res.extra - np.concatenate([sb.true_offsets.ravel(), sb.true_drifts.ravel()])
    e_p = res.points - sb.true_points
    return e_c, e_x, e_p


def _whitened_rms_all(sb, res):
    """sqrt(||J e||^2 / (sigma0^2 u)) with J built here from the model, the navigation term and the priors."""
    pb = sb.problem
    e_c, e_x, e_p = _errors(sb, res)
    o = pb.obs
    _, Jc, Jp = pb.model.linearize(res.cam_params, o.cam_idx, res.points[o.pt_idx])
    Je_img = (np.einsum("nki,ni->nk", Jc, e_c[o.cam_idx]) + np.einsum("nki,ni->nk", Jp, e_p[o.pt_idx])) / o.sigma
    _, Jx = sb.navigation.linearize(res.cam_params, res.extra)
    Je_nav = Jx @ np.concatenate([e_c.ravel(), np.where(sb.navigation.extra_free(), e_x, 0.0)])
    pr = pb.priors
    Je_ctl = e_p[pr.idx] / pr.sigma
    chi2 = (np.sum(Je_img ** 2) + np.sum(Je_nav ** 2) + np.sum(Je_ctl ** 2)) / res.sigma0 ** 2
    return np.sqrt(chi2 / pb.n_unknowns())


def _stats(sb, res, prec):
    e_c, e_x, e_p = _errors(sb, res)
    nc = e_c.size
    Qcc = prec.Q_red[:nc, :nc] * res.sigma0 ** 2
    img_joint = np.sqrt(e_c.ravel() @ np.linalg.solve(Qcc, e_c.ravel()) / nc)
    img_marg = e_c / np.sqrt(np.diagonal(prec.cam_cov, axis1=1, axis2=2))
    free = sb.navigation.extra_free()
    z_x = e_x[free] / np.sqrt(np.diag(prec.extra_cov))[free]
    z_p = e_p / np.sqrt(np.diagonal(prec.pt_cov, axis1=1, axis2=2))
    return img_joint, img_marg.ravel(), z_x, z_p.ravel()


@pytest.mark.slow
def test_block_with_navigation_recovers_truth_consistently_with_sigma():
    sb = frame_case(orbits=4, per_orbit=12, points=1500, seed=1)
    pb = sb.problem
    res = solve(pb, SolverOptions(ftol=1e-9))
    assert res.converged
    assert abs(res.sigma0 - 1.0) < 0.05            # image noise 0.3 px given as sigma 0.3 px
    assert abs(_whitened_rms_all(sb, res) - 1.0) < 0.1
    prec = res.precision()
    img_joint, img_marg, z_x, z_p = _stats(sb, res, prec)
    assert abs(img_joint - 1.0) < 0.13             # 288 image parameters, sd 0.042: 3 sd (1 +- 0.1 pooled below)
    assert abs(np.sqrt(np.mean(z_p ** 2)) - 1.0) < 0.1
    # offsets/drifts of one block: ~24 independent values; P(any beyond 3.5 sigma) ~ 24 * 4.7e-4 = 1 %
    assert abs(z_x.mean()) < 0.5
    assert np.mean(np.abs(z_x) < 2) >= 0.8
    assert np.max(np.abs(z_x)) < 3.5
    # group quadratic forms add up to the total cost
    q = res.group_quadratic_forms()
    assert sum(v for v, _ in q.values()) == pytest.approx(2 * res.cost, rel=1e-9)


@pytest.mark.slow
@pytest.mark.parametrize("modes", [{}, POSITION_ONLY], ids=["observed_offsets", "free_position_offsets"])
def test_monte_carlo_normalised_errors(modes):
    # 12 blocks: 12 x 288 image parameters (~12 x 24 = 290 independent values) and 12 x 48 (resp. 24)
    # offsets/drifts (~290 resp. 290 independent values).  For n independent N(0, 1) the RMS has sd
    # 1/sqrt(2n) = 0.04, so 1 +- 0.1 is a 2.4-sd bound; the fraction within 2 sigma has mean 0.954 and
    # sd sqrt(0.046 * 0.954 / n) = 0.012, so ">= 95 %" would fail for ~40 % of correct set-ups: the bound
    # is 0.92 (3 sd); P(any of ~290 beyond 4 sigma) ~ 2 %.
    zi, zx, s0 = [], [], []
    for seed in range(12):
        sb = frame_case(orbits=4, per_orbit=12, points=1500, seed=seed, **modes)
        res = solve(sb.problem, SolverOptions(ftol=1e-9))
        assert res.converged
        img_joint, img_marg, z_x, _ = _stats(sb, res, res.precision())
        assert abs(img_joint - 1.0) < 0.15         # per block, 288 dof: 3.5 sd
        zi.append(img_marg)
        zx.append(z_x)
        s0.append(res.sigma0)
    zi, zx = np.concatenate(zi), np.concatenate(zx)
    assert abs(np.mean(s0) - 1.0) < 0.02
    assert abs(np.sqrt(np.mean(zi ** 2)) - 1.0) < 0.1
    assert abs(np.mean(zi)) < 0.15
    assert abs(np.sqrt(np.mean(zx ** 2)) - 1.0) < 0.1
    assert np.mean(np.abs(zx) < 2.0) >= 0.92
    assert np.max(np.abs(zx)) < 4.0


def test_free_attitude_and_position_offsets_are_not_separable():
    # why "free" for all six offsets and drifts is not the default: the data leave the attitude /
    # position split to perspective, posterior sigma of the positions is ~100x the navigation noise and
    # the estimator leaves the linear regime (errors of several sigma against the linearised covariance)
    sb = frame_case(orbits=2, per_orbit=8, points=400, seed=3, offset_mode="free", drift_mode="free")
    res = solve(sb.problem, SolverOptions(ftol=1e-9))
    prec = res.precision()
    s_pos = np.sqrt(np.diagonal(prec.cam_cov, axis1=1, axis2=2))[:, 3:6]
    assert np.median(s_pos[:, 1:]) > 30 * 10.0     # east/north position sigma vs 10 m navigation noise
    ok = frame_case(orbits=2, per_orbit=8, points=400, seed=3)
    res = solve(ok.problem, SolverOptions(ftol=1e-9))
    s_pos = np.sqrt(np.diagonal(res.precision().cam_cov, axis1=1, axis2=2))[:, 3:6]
    assert np.max(s_pos) < 100.0                   # bounded by the offset sigma (100 m)


def test_per_parameter_offset_modes():
    n, p = 6, 3
    obs = np.zeros((n, p))
    orbit = np.array([0, 0, 0, 1, 1, 1])
    nav = NavigationObservations(obs, 1.0, orbit, np.arange(n, dtype=float), offset=("fixed", "free", "observed"),
                                 drift="observed", offset_sigma=[np.inf, np.inf, 2.0], drift_sigma=0.5)
    free = nav.extra_free()
    assert free[:6].tolist() == [False, True, True] * 2 and free[6:].all()
    # 18 navigation values + 2 orbits x 1 observed offset + 2 orbits x 3 observed drifts
    assert nav.n_obs_scalar == 18 + 2 + 6
    extra = np.arange(12, dtype=float) + 1.0
    r, J = nav.linearize(np.zeros((n, p)), extra)
    assert J.shape == (26, n * p + 12)
    # pseudo-observation rows: observed offset of orbit 1, parameter 2 is extra[5] / 2
    assert r[18 + 1] == pytest.approx(extra[5] / 2.0)
    assert r[20 + 3] == pytest.approx(extra[6 + 3] / 0.5)
    # linear model: residuals equal the Jacobian times the unknowns minus the observations
    assert np.allclose(r, J @ np.concatenate([np.zeros(n * p), extra]))
    with pytest.raises(AdjustmentInputError, match="offset"):
        NavigationObservations(obs, 1.0, orbit, offset=("free", "bogus", "fixed"))
    with pytest.raises(AdjustmentInputError, match="offset_sigma"):
        NavigationObservations(obs, 1.0, orbit, offset="observed")
    with pytest.raises(AdjustmentInputError, match="offset_sigma"):
        NavigationObservations(obs, 1.0, orbit, offset=("observed", "free", "free"), offset_sigma=[0.0, 1, 1])
