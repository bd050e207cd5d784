"""RFM + per-image affine correction (LROC study Eq. 13): model vs closed form and finite differences,
and a synthetic LROC-like 7-image block whose check points come down to the noise level."""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.adjust import BundleProblem, SolverOptions, solve
from lunarmap.adjust.rfm_affine import AffineRFMModel
from lunarmap.adjust.simulate_rfm_block import check_point_errors, simulate_rfm_block


@pytest.fixture(scope="module")
def block():
    return simulate_rfm_block(seed=0)


def _random_params(rng, n):
    return np.column_stack([rng.normal(0, 5, n), rng.normal(0, 1e-3, n), rng.normal(0, 1e-3, n),
                            rng.normal(0, 5, n), rng.normal(0, 1e-3, n), rng.normal(0, 1e-3, n)])


def test_eq13_closed_form_and_zero_correction(block):
    model = AffineRFMModel(block.rfms, origin="image")
    X = block.true_points[:5]
    cam = np.full(5, 2)
    r, c = block.rfms[2].ground_to_image_xyz(X)
    assert np.allclose(model.project(model.initial_params(), cam, X), np.column_stack([r, c]), atol=1e-9)
    p = np.zeros((model.n_images, 6))
    p[2] = [1.5, 2e-4, -3e-4, -0.7, 1e-4, 5e-4]
    # Eq. 13 literally: r = r' + p_r0 + p_r1 c' + p_r2 r', c = c' + p_c0 + p_c1 c' + p_c2 r'
    want = np.column_stack([r + 1.5 + 2e-4 * c - 3e-4 * r, c - 0.7 + 1e-4 * c + 5e-4 * r])
    assert np.allclose(model.project(p, cam, X), want, atol=1e-9)


@pytest.mark.parametrize("origin", ["center", "image"])
def test_jacobians_match_finite_differences(block, origin):
    rng = np.random.default_rng(3)
    model = AffineRFMModel(block.rfms, origin=origin)
    params = _random_params(rng, model.n_images)
    o = block.problem.obs
    cam, X = o.cam_idx[:40], block.true_points[o.pt_idx[:40]]
    x, Jc, Jp = model.linearize(params, cam, X)
    assert np.allclose(x, model.project(params, cam, X))
    for k in range(3):
        h = np.zeros(3)
        h[k] = 0.01   # metres
        fd = (model.project(params, cam, X + h) - model.project(params, cam, X - h)) / 0.02
        assert np.allclose(Jp[:, :, k], fd, rtol=1e-6, atol=1e-8)
    for k in range(6):
        step = 1e-3 if k in (0, 3) else 1e-7
        dp = np.zeros_like(params)
        dp[:, k] = step
        fd = (model.project(params + dp, cam, X) - model.project(params - dp, cam, X)) / (2 * step)
        assert np.allclose(Jc[:, :, k], fd, rtol=1e-6, atol=1e-6)


def test_initial_points_invert_the_affine(block):
    rng = np.random.default_rng(4)
    model = AffineRFMModel(block.rfms)
    params = _random_params(rng, model.n_images)
    o = block.problem.obs
    X = block.true_points
    xy = model.project(params, o.cam_idx, X[o.pt_idx])
    heights = np.linalg.norm(X, axis=1) - model.radius
    # every ray monoplotted at the true height of its point hits the point; the mean is the point
    for j in range(3):
        m = o.pt_idx == j
        x0 = model.initial_points(params, o.cam_idx[m], np.zeros(m.sum(), np.int64), xy[m], 1,
                                  height=heights[j])
        assert np.allclose(x0[0], X[j], atol=1e-3)


def test_origin_choice_is_a_reparameterisation(block):
    pb = block.problem
    out = []
    for origin in ("center", "image"):
        model = AffineRFMModel(block.rfms, origin=origin)
        p = BundleProblem(model, model.initial_params(), pb.points, pb.obs, pb.priors)
        out.append(solve(p, SolverOptions(ftol=1e-12)))
    assert out[0].sigma0 == pytest.approx(out[1].sigma0, rel=1e-6)
    assert np.allclose(out[0].points, out[1].points, atol=1e-4)


def test_affine_adjustment_brings_check_points_to_noise_level(block):
    pb = block.problem
    before = check_point_errors(block, pb.points)
    res = solve(pb, SolverOptions(ftol=1e-10))
    assert res.converged
    assert abs(res.sigma0 - 1.0) < 0.1          # 0.3 px noise given as sigma 0.3 px: the model fits
    prec = res.precision()
    after = check_point_errors(block, res.points, prec.pt_cov)
    # navigation errors of tens of metres (tens of pixels) before the adjustment
    assert np.all(before["rms"] > 5.0)
    assert np.all(before["rms"] > 20 * after["rms"])
    assert np.all(after["expected"] < 0.6)       # metres; GSD ~0.5 m
    # oracle 1: the same block with error-free RFMs (identical noise draws) - what is left after the
    # affine adjustment is the image and control noise, not the navigation errors
    clean = simulate_rfm_block(seed=0, pos_sigma=0.0, att_sigma=0.0, att_drift_sigma=0.0)
    assert np.array_equal(clean.problem.obs.xy, pb.obs.xy)
    res0 = solve(clean.problem, SolverOptions(ftol=1e-10))
    assert np.max(np.abs(res.points[block.check] - res0.points[block.check])) < 0.02   # metres
    # oracle 2: the errors are consistent with the posterior sigma.  Within one block they are mostly
    # one common datum shift (control-point noise), so this is ~1 sample per component: loose bound here,
    # the statistical check is the Monte Carlo test below
    assert abs(np.sqrt(np.mean(after["z"] ** 2)) - 1.0) < 0.4


@pytest.mark.slow
def test_check_point_errors_match_posterior_sigma_monte_carlo():
    # 10 blocks x 15 check points; the common datum shift of each block makes the 10 blocks the
    # effective samples: RMS of 30 (blocks x components) N(0,1) values is within 1 +- 0.25 (> 99 %)
    zs = []
    for seed in range(10):
        sb = simulate_rfm_block(seed=seed)
        res = solve(sb.problem, SolverOptions(ftol=1e-10))
        zs.append(check_point_errors(sb, res.points, res.precision().pt_cov)["z"])
    z = np.concatenate(zs)
    assert abs(np.sqrt(np.mean(z ** 2)) - 1.0) < 0.25
    assert np.all(np.abs(np.sqrt(np.mean(z ** 2, axis=0)) - 1.0) < 0.35)


def test_control_points_are_needed_for_the_datum(block):
    from lunarmap.errors import DatumDefectError

    pb = block.problem
    p = BundleProblem(pb.model, pb.cam_params, pb.points, pb.obs, None)
    with pytest.raises(DatumDefectError):
        solve(p)
