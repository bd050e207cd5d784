"""The jitter smoothness prior (issue 30, item 3): its rows are the second differences of the spline's knot
coefficients (oracle: scipy's BSpline fitted to the spline's attitude), it forms an observation group of its
own, and the image model takes the knot spacing per image."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import BSpline

from lunarmap.adjust import BundleProblem, ImageObservations, JitterSmoothness, SensorImageModel, observation_groups
from lunarmap.camera.corrections import LineScanCorrections
from lunarmap.errors import AdjustmentInputError, JitterKnotSpacingError
from lunarmap.simulate.orbits import nac_like_interior
from lunarmap.simulate.stereo import pointed_camera

CAMS = [pointed_camera("linescan", 30.0, 10.0, roll, interior=nac_like_interior(n_lines=1200, n_samples=500))
        for roll in (-5.0, 5.0)]


def _model(jitter=(100.0, None), degree=1):
    return SensorImageModel(CAMS, degree=degree, jitter_lines=list(jitter))


def test_rows_are_second_differences_of_the_knot_coefficients():
    model = _model()
    corr = model.corrections[0]
    assert isinstance(corr, LineScanCorrections) and corr.jitter_lines == 100.0
    assert model.corrections[1].n_params == 12 and model.n_params == corr.n_params
    rng = np.random.default_rng(0)
    params = np.zeros((2, model.n_params))
    params[0, :corr.n_params] = rng.normal(0, 2e-6, corr.n_params)
    term = JitterSmoothness(model, sigma=1.5e-6)
    r, J = term.linearize(params, np.zeros(0))
    assert r.shape == (term.n_obs_scalar,) == (3 * (corr.n_knots - 2),)
    np.testing.assert_allclose(J @ params.ravel(), r)
    # oracle: the knot coefficients from scipy's B-spline fitted to the spline's attitude over its span
    lines = np.linspace(0.0, 1200.0, 2401)
    t = CAMS[0].image_time(lines)
    w = corr.jitter(params[0, :corr.n_params], t)
    h = corr.knot_spacing
    knots = (np.arange(-3, corr.n_segments + 4)) * h
    design = BSpline.design_matrix(np.clip(lines, 0, corr.n_segments * h * (1 - 1e-12)), knots, 3).toarray()
    coef, *_ = np.linalg.lstsq(design, w, rcond=None)
    want = np.diff(coef, n=2, axis=0) / 1.5e-6                    # (n_knots - 2, 3)
    got = np.stack([r[term.row_kind == 0][k * (corr.n_knots - 2):(k + 1) * (corr.n_knots - 2)] for k in range(3)], 1)
    np.testing.assert_allclose(got, want, atol=1e-6 * np.max(np.abs(want)))
    assert set(term.row_image) == {0} and term.observed_images().tolist() == [True, False]


def test_zero_prior_rows_and_observation_group():
    model = _model((80.0, 120.0), degree=2)
    term = JitterSmoothness(model, sigma=2e-6, zero_sigma=1e-5)
    c0, c1 = model.corrections
    assert term.n_obs_scalar == 3 * (c0.n_knots - 2 + c0.n_jitter) + 3 * (c1.n_knots - 2 + c1.n_jitter)
    params = np.zeros((2, model.n_params))
    params[1, c1.n_poly + 4] = 3e-6                                 # z_1 of axis y of image 1
    r, _ = term.linearize(params, np.zeros(0))
    zero_rows = np.flatnonzero((term.row_kind == 1) & (r != 0))
    assert zero_rows.size == 1 and r[zero_rows[0]] == pytest.approx(0.3) and term.row_image[zero_rows[0]] == 1
    rng = np.random.default_rng(1)
    X = np.concatenate([CAMS[0].image_to_ground(rng.uniform(0, 1200, 30), rng.uniform(0, 500, 30), 0.0)])
    li, sa = CAMS[1].ground_to_image(X)
    ok = np.isfinite(li)
    X = X[ok]
    l0, s0 = CAMS[0].ground_to_image(X)
    obs = ImageObservations(np.r_[np.zeros(X.shape[0]), np.ones(X.shape[0])].astype(np.int64),
                            np.r_[np.arange(X.shape[0]), np.arange(X.shape[0])],
                            np.column_stack([np.r_[l0, li[ok]], np.r_[s0, sa[ok]]]), 0.1)
    pb = BundleProblem(model, np.zeros((2, model.n_params)), X, obs, terms=[term],
                       cam_param_free=np.zeros((2, model.n_params), bool))
    groups = observation_groups(pb)
    k = groups.names.index("jitter smoothness")
    assert np.all(groups.terms[0] == k)


def test_bad_inputs_are_named_errors():
    with pytest.raises(AdjustmentInputError):
        JitterSmoothness(_model(), sigma=0.0)
    with pytest.raises(AdjustmentInputError):
        JitterSmoothness(_model(), sigma=1e-6, zero_sigma=float("nan"))
    with pytest.raises(AdjustmentInputError, match="no image"):
        JitterSmoothness(_model((None, None)), sigma=1e-6)
    with pytest.raises(AdjustmentInputError):
        SensorImageModel(CAMS, jitter_lines=[100.0])
    with pytest.raises(JitterKnotSpacingError):
        SensorImageModel(CAMS, jitter_lines=0.5)
    # one spacing for all line-scan images
    assert all(c.jitter_lines == 60.0 for c in SensorImageModel(CAMS, jitter_lines=60.0).corrections)
