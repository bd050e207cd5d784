"""Bad adjustment inputs give clear exceptions that name what is wrong."""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.adjust import BundleProblem, ImageObservations, PointPriors, SolverOptions, solve
from lunarmap.adjust.navigation import NavigationObservations
from blockhelp import frame_case
from lunarmap.errors import (AdjustmentInputError, DatumDefectError, InsufficientObservationsError,
                             UnobservedParameterError)


@pytest.fixture(scope="module")
def sb():
    return frame_case(orbits=2, per_orbit=5, points=120, n_control=4, seed=4)


def _rebuild(sb, **changes):
    pb = sb.problem
    o = pb.obs
    kw = dict(model=pb.model, cam_params=pb.cam_params.copy(), points=pb.points.copy(),
              obs=ImageObservations(o.cam_idx.copy(), o.pt_idx.copy(), o.xy.copy(), o.sigma.copy()),
              priors=PointPriors(pb.priors.idx.copy(), pb.priors.xyz.copy(), pb.priors.sigma.copy()),
              terms=list(pb.terms))
    kw.update(changes)
    return BundleProblem(**kw)


def test_the_reference_block_is_valid(sb):
    res = solve(_rebuild(sb), SolverOptions(ftol=1e-8))
    assert res.converged


def test_no_control_no_navigation_is_a_datum_defect(sb):
    pb = _rebuild(sb, priors=None, terms=[])
    with pytest.raises(DatumDefectError, match="datum"):
        solve(pb)


def test_too_few_observations(sb):
    # two images, three points each seen in both: 12 observations for 12 + 9 unknowns
    pb = sb.problem
    o = pb.obs
    both = np.intersect1d(o.pt_idx[o.cam_idx == 0], o.pt_idx[o.cam_idx == 1])[:3]
    m = np.isin(o.cam_idx, [0, 1]) & np.isin(o.pt_idx, both)
    remap = np.zeros(pb.n_points, np.int64)
    remap[both] = np.arange(both.size)
    obs = ImageObservations(o.cam_idx[m], remap[o.pt_idx[m]], o.xy[m], 0.3)
    from lunarmap.adjust import SensorImageModel

    model = SensorImageModel(pb.model.sensors[:2])
    with pytest.raises(InsufficientObservationsError, match="12 scalar observations for 21 unknowns"):
        BundleProblem(model, pb.cam_params[:2], pb.points[both], obs)
    with pytest.raises(AdjustmentInputError, match="2 rows but the image model describes 10 images"):
        BundleProblem(pb.model, pb.cam_params[:2], pb.points[both], obs)


def test_image_without_observations(sb):
    pb = sb.problem
    m = pb.obs.cam_idx != 3
    o = ImageObservations(pb.obs.cam_idx[m], pb.obs.pt_idx[m], pb.obs.xy[m], 0.3)
    still_seen = np.bincount(o.pt_idx, minlength=pb.n_points) >= 2
    idx = np.nonzero(still_seen)[0]
    remap = -np.ones(pb.n_points, np.int64)
    remap[idx] = np.arange(idx.size)
    keep = still_seen[o.pt_idx]
    o = ImageObservations(o.cam_idx[keep], remap[o.pt_idx[keep]], o.xy[keep], 0.3)
    with pytest.raises(UnobservedParameterError, match="image 3"):
        BundleProblem(pb.model, pb.cam_params, pb.points[idx], o)
    # navigation observations of that image make it determinable
    nav = sb.navigation
    BundleProblem(pb.model, pb.cam_params, pb.points[idx], o, terms=[nav])
    # ... and so does holding its parameters fixed
    free = np.ones_like(pb.cam_params, dtype=bool)
    free[3] = False
    BundleProblem(pb.model, pb.cam_params, pb.points[idx], o, cam_param_free=free, terms=[nav])


def test_point_in_one_image_only(sb):
    pb = sb.problem
    o = pb.obs
    j = int(np.setdiff1d(np.arange(pb.n_points), pb.priors.idx)[0])
    rows = np.nonzero(o.pt_idx == j)[0]
    m = np.ones(o.n, bool)
    m[rows[1:]] = False
    with pytest.raises(UnobservedParameterError, match=f"point {j}"):
        _rebuild(sb, obs=ImageObservations(o.cam_idx[m], o.pt_idx[m], o.xy[m], 0.3))


