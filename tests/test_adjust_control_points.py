"""Control points as latitude/longitude/height with sigma: propagated XYZ covariance vs closed form,
finite differences and Monte Carlo; PointPriors covariance validation."""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.adjust import BundleProblem, ImageObservations, PointPriors
from lunarmap.adjust.control_points import enu_basis, lonlat_covariance_to_xyz, lonlat_priors
from lunarmap.camera.geodesy import lonlat_height_to_xyz
from lunarmap.camera.shape import MOON_RADIUS
from lunarmap.errors import AdjustmentInputError

R = MOON_RADIUS


def test_closed_form_at_lat0_lon0():
    # at (0, 0): east = +y, north = +z, up = +x, so C = diag(s_h^2, ((R+h) s_lon)^2, ((R+h) s_lat)^2)
    h, s_lon, s_lat, s_h = 1200.0, 1e-3, 2e-3, 30.0     # degrees, degrees, metres
    pr = lonlat_priors([0], 0.0, 0.0, h, s_lon, s_lat, s_h, unit="deg")
    rad = np.pi / 180
    want = np.diag([s_h ** 2, ((R + h) * s_lon * rad) ** 2, ((R + h) * s_lat * rad) ** 2])
    assert np.allclose(pr.cov[0], want, rtol=1e-12, atol=1e-9)
    assert np.allclose(pr.xyz[0], [R + h, 0.0, 0.0])
    assert not pr.correlated


def test_general_point_matches_finite_differences_and_units():
    lon, lat, h = 123.4, -56.7, -800.0
    s = np.array([2e-4, 3e-4, 12.0])          # deg, deg, m
    cov = lonlat_covariance_to_xyz([lon], [lat], [h], np.diag(s ** 2)[None], unit="deg")[0]
    # finite-difference Jacobian of the forward transformation (metres per degree / per metre)
    J = np.empty((3, 3))
    for k, step in enumerate((1e-6, 1e-6, 1e-3)):
        d = np.zeros(3)
        d[k] = step
        J[:, k] = (lonlat_height_to_xyz(lon + d[0], lat + d[1], h + d[2]) -
                   lonlat_height_to_xyz(lon - d[0], lat - d[1], h - d[2])) / (2 * step)
    assert np.allclose(cov, J @ np.diag(s ** 2) @ J.T, rtol=1e-6, atol=1e-6)
    # radians and ground metres give the same covariance
    cov_rad = lonlat_covariance_to_xyz([lon], [lat], [h], np.diag((s * [np.pi / 180, np.pi / 180, 1]) ** 2)[None],
                                       unit="rad")[0]
    m_per_deg = (R + h) * np.pi / 180
    s_m = s * [m_per_deg * np.cos(np.radians(lat)), m_per_deg, 1.0]
    cov_m = lonlat_covariance_to_xyz([lon], [lat], [h], np.diag(s_m ** 2)[None], unit="m")[0]
    assert np.allclose(cov_rad, cov, rtol=1e-10)
    assert np.allclose(cov_m, cov, rtol=1e-10)
    # the ENU rotation of the covariance is diagonal with the ground sigmas
    E = enu_basis(lon, lat)
    assert np.allclose(E @ cov @ E.T, np.diag(s_m ** 2), rtol=1e-10, atol=1e-9)


def test_monte_carlo_covariance():
    rng = np.random.default_rng(0)
    lon, lat, h = 40.0, 35.0, 500.0
    s = np.array([5e-4, 8e-4, 40.0])
    samples = lonlat_height_to_xyz(lon + rng.normal(0, s[0], 200_000), lat + rng.normal(0, s[1], 200_000),
                                   h + rng.normal(0, s[2], 200_000))
    mc = np.cov(samples.T)
    cov = lonlat_priors([3], lon, lat, h, *s).cov[0]
    # 200k samples: sample covariance within ~1 % (entries relative to the largest variance)
    assert np.allclose(mc, cov, atol=0.01 * np.max(np.diag(cov)))


def test_isotropic_bound_is_conservative():
    pr = lonlat_priors([0, 1], [10.0, -70.0], [45.0, 80.0], [0.0, 100.0], 50.0, 20.0, 5.0, unit="m")
    full = lonlat_priors([0, 1], [10.0, -70.0], [45.0, 80.0], [0.0, 100.0], 50.0, 20.0, 5.0, unit="m",
                         representation="isotropic-bound")
    assert full.cov is None and np.allclose(full.sigma, 50.0)
    for k in range(2):
        assert np.all(np.linalg.eigvalsh(np.diag(full.sigma[k] ** 2) - pr.cov[k]) >= -1e-6)


def _tiny_problem(priors):
    # two frame images looking at three points: enough structure for BundleProblem validation
    from lunarmap.adjust import FrameModel

    R0 = np.repeat(np.eye(3)[None], 4, axis=0)
    model = FrameModel(R0, 1000.0)
    params = np.array([[0, 0, 0, 0, 0, 10.0], [0, 0, 0, 1.0, 0, 10.0], [0, 0, 0, 0, 1.0, 10.0],
                       [0, 0, 0, 1.0, 1.0, 10.0]])
    X = np.array([[0.1, 0.2, 0.0], [-0.2, 0.1, 0.0], [0.0, -0.3, 0.5], [0.5, 0.5, 0.1], [0.7, 0.2, -0.2],
                  [0.3, 0.9, 0.0]])
    ci = np.repeat(np.arange(4), 6)
    pi = np.tile(np.arange(6), 4)
    xy = model.project(params, ci, X[pi])
    return BundleProblem(model, params, X, ImageObservations(ci, pi, xy, 1.0), priors)


