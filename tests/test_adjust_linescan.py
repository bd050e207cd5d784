"""Adjustment of NAC-like line-scan cameras (with their lrolrocnac distortion) through their polynomial
position/attitude corrections: the truth of the simulated navigation errors reproduces the true cameras,
and an adjusted block recovers check points and corrections within their posterior sigma."""

from __future__ import annotations

import numpy as np
import pytest

from blockhelp import check_errors, linescan_case
from lunarmap.adjust import SensorImageModel, SolverOptions, solve


@pytest.fixture(scope="module")
def block():
    return linescan_case(seed=0)


def test_cameras_are_distorted(block):
    assert all(c.distortion.name == "lrolrocnac" for c in block.block.nav_cameras)


def test_true_parameters_reproduce_the_true_cameras(block):
    pb = block.problem
    o = pb.obs
    xy = pb.model.project(block.true_params, o.cam_idx, block.true_points[o.pt_idx])
    for i, cam in enumerate(block.block.true_cameras):
        m = o.cam_idx == i
        li, sa = cam.ground_to_image(block.true_points[o.pt_idx[m]])
        assert np.max(np.abs(xy[m] - np.column_stack([li, sa]))) < 1e-6


def test_block_adjustment_recovers_points_and_corrections(block):
    pb = block.problem
    before = check_errors(block.true_points, block.check, pb.points)
    res = solve(pb, SolverOptions(ftol=1e-10))
    assert res.converged
    assert abs(res.sigma0 - 1.0) < 0.15      # ~230 redundant observations: sd ~0.05
    prec = res.precision()
    after = check_errors(block.true_points, block.check, res.points, prec.pt_cov)
    assert np.all(before["rms"] > 2.0)       # metres: navigation errors of tens of metres
    assert np.all(after["rms"] < 2.0 * after["expected"])
    assert np.all(after["expected"] < 0.6)
    # the degree-0 and -1 attitude and degree-0 position corrections vs their closed-form truth
    z = (res.cam_params - block.true_params)[:, :9] / np.sqrt(np.diagonal(prec.cam_cov, axis1=1, axis2=2))[:, :9]
    assert np.max(np.abs(z)) < 3.5           # 27 values, P(any beyond 3.5) ~ 1 %
    assert abs(np.sqrt(np.mean(z ** 2)) - 1.0) < 0.35
    # the adjusted cameras (new objects) project the points as the adjusted model does
    adjusted = pb.model.adjusted(res.cam_params)
    X = res.points[pb.obs.pt_idx]
    for i, cam in enumerate(adjusted):
        m = pb.obs.cam_idx == i
        li, sa = cam.ground_to_image(X[m], within_image=False)
        want = pb.model.project(res.cam_params, pb.obs.cam_idx[m], X[m])
        assert np.max(np.abs(np.column_stack([li, sa]) - want)) < 1e-6


@pytest.mark.slow
def test_monte_carlo_check_points_and_parameters():
    # 10 blocks: ~30 effective check-point samples (a common datum shift per block and component),
    # RMS sd ~0.13 -> bound 1 +- 0.35; 270 parameter values (~90 effective) -> bound 1 +- 0.2
    zc, zp = [], []
    for seed in range(10):
        case = linescan_case(seed=seed)
        res = solve(case.problem, SolverOptions(ftol=1e-10))
        prec = res.precision()
        zc.append(check_errors(case.true_points, case.check, res.points, prec.pt_cov)["z"])
        s = np.sqrt(np.diagonal(prec.cam_cov, axis1=1, axis2=2))
        zp.append(((res.cam_params - case.true_params) / s)[:, :9])
    zc, zp = np.concatenate(zc), np.concatenate(zp)
    assert abs(np.sqrt(np.mean(zc ** 2)) - 1.0) < 0.35
    assert abs(np.sqrt(np.mean(zp ** 2)) - 1.0) < 0.2


def test_mixed_block_pads_frame_images(block):
    """Frame and line-scan images in one model: the frame images' padding columns never move."""
    from lunarmap.simulate.orbits import frame_interior
    from lunarmap.simulate.stereo import pointed_camera

    frame = pointed_camera("frame", 30.0, 20.0, 5.0, interior=frame_interior())
    model = SensorImageModel(block.block.nav_cameras + [frame], degree=1)
    assert model.n_params == 12
    mask = model.param_mask
    assert mask[:3].all() and mask[3, :6].all() and not mask[3, 6:].any()
    assert model.param_names_of(3) == ("w_x", "w_y", "w_z", "c_x", "c_y", "c_z")
    X = block.true_points[:5]
    p = np.zeros((4, 12))
    p[3, 6:] = 99.0     # padding is ignored
    l, s = frame.ground_to_image(X, within_image=False)
    np.testing.assert_allclose(model.project(p, np.full(5, 3), X), np.column_stack([l, s]), atol=1e-9)
