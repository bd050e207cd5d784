"""Posterior precision: oracle = dense inverse of the normal matrix built from finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.adjust import SolverOptions, solve
from lunarmap.adjust.simulate_block import simulate_frame_block
from lunarmap.adjust.solver import AdjustmentState, _image_residuals, _prior_terms


def test_covariances_and_redundancy_numbers_against_dense_fd():
    sb = simulate_frame_block(orbits=2, per_orbit=4, points=80, seed=3)
    pb = sb.problem
    res = solve(pb, SolverOptions(ftol=1e-12))
    pr = res.precision()
    nav = sb.navigation
    nc, ne = pb.n_images * 6, nav.n_extra

    def fun(x):
        st = AdjustmentState(x[:nc].reshape(-1, 6), x[nc + ne:].reshape(-1, 3), x[nc:nc + ne], np.ones(pb.obs.n))
        return np.concatenate([_image_residuals(pb, st).ravel(), _prior_terms(pb, st.points)[1].ravel(),
                               nav.linearize(st.cam_params, st.extra)[0]])

    x = np.concatenate([res.cam_params.ravel(), res.extra, res.points.ravel()])
    scale = np.concatenate([np.tile([1e-6] * 3 + [1e-2] * 3, pb.n_images), np.full(ne, 1e-6),
                            np.full(3 * pb.n_points, 1e-2)])
    r0 = fun(x)
    J = np.empty((r0.size, x.size))
    for k in range(x.size):  # central differences, independent of the analytic Jacobians
        e = np.zeros_like(x)
        e[k] = scale[k]
        J[:, k] = (fun(x + e) - fun(x - e)) / (2 * scale[k])
    Q = np.linalg.inv(J.T @ J) * res.sigma0 ** 2
    cam = np.array([Q[6 * i:6 * i + 6, 6 * i:6 * i + 6] for i in range(pb.n_images)])
    o = nc + ne
    pts = np.array([Q[o + 3 * j:o + 3 * j + 3, o + 3 * j:o + 3 * j + 3] for j in range(pb.n_points)])
    np.testing.assert_allclose(pr.cam_cov, cam, rtol=1e-2, atol=1e-4 * np.abs(cam).max())
    np.testing.assert_allclose(pr.pt_cov, pts, rtol=1e-2, atol=1e-4 * np.abs(pts).max())
    np.testing.assert_allclose(pr.extra_cov, Q[nc:o, nc:o], rtol=1e-2, atol=1e-4 * np.abs(Q[nc:o, nc:o]).max())
    H = J @ np.linalg.solve(J.T @ J, J.T)
    red = (1 - np.diag(H))[: 2 * pb.obs.n].reshape(-1, 2)
    np.testing.assert_allclose(pr.redundancy_numbers, red, atol=1e-3)
    # sum of all redundancy numbers = redundancy (trace identity)
    assert np.sum(1 - np.diag(H)) == pytest.approx(res.redundancy, abs=1e-3)
    ds = res.points_dataset(with_precision=True)
    assert ds["sigma"].shape == (pb.n_points, 3) and ds.attrs["sigma0"] == res.sigma0