def test_correlated_priors_are_weighted_by_their_inverse_covariance():
    """Oracle: scipy least_squares on residuals whitened with an independent Cholesky of each covariance."""
    from scipy.optimize import least_squares

    from lunarmap.adjust import SolverOptions, solve
    from blockhelp import frame_case
    from lunarmap.adjust.normal import AdjustmentState, image_residuals as _image_residuals

    sb = frame_case(orbits=2, per_orbit=4, points=80, seed=7)
    base = sb.problem
    k = base.priors.idx.size
    rng = np.random.default_rng(3)
    A = rng.normal(size=(k, 3, 3)) * 40.0
    cov = A @ np.swapaxes(A, 1, 2) + np.eye(3) * 100.0        # strongly correlated, metres^2
    pr = PointPriors(base.priors.idx, base.priors.xyz, cov=cov)
    assert pr.correlated
    pb = BundleProblem(base.model, base.cam_params, base.points, base.obs, pr, terms=base.terms)
    res = solve(pb, SolverOptions(ftol=1e-10))
    nav = sb.navigation
    nc, ne = pb.n_images * 6, nav.n_extra
    Linv = np.linalg.inv(np.linalg.cholesky(cov))              # whitening independent of sqrt_weight()

    def fun(x):
        st = AdjustmentState(x[:nc].reshape(-1, 6), x[nc + ne:].reshape(-1, 3), x[nc:nc + ne], np.ones(pb.obs.n))
        rc = np.einsum("kij,kj->ki", Linv, st.points[pr.idx] - pr.xyz)
        return np.concatenate([_image_residuals(pb, st).ravel(), rc.ravel(),
                               nav.linearize(st.cam_params, st.extra)[0]])

    x1 = np.concatenate([res.cam_params.ravel(), res.extra, res.points.ravel()])
    assert 0.5 * np.sum(fun(x1) ** 2) == pytest.approx(res.cost, rel=1e-9)
    ls = least_squares(fun, x1, method="trf", x_scale="jac", ftol=1e-14, xtol=1e-14, gtol=1e-12, max_nfev=5)
    assert ls.cost <= res.cost + 1e-9 and res.cost - ls.cost < 0.01
    sig = np.sqrt(np.diagonal(res.precision().pt_cov, axis1=1, axis2=2))
    assert np.max(np.abs(res.points - ls.x[nc + ne:].reshape(-1, 3)) / sig) < 0.1
    # the correlated weights matter: the per-axis-sigma problem has a different minimum
    diag = PointPriors(pr.idx, pr.xyz, sigma=np.sqrt(np.diagonal(cov, axis1=1, axis2=2)))
    res_d = solve(BundleProblem(base.model, base.cam_params, base.points, base.obs, diag, terms=base.terms),
                  SolverOptions(ftol=1e-10))
    assert np.max(np.abs(res_d.points[pr.idx] - res.points[pr.idx])) > 1e-3


def test_diagonal_covariance_is_per_axis_sigma():
    # a diagonal covariance is exactly per-axis sigma
    pb = _tiny_problem(PointPriors([0, 1], [[0.1, 0.2, 0.0], [-0.2, 0.1, 0.0]],
                                   cov=np.array([np.diag([4.0, 9.0, 1.0]), np.zeros((3, 3))])))
    assert np.allclose(pb.priors.sigma, [[2.0, 3.0, 1.0], [0, 0, 0]])
    assert pb.priors.fixed.tolist() == [False, True]
    W = pb.priors.sqrt_weight()
    assert np.allclose(W[0], np.diag([0.5, 1 / 3, 1.0])) and np.all(W[1] == 0)


@pytest.mark.parametrize("cov, match", [
    (np.ones((1, 3, 3)), "positive definite"),
    (np.array([[[1.0, 0.1, 0], [0.2, 1.0, 0], [0, 0, 1]]]), "symmetric"),
    (np.full((1, 3, 3), np.nan), "non-finite"),
    (np.eye(3)[None].repeat(2, 0), r"\(1, 3, 3\)"),
])
def test_bad_covariances(cov, match):
    with pytest.raises(AdjustmentInputError, match=match):
        _tiny_problem(PointPriors([0], [[0.1, 0.2, 0.0]], cov=cov))


def test_bad_lonlat_inputs():
    with pytest.raises(AdjustmentInputError, match="unit"):
        lonlat_priors([0], 0, 0, 0, 1, 1, 1, unit="furlong")
    with pytest.raises(AdjustmentInputError, match="non-finite"):
        lonlat_priors([0], np.nan, 0, 0, 1, 1, 1)
    with pytest.raises(AdjustmentInputError, match=">= 0"):
        lonlat_priors([0], 0, 0, 0, -1, 1, 1)
    with pytest.raises(AdjustmentInputError, match="some but not all"):
        lonlat_priors([0], 0, 0, 0, 0, 1, 1)
    with pytest.raises(AdjustmentInputError, match="2 values"):
        lonlat_priors([0, 1], [0, 1, 2], 0, 0, 1, 1, 1)
    with pytest.raises(AdjustmentInputError, match="some but not all"):
        _tiny_problem(PointPriors([0], [[0.1, 0.2, 0.0]], [[0.0, 1.0, 1.0]]))
