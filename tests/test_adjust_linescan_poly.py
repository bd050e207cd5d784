"""Line-scan model with polynomial position/attitude corrections: vs the rigorous LineScanCamera, finite
differences, the closed-form truth of the simulated navigation errors, and a small adjusted block."""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.adjust import SolverOptions, solve
from lunarmap.adjust.linescan_poly import LineScanPolyModel
from lunarmap.adjust.simulate_linescan_block import simulate_linescan_block
from lunarmap.adjust.simulate_rfm_block import _camera, check_point_errors
from lunarmap.camera.geodesy import lonlat_height_to_xyz
from lunarmap.errors import AdjustmentInputError


@pytest.fixture(scope="module")
def points_and_camera():
    cam = _camera(30.0, 20.0, 8.0, 50e3, 3000, 1500, k1=None)
    rng = np.random.default_rng(0)
    g = cam.image_to_ground(rng.uniform(50, 2950, 60), rng.uniform(50, 1450, 60), 0.0)
    from lunarmap.camera.geodesy import xyz_to_lonlat_height

    lon, lat, _ = xyz_to_lonlat_height(g)
    X = lonlat_height_to_xyz(lon, lat, rng.uniform(-300, 300, 60))
    return cam, X


@pytest.mark.parametrize("degree", [0, 1, 2])
def test_zero_corrections_equal_the_rigorous_camera(points_and_camera, degree):
    cam, X = points_and_camera
    m = LineScanPolyModel([cam], degree)
    assert m.n_params == 6 * (degree + 1)
    li, sa = cam.ground_to_image(X, within_image=False)
    xy = m.project(m.initial_params(), np.zeros(len(X), np.int64), X)
    assert np.max(np.abs(xy - np.column_stack([li, sa]))) < 1e-6


def test_jacobians_match_finite_differences(points_and_camera):
    cam, X = points_and_camera
    m = LineScanPolyModel([cam, cam], 2)
    rng = np.random.default_rng(1)
    p = rng.normal(0, 1, (2, 18)) * np.tile([1e-4] * 3 + [5.0] * 3, 3)
    ci = np.repeat([0, 1], len(X) // 2)
    x, Jc, Jp = m.linearize(p, ci, X)
    assert np.allclose(x, m.project(p, ci, X), atol=1e-9)
    for k in range(3):
        h = np.zeros(3)
        h[k] = 0.01
        fd = (m.project(p, ci, X + h) - m.project(p, ci, X - h)) / 0.02
        assert np.allclose(Jp[:, :, k], fd, rtol=1e-6, atol=1e-7)
    for k in range(18):
        # steps well above the 1e-9-line Newton tolerance of the projection (FD noise ~1e-9 / step)
        st = 1e-5 if k % 6 < 3 else 1e-2
        d = np.zeros_like(p)
        d[:, k] = st
        fd = (m.project(p + d, ci, X) - m.project(p - d, ci, X)) / (2 * st)
        # relative to the column's scale: some entries are ~1e-5 of it (a roll barely moves the line)
        assert np.allclose(Jc[:, :, k], fd, rtol=1e-5, atol=1e-6 * np.abs(fd).max())


@pytest.fixture(scope="module")
def block():
    return simulate_linescan_block(seed=0)


def test_true_parameters_reproduce_the_true_cameras(block):
    pb = block.problem
    o = pb.obs
    xy = pb.model.project(block.true_params, o.cam_idx, block.true_points[o.pt_idx])
    for i, cam in enumerate(block.true_cameras):
        m = o.cam_idx == i
        li, sa = cam.ground_to_image(block.true_points[o.pt_idx[m]])
        assert np.max(np.abs(xy[m] - np.column_stack([li, sa]))) < 1e-6


def test_block_adjustment_recovers_points_and_corrections(block):
    pb = block.problem
    before = check_point_errors(block, pb.points)
    res = solve(pb, SolverOptions(ftol=1e-10))
    assert res.converged
    assert abs(res.sigma0 - 1.0) < 0.15      # ~230 redundant observations: sd ~0.05
    prec = res.precision()
    after = check_point_errors(block, res.points, prec.pt_cov)
    assert np.all(before["rms"] > 2.0)       # metres: navigation errors of tens of metres
    assert np.all(after["rms"] < 2.0 * after["expected"])
    assert np.all(after["expected"] < 0.6)
    # the degree-0 and -1 attitude and degree-0 position corrections vs their closed-form truth
    z = (res.cam_params - block.true_params)[:, :9] / np.sqrt(np.diagonal(prec.cam_cov, axis1=1, axis2=2))[:, :9]
    assert np.max(np.abs(z)) < 3.5           # 27 values, P(any beyond 3.5) ~ 1 %
    assert abs(np.sqrt(np.mean(z ** 2)) - 1.0) < 0.35


@pytest.mark.slow
def test_monte_carlo_check_points_and_parameters():
    # 10 blocks: ~30 effective check-point samples (a common datum shift per block and component),
    # RMS sd ~0.13 -> bound 1 +- 0.35; 270 parameter values (~90 effective) -> bound 1 +- 0.2
    zc, zp = [], []
    for seed in range(10):
        sb = simulate_linescan_block(seed=seed)
        res = solve(sb.problem, SolverOptions(ftol=1e-10))
        prec = res.precision()
        zc.append(check_point_errors(sb, res.points, prec.pt_cov)["z"])
        s = np.sqrt(np.diagonal(prec.cam_cov, axis1=1, axis2=2))
        zp.append(((res.cam_params - sb.true_params) / s)[:, :9])
    zc, zp = np.concatenate(zc), np.concatenate(zp)
    assert abs(np.sqrt(np.mean(zc ** 2)) - 1.0) < 0.35
    assert abs(np.sqrt(np.mean(zp ** 2)) - 1.0) < 0.2


def test_bad_model_inputs(points_and_camera):
    cam, _ = points_and_camera
    with pytest.raises(AdjustmentInputError, match="degree"):
        LineScanPolyModel([cam], 3)
    with pytest.raises(AdjustmentInputError, match="distortion"):
        LineScanPolyModel([_camera(30.0, 20.0, 0.0, 50e3, 3000, 1500)])
    with pytest.raises(AdjustmentInputError, match="at least one"):
        LineScanPolyModel([])