@pytest.mark.parametrize("what, match", [
    ("xy", "image observations xy: 1 non-finite"),
    ("sigma", "image observation sigma"),
    ("params", "initial image parameters"),
    ("points", "initial points"),
    ("control", "control point coordinates"),
])
def test_nan_inputs_are_named(sb, what, match):
    pb = sb.problem
    o = pb.obs
    xy, sig, params, pts = o.xy.copy(), o.sigma.copy(), pb.cam_params.copy(), pb.points.copy()
    pr = PointPriors(pb.priors.idx.copy(), pb.priors.xyz.copy(), pb.priors.sigma.copy())
    {"xy": xy, "sigma": sig, "params": params, "points": pts, "control": pr.xyz}[what][2, 1] = np.nan
    with pytest.raises(AdjustmentInputError, match=match):
        BundleProblem(pb.model, params, pts, ImageObservations(o.cam_idx, o.pt_idx, xy, sig), pr, terms=pb.terms)


@pytest.mark.parametrize("change, match", [
    (lambda o: setattr(o, "cam_idx", o.cam_idx + 100), "cam_idx out of range"),
    (lambda o: setattr(o, "pt_idx", -o.pt_idx - 1), "pt_idx out of range"),
    (lambda o: setattr(o, "sigma", 0.0), "sigma must be > 0"),
    (lambda o: setattr(o, "sigma", np.ones(7)), "sigma has shape"),
    (lambda o: setattr(o, "xy", o.xy[:, :1]), "must agree"),
])
def test_bad_observation_arrays(sb, change, match):
    o0 = sb.problem.obs
    o = ImageObservations(o0.cam_idx.copy(), o0.pt_idx.copy(), o0.xy.copy(), o0.sigma.copy())
    change(o)
    with pytest.raises(AdjustmentInputError, match=match):
        _rebuild(sb, obs=o)


def test_bad_shapes_and_priors(sb):
    pb = sb.problem
    with pytest.raises(AdjustmentInputError, match="columns"):
        _rebuild(sb, cam_params=pb.cam_params[:, :5])
    with pytest.raises(AdjustmentInputError, match=r"points must be \(n, 3\)"):
        _rebuild(sb, points=pb.points[:, :2])
    with pytest.raises(AdjustmentInputError, match="index out of range"):
        _rebuild(sb, priors=PointPriors([pb.n_points], [[0.0, 0.0, 0.0]], [[1.0, 1.0, 1.0]]))
    with pytest.raises(AdjustmentInputError, match="repeat"):
        _rebuild(sb, priors=PointPriors([0, 0], np.zeros((2, 3)), np.ones((2, 3))))
    with pytest.raises(AdjustmentInputError, match=">= 0"):
        _rebuild(sb, priors=PointPriors([0], np.zeros((1, 3)), -np.ones((1, 3))))
    with pytest.raises(AdjustmentInputError, match="sigma or cov"):
        _rebuild(sb, priors=PointPriors([0], np.zeros((1, 3))))


def test_bad_navigation(sb):
    n = sb.problem.n_images
    orbit = np.zeros(n, np.int64)
    obs = np.zeros((n, 6))
    bad = obs.copy()
    bad[1, 4] = np.nan
    with pytest.raises(AdjustmentInputError, match="1 NaN/inf"):
        NavigationObservations(bad, 1.0, orbit)
    # NaN where the parameter is not observed (sigma inf) is fine
    sig = np.ones((n, 6))
    sig[1, 4] = np.inf
    NavigationObservations(bad, sig, orbit)
    with pytest.raises(AdjustmentInputError, match="sigma must be > 0"):
        NavigationObservations(obs, 0.0, orbit)
    with pytest.raises(AdjustmentInputError, match="orbit"):
        NavigationObservations(obs, 1.0, orbit[:-1])
    with pytest.raises(AdjustmentInputError, match="s must be"):
        NavigationObservations(obs, 1.0, orbit, s=np.full(n, np.nan))
