"""RFM + per-image affine correction (LROC study Eq. 13) through the sensor-model interface: the origin
choice is a reparameterisation, and a synthetic LROC-like 7-image block brings its check points down to
the noise level (oracle: the same block with error-free RFMs and identical noise draws)."""

from __future__ import annotations

import numpy as np
import pytest

from blockhelp import check_errors, rfm_case
from lunarmap.adjust import BundleProblem, SensorImageModel, SolverOptions, solve
from lunarmap.camera.sensor import SensorModel


@pytest.fixture(scope="module")
def block():
    return rfm_case(seed=0)


def test_rfms_are_sensor_models_and_zero_corrections_reproduce_them(block):
    assert all(isinstance(r, SensorModel) for r in block.rfms)
    model = block.problem.model
    X = block.true_points[:5]
    r, c = block.rfms[2].ground_to_image(X, within_image=False)
    np.testing.assert_allclose(model.project(model.initial_params(), np.full(5, 2), X), np.column_stack([r, c]),
                               atol=1e-9)


def test_initial_points_from_rays_of_corrected_rfms(block):
    model = block.problem.model
    o = block.problem.obs
    rng = np.random.default_rng(4)
    params = np.column_stack([rng.normal(0, 5, 7), rng.normal(0, 1e-4, 7), rng.normal(0, 1e-4, 7),
                              rng.normal(0, 5, 7), rng.normal(0, 1e-4, 7), rng.normal(0, 1e-4, 7)])
    X = block.true_points
    xy = model.project(params, o.cam_idx, X[o.pt_idx])
    x0 = model.initial_points(params, o.cam_idx, o.pt_idx, xy, X.shape[0])
    # rays through exact measurements of the corrected RFMs meet at the points (RFM rays are the
    # lines between the ground points at the top and bottom of the height range)
    assert np.max(np.linalg.norm(x0 - X, axis=1)) < 0.05


def test_origin_choice_is_a_reparameterisation(block):
    pb = block.problem
    out = []
    for origin in ("center", "image"):
        model = SensorImageModel(block.rfms, corrections=[r.corrections(origin=origin) for r in block.rfms])
        p = BundleProblem(model, model.initial_params(), pb.points, pb.obs, pb.priors)
        out.append(solve(p, SolverOptions(ftol=1e-12)))
    assert out[0].sigma0 == pytest.approx(out[1].sigma0, rel=1e-6)
    assert np.allclose(out[0].points, out[1].points, atol=1e-4)


def test_affine_adjustment_brings_check_points_to_noise_level(block):
    pb = block.problem
    before = check_errors(block.true_points, block.check, pb.points)
    res = solve(pb, SolverOptions(ftol=1e-10))
    assert res.converged
    assert abs(res.sigma0 - 1.0) < 0.1          # 0.3 px noise given as sigma 0.3 px: the model fits
    prec = res.precision()
    after = check_errors(block.true_points, block.check, res.points, prec.pt_cov)
    assert np.all(before["rms"] > 5.0)          # navigation errors of tens of metres
    assert np.all(before["rms"] > 20 * after["rms"])
    assert np.all(after["expected"] < 0.6)      # metres; GSD ~0.5 m
    clean = rfm_case(seed=0, pos_sigma=0.0, att_sigma=0.0, att_drift_sigma=0.0)
    assert np.array_equal(clean.problem.obs.xy, pb.obs.xy)
    res0 = solve(clean.problem, SolverOptions(ftol=1e-10))
    assert np.max(np.abs(res.points[block.check] - res0.points[block.check])) < 0.02   # metres
    assert abs(np.sqrt(np.mean(after["z"] ** 2)) - 1.0) < 0.4
    # adjusted sensors: RFMs followed by their affine correction, projecting like the model
    adjusted = pb.model.adjusted(res.cam_params)
    X = res.points[pb.obs.pt_idx]
    for i, s in enumerate(adjusted):
        m = pb.obs.cam_idx == i
        li, sa = s.ground_to_image(X[m], within_image=False)
        np.testing.assert_allclose(np.column_stack([li, sa]), pb.model.project(res.cam_params, pb.obs.cam_idx[m], X[m]),
                                   atol=1e-9)


@pytest.mark.slow
def test_check_point_errors_match_posterior_sigma_monte_carlo():
    zs = []
    for seed in range(10):
        case = rfm_case(seed=seed)
        res = solve(case.problem, SolverOptions(ftol=1e-10))
        zs.append(check_errors(case.true_points, case.check, res.points, res.precision().pt_cov)["z"])
    z = np.concatenate(zs)
    assert abs(np.sqrt(np.mean(z ** 2)) - 1.0) < 0.25
    assert np.all(np.abs(np.sqrt(np.mean(z ** 2, axis=0)) - 1.0) < 0.35)


def test_control_points_are_needed_for_the_datum(block):
    from lunarmap.errors import DatumDefectError

    pb = block.problem
    p = BundleProblem(pb.model, pb.cam_params, pb.points, pb.obs, None)
    with pytest.raises(DatumDefectError):
        solve(p)
