"""Line-scan jitter corrections (issue 30, item 3): the cubic B-spline attitude on top of the polynomial.

Oracles: central differences of the projection for the analytic partials; scipy's ``BSpline`` for the
spline's basis; the corrected camera's own rigorous ``ground_to_image`` for ``apply``.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import BSpline

from lunarmap.camera.corrections import LineScanCorrections, cubic_bspline_basis
from lunarmap.errors import InvalidInputError, JitterKnotSpacingError
from lunarmap.orientation.rotation import matrix_to_rotvec
from lunarmap.simulate.orbits import nac_like_interior
from lunarmap.simulate.stereo import pointed_camera

CAM = pointed_camera("linescan", 30.0, 10.0, 12.0, interior=nac_like_interior(n_lines=2000, n_samples=1000))


def _points(cam, n=16, seed=0):
    rng = np.random.default_rng(seed)
    line = rng.uniform(0, cam.n_lines, n)
    sample = rng.uniform(0, cam.n_samples, n)
    return line, cam.image_to_ground(line, sample, rng.uniform(-800, 800, n))


def _params(corr, seed, jitter_rad=3e-6):
    rng = np.random.default_rng(seed)
    scale = np.where(np.array(corr.units) == "rad", 3e-5, 5.0)
    scale[corr.n_poly:] = jitter_rad
    return rng.normal(0.0, 1.0, corr.n_params) * scale


@pytest.mark.parametrize("degree, spacing", [(0, 150.0), (1, 150.0), (2, 333.3)])
def test_jitter_partials_match_central_differences(degree, spacing):
    corr = CAM.corrections(degree, jitter_lines=spacing)
    assert corr.n_params == 6 * (degree + 1) + 3 * (int(round(2000 / spacing)) + 3 - degree - 1)
    assert corr.knot_spacing * corr.n_segments == pytest.approx(2000.0)
    assert corr.n_params == len(corr.names) == len(corr.units)
    assert all(u == "rad" for u in corr.units[corr.n_poly:]) and corr.names[corr.n_poly] == "jwx_0"
    _, X = _points(CAM)
    p = _params(corr, 1)
    pix, jc, jx = corr.partials(p, X)
    np.testing.assert_allclose(pix, corr.project(p, X), atol=1e-9)
    for k in range(corr.n_params):
        # 0.01 px steps: the spline's edge terms bend the projection more than the polynomial's (0.05 px
        # steps left 2e-5 of second-order error, converging as h^2)
        h = 0.01 / np.max(np.abs(jc[:, :, k]))
        d = np.zeros(corr.n_params)
        d[k] = h
        fd = (corr.project(p + d, X) - corr.project(p - d, X)) / (2 * h)
        err = np.max(np.abs(jc[:, :, k] - fd)) / np.max(np.abs(fd))
        assert err < 2e-6, (corr.names[k], err)
    for k in range(3):
        d = np.zeros(3)
        d[k] = 0.05 / np.max(np.abs(jx[:, :, k]))
        fd = (corr.project(p, X + d) - corr.project(p, X - d)) / (2 * d[k])
        assert np.max(np.abs(jx[:, :, k] - fd)) / np.max(np.abs(fd)) < 2e-6


def test_basis_is_scipys_uniform_cubic_bspline():
    n_seg = 7
    s = np.linspace(0.0, n_seg, 301)
    knots = np.arange(-3.0, n_seg + 4.0)           # coefficient j's support [j - 3, j + 1]
    ours = cubic_bspline_basis(s, n_seg)
    for j in range(n_seg + 3):
        c = np.zeros(n_seg + 3)
        c[j] = 1.0
        np.testing.assert_allclose(ours[:, j], BSpline(knots, c, 3, extrapolate=False)(s), atol=1e-14)
    # held at the end values outside the span
    np.testing.assert_allclose(cubic_bspline_basis([-2.0, n_seg + 1.5], n_seg), cubic_bspline_basis([0.0, n_seg], n_seg))


@pytest.mark.parametrize("degree", [0, 1, 2])
def test_spline_holds_no_polynomial_of_the_polynomials_degree(degree):
    """Least squares of the spline parameters to a degree-``degree`` attitude over the image leaves it all:
    the spline and the polynomial are not collinear (the design has full column rank)."""
    corr = CAM.corrections(degree, jitter_lines=100.0)
    t = CAM.image_time(np.linspace(0.0, 2000.0, 801))
    tau = corr.tau(t)
    G = corr._jitter_rows(t)                             # spline basis of one axis
    for k in range(degree + 1):
        f = tau ** k
        z, *_ = np.linalg.lstsq(G, f, rcond=None)
        # the best spline fit of a pure polynomial is nothing: its residual keeps (nearly) all of it
        assert np.linalg.norm(f - G @ z) > 0.99 * np.linalg.norm(f), k
    P = tau[:, None] ** np.arange(degree + 1)[None, :]
    D = np.column_stack([P, G])
    sv = np.linalg.svd(D / np.linalg.norm(D, axis=0), compute_uv=False)
    assert sv[-1] / sv[0] > 1e-2


def test_spline_reproduces_a_sinusoid_of_several_knots():
    """A 5 Hz attitude on NAC lines (588 lines a period) with knots every 100 lines: the spline's least-squares
    fit (on top of a degree-1 polynomial) follows it to < 1 % of its amplitude."""
    corr = CAM.corrections(1, jitter_lines=100.0)
    t = CAM.image_time(np.linspace(0.0, 2000.0, 2001))
    f = 2e-6 * np.sin(2 * np.pi * 5.0 * (t - t[0]) + 0.4)
    A = np.column_stack([np.ones_like(t), corr.tau(t), corr._jitter_rows(t)])
    coef, *_ = np.linalg.lstsq(A, f, rcond=None)
    assert np.sqrt(np.mean((A @ coef - f) ** 2)) < 0.01 * 2e-6


def test_applied_jitter_gives_a_camera_that_projects_the_same():
    corr = CAM.corrections(1, jitter_lines=150.0)
    _, X = _points(CAM, seed=3)
    p = _params(corr, 4)
    new = corr.apply(p)
    li, sa = new.ground_to_image(X, within_image=False)
    # 3 urad random knots (0.3 px of jitter): the records' interpolation follows within 1e-4 px
    np.testing.assert_allclose(np.column_stack([li, sa]), corr.project(p, X), atol=1e-4)
    assert new.eo.times.size > CAM.eo.times.size + 8 * corr.n_segments
    # the corrected camera's attitude carries the spline: w(t) of the records vs the model's
    t = CAM.image_time(np.array([100.0, 777.0, 1500.0]))
    R0 = CAM.eo.rotation_at(t)
    R1 = new.eo.rotation_at(t)
    w = matrix_to_rotvec(np.swapaxes(R1, -1, -2) @ R0)   # R1^T R0 = exp([w]x)
    np.testing.assert_allclose(w, corr.attitude_correction(p, t), atol=2e-9)


@pytest.mark.parametrize("bad", [0.5, 0.0, -3.0, float("nan"), float("inf"), "ten"])
def test_knot_spacing_below_a_line_is_a_named_error(bad):
    with pytest.raises(JitterKnotSpacingError):
        CAM.corrections(1, jitter_lines=bad)
    assert issubclass(JitterKnotSpacingError, InvalidInputError)


def test_without_jitter_the_corrections_are_the_polynomial_ones():
    a, b = CAM.corrections(1), LineScanCorrections(CAM, 1, jitter_lines=None)
    assert a.names == b.names and a.n_params == 12 and b.jitter_lines is None
    _, X = _points(CAM, seed=5)
    p = _params(a, 6)
    np.testing.assert_allclose(a.project(p, X), b.project(p, X), atol=1e-12)
    np.testing.assert_allclose(b.jitter(p, [0.0, 0.1]), 0.0)


def test_jitter_corrections_pickle():
    import pickle

    corr = CAM.corrections(1, jitter_lines=120.0)
    copy = pickle.loads(pickle.dumps(corr))
    _, X = _points(CAM, seed=7)
    p = _params(corr, 8)
    np.testing.assert_array_equal(copy.project(p, X), corr.project(p, X))
    assert copy.names == corr.names and copy.knot_spacing == corr.knot_spacing


def test_applied_jitter_stays_within_the_original_samples():
    """An EO that spans the image lines only (as an ISD's): the corrected EO is not extrapolated beyond it."""
    from lunarmap.camera import LineScanCamera
    from lunarmap.simulate.orbits import NAC_LINE_TIME, polar_orbit_eo

    half = 0.5 * 2000 * NAC_LINE_TIME
    eo = polar_orbit_eo(lat_center=10.0, lon=30.0, altitude=50e3, half_span=half, step=half / 20, roll_deg=5.0)
    cam = LineScanCamera(nac_like_interior(n_lines=2000, n_samples=1000), eo, CAM.shape,
                         line_times=(-half, NAC_LINE_TIME))
    corr = cam.corrections(1, jitter_lines=500.0)       # the spline's span reaches 500 lines beyond the image
    new = corr.apply(_params(corr, 9))
    assert new.eo.time_range == pytest.approx(eo.time_range, abs=1e-12)
    _, X = _points(cam, seed=10)
    li, sa = new.ground_to_image(X, within_image=False)
    np.testing.assert_allclose(np.column_stack([li, sa]), corr.project(_params(corr, 9), X), atol=1e-4)
