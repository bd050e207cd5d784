"""Posterior precision: oracle = dense inverse of the normal matrix built from finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.adjust import SolverOptions, solve
from conftest import require
from blockhelp import frame_case
from lunarmap.adjust.normal import AdjustmentState, image_residuals as _image_residuals, prior_terms as _prior_terms


def test_covariances_and_redundancy_numbers_against_dense_fd():
    sb = frame_case(orbits=2, per_orbit=4, points=80, seed=3)
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
    # issue 11: redundancy numbers of the control and navigation observations too (rows of the FD Jacobian)
    k = 2 * pb.obs.n
    nc3 = 3 * int((~pb.priors.fixed).sum())
    np.testing.assert_allclose(pr.control_redundancy.ravel(), 1 - np.diag(H)[k:k + nc3], atol=1e-3)
    np.testing.assert_allclose(pr.term_redundancy[0], 1 - np.diag(H)[k + nc3:], atol=1e-3)
    assert len(pr.term_redundancy) == 1 and pr.term_redundancy[0].size == nav.n_obs_scalar
    # sum of all redundancy numbers = redundancy (trace identity)
    assert np.sum(1 - np.diag(H)) == pytest.approx(res.redundancy, abs=1e-3)
    total = pr.redundancy_numbers.sum() + pr.control_redundancy.sum() + pr.term_redundancy[0].sum()
    assert total == pytest.approx(res.redundancy, abs=1e-3)
    ds = res.points_dataset(with_precision=True)
    assert ds["sigma"].shape == (pb.n_points, 3) and ds.attrs["sigma0"] == res.sigma0


# --- sparse selected inversion ------------------------------------------------------------------

def _bare_block(seed=4, orbits=3, per_orbit=8, points=600):
    """A simulated block without navigation terms (datum from the weighted control points)."""
    from lunarmap.adjust import BundleProblem

    pb = frame_case(orbits=orbits, per_orbit=per_orbit, points=points, seed=seed).problem
    return BundleProblem(pb.model, pb.cam_params, pb.points, pb.obs, priors=pb.priors)


def test_selected_inverse_blocks_match_dense_inverse():
    import scipy.sparse as sp

    from lunarmap.adjust.precision import reduced_inverse_blocks

    pb = _bare_block()
    res = solve(pb, SolverOptions(ftol=1e-10))
    st = res.structure
    from lunarmap.adjust.normal import Terms as _Terms, linearize, reduced_system

    lin = linearize(pb, res.state, st, _Terms(pb), pb.point_fixed())
    S, _, _, _ = reduced_system(lin, st, _Terms(pb), 0.0, res.free_red)
    # compare in Jacobi-scaled units (Q_ij sqrt(S_ii S_jj)): the block is ill-conditioned (cond ~3e8),
    # so two exact-arithmetic-equivalent methods agree to ~1e-6 of the largest scaled variance
    d = np.sqrt(S.diagonal())
    Qd = np.linalg.inv(S.toarray() / d[:, None] / d[None, :]) / d[:, None] / d[None, :]
    ar = np.arange(6)
    r = 6 * st.block_row[:, None, None] + ar[None, :, None]
    c = 6 * st.block_col[:, None, None] + ar[None, None, :]
    want = Qd[r, c] * d[r] * d[c]
    tol = dict(rtol=0, atol=1e-5 * np.abs(np.diag(Qd) * d * d).max())
    for kw in (dict(keep_dense=True), dict(keep_dense=False), dict(keep_dense=False, method="supernodal"),
               dict(keep_dense=False, method="chunks", use_band=True),
               dict(keep_dense=False, method="chunks", use_band=False),
               dict(keep_dense=False, method="chunks", use_band=False, chunk_columns=12)):
        Qblk, _, Q = reduced_inverse_blocks(sp.csr_matrix(S), res.free_red, st.block_row, st.block_col, 6, st.n_cam,
                                            **kw)
        np.testing.assert_allclose(Qblk * d[r] * d[c], want, err_msg=str(kw), **tol)
        if Q is not None:
            np.testing.assert_allclose(Q * d[:, None] * d[None, :], Qd * d[:, None] * d[None, :], rtol=0,
                                       atol=tol["atol"])


def test_sparse_precision_matches_dense_method_with_navigation_terms():
    from lunarmap.adjust.precision import posterior_precision
    from lunarmap.adjust.schur import HAVE_COMPILED

    require(HAVE_COMPILED, "numba (the compiled adjustment kernels)")
    pb = frame_case(orbits=3, per_orbit=6, points=500, seed=9).problem
    res = solve(pb, SolverOptions(ftol=1e-10))
    a = posterior_precision(res, method="sparse", redundancy=True, inverse_method="supernodal")
    b = posterior_precision(res, method="dense", redundancy=True)
    c = posterior_precision(res, method="sparse", redundancy=True, inverse_method="chunks")
    assert a.method == "sparse-supernodal" and c.method == "sparse-chunks"
    for other in (a, c):
        for name in ("cam_cov", "pt_cov", "extra_cov", "cam_extra_cov"):
            x, y = getattr(other, name), getattr(b, name)
            np.testing.assert_allclose(x, y, rtol=1e-6, atol=1e-9 * np.abs(y).max(), err_msg=name)
        np.testing.assert_allclose(other.redundancy_numbers, b.redundancy_numbers, atol=1e-7)
        np.testing.assert_allclose(other.control_redundancy, b.control_redundancy, atol=1e-7)
        np.testing.assert_allclose(other.term_redundancy[0], b.term_redundancy[0], atol=1e-7)
    assert np.sum(a.redundancy_numbers) + 0 == pytest.approx(
        np.sum(b.redundancy_numbers), abs=1e-5)


def test_singular_reduced_system_raises_datum_defect():
    import scipy.sparse as sp

    from lunarmap.adjust import DatumDefectError
    from lunarmap.adjust.precision import reduced_inverse_blocks

    rng = np.random.default_rng(0)
    A = rng.normal(size=(40, 12))
    A[:, 11] = A[:, 3] - 2.0 * A[:, 7]          # rank 11: an undefined direction
    S = sp.csr_matrix(A.T @ A)
    br, bc = np.array([0, 0, 1]), np.array([0, 1, 1])
    for kw in (dict(keep_dense=True), dict(keep_dense=False), dict(keep_dense=False, method="chunks", use_band=True),
               dict(keep_dense=False, method="chunks", use_band=False)):
        with pytest.raises(DatumDefectError):
            reduced_inverse_blocks(S, np.ones(12, bool), br, bc, 6, 2, **kw)


def test_undetermined_point_does_not_break_precision():
    from lunarmap.adjust.precision import posterior_precision

    pb = _bare_block(seed=2, orbits=2, per_orbit=6, points=300)
    res = solve(pb, SolverOptions(ftol=1e-10))
    # move one 2-ray point far out along its first ray: its depth is then not determined
    o = pb.obs
    track = np.bincount(o.pt_idx, minlength=pb.n_points)
    j = int(np.nonzero((track == 2) & ~pb.point_fixed())[0][0])
    i = int(np.nonzero(o.pt_idx == j)[0][0])
    k = o.cam_idx[i]
    C = pb.model.sensors[k].rays(*o.xy[i])[0] + res.cam_params[k, 3:6]   # adjusted projection centre
    res.state.points[j] = C + 1e9 * (res.state.points[j] - C)
    pr = posterior_precision(res, redundancy=True)
    assert j in pr.undetermined_points and np.all(np.isinf(pr.pt_cov[j]))
    ok = np.ones(pb.n_points, bool)
    ok[pr.undetermined_points] = False
    assert np.all(np.isfinite(pr.pt_cov[ok])) and np.all(np.isfinite(pr.cam_cov))
