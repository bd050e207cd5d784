"""Reference-DTM heights as observations of the tie points (issue 30, part 1): the term's residuals and
partials against closed forms and finite differences, and its bad input."""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.adjust import ReferenceDtm, dtm_heights
from lunarmap.adjust.terrain import point_height
from lunarmap.camera.geodesy import lonlat_height_to_xyz
from lunarmap.errors import DtmCoverageError, DtmCrsError, TerrainInputError
from lunarmap.simulate import reference_dtm

R_MOON = 1737400.0


def _plane(lon, lat):
    """A tilted plane in (lon, lat) degrees: bilinear interpolation reproduces it exactly."""
    return 500.0 + 800.0 * (lon - 10.0) - 300.0 * (lat - 5.0)


@pytest.fixture
def dtm(tmp_path):
    sim = reference_dtm(tmp_path / "dtm.tif", _plane, (9.5, 10.5), (4.5, 5.5), 300.0, noise_sigma=0.0, seed=1)
    return tmp_path / "dtm.tif", sim


def _points(n=60, seed=0, dh=0.0):
    rng = np.random.default_rng(seed)
    lon, lat = rng.uniform(9.7, 10.3, n), rng.uniform(4.7, 5.3, n)
    h = _plane(lon, lat) + dh + rng.normal(0, 20.0, n)
    return lonlat_height_to_xyz(lon, lat, h), h - _plane(lon, lat)


def test_residual_is_height_above_the_dtm(dtm):
    path, _ = dtm
    X, dh = _points()
    term = dtm_heights(ReferenceDtm(str(path), 2.0), X, 0, 1)
    assert term.n_obs_scalar == X.shape[0] and term.skipped == 0
    # closed form: the point's height above the sphere minus the plane's height (exact for a bilinear grid)
    np.testing.assert_allclose(term.residuals_m(X), dh, atol=0.05)


def test_point_partials_match_finite_differences(dtm):
    path, _ = dtm
    X, _ = _points(n=20, seed=3)
    term = dtm_heights(ReferenceDtm(str(path), 2.0), X, 0, 1)
    r, J, Jp = term.linearize(np.zeros(0), np.zeros(0), X)
    np.testing.assert_allclose(r, term.residuals_m(X) / 2.0, rtol=1e-12)
    step = 0.5
    num = np.empty_like(Jp)
    for k in range(3):
        d = np.zeros(3)
        d[k] = step
        num[:, k] = (term.residuals_m(X + d) - term.residuals_m(X - d)) / (2 * step) / 2.0
    np.testing.assert_allclose(Jp, num, atol=1e-6)
    # the slope matters: against the radial unit vector alone the partials differ by the plane's gradient
    radial = X / np.linalg.norm(X, axis=1, keepdims=True) / 2.0
    assert np.max(np.abs(Jp - radial)) > 1e-3


def test_points_outside_and_on_holes_are_counted_and_none_covered_is_named(tmp_path):
    sim = reference_dtm(tmp_path / "holes.tif", _plane, (9.5, 10.5), (4.5, 5.5), 300.0, noise_sigma=0.0,
                        holes=40, hole_radius_px=4, seed=2)
    X, _ = _points(n=200, seed=5)
    far = lonlat_height_to_xyz(np.full(5, 40.0), np.full(5, 40.0), np.zeros(5))     # 35 degrees off the grid
    term = dtm_heights(ReferenceDtm(str(tmp_path / "holes.tif"), 2.0), np.vstack([X, far]), 0, 1)
    assert term.skipped >= 5 and term.n_obs_scalar + term.skipped == 205
    assert np.isfinite(sim.heights).sum() < sim.heights.size          # the holes are there
    with pytest.raises(DtmCoverageError, match="covers none"):
        dtm_heights(ReferenceDtm(str(tmp_path / "holes.tif"), 2.0), far, 0, 1)


def test_dtm_without_crs_and_bad_sigma_are_named(tmp_path):
    reference_dtm(tmp_path / "nocrs.tif", _plane, (9.5, 10.5), (4.5, 5.5), 300.0, crs=None)
    X, _ = _points(n=5)
    with pytest.raises(DtmCrsError):
        dtm_heights(ReferenceDtm(str(tmp_path / "nocrs.tif"), 2.0), X, 0, 1)
    with pytest.raises(TerrainInputError):
        ReferenceDtm(str(tmp_path / "nocrs.tif"), 0.0)


def test_slope_baseline_gives_the_terrain_slope_not_the_noise(tmp_path):
    """On the plane the baseline's slope is the plane's (closed form); on a noisy plane it is closer to the
    plane's slope than the cell's own gradient, by about the ratio of baseline to node spacing."""
    truth = np.array([800.0, -300.0]) * 180.0 / np.pi          # the plane's dh/d(lon, lat), metres per radian
    X, _ = _points(n=200, seed=7)
    reference_dtm(tmp_path / "plane.tif", _plane, (9.5, 10.5), (4.5, 5.5), 300.0, noise_sigma=0.0, seed=1)
    term = dtm_heights(ReferenceDtm(str(tmp_path / "plane.tif"), 2.0, slope_baseline_m=900.0), X, 0, 1)
    lon, lat, _, _ = point_height(X[term.point_index], term.radius)
    np.testing.assert_allclose(term.window.slope(lon, lat, 900.0), np.broadcast_to(truth, (lon.size, 2)), rtol=1e-4)
    reference_dtm(tmp_path / "noisy.tif", _plane, (9.5, 10.5), (4.5, 5.5), 300.0, noise_sigma=30.0, seed=1)
    noisy = dtm_heights(ReferenceDtm(str(tmp_path / "noisy.tif"), 2.0, slope_baseline_m=3000.0), X, 0, 1)
    _, cell = noisy.window.sample(lon, lat)
    base = noisy.window.slope(lon, lat, 3000.0)
    err_cell = np.sqrt(np.nanmean((cell - truth) ** 2))
    err_base = np.sqrt(np.nanmean((base - truth) ** 2))
    assert err_base < 0.3 * err_cell
    # the term's partials use the baseline's slope: against the plane's closed-form partials they are closer
    _, _, Jb = noisy.linearize(np.zeros(0), np.zeros(0), X)
    plain = dtm_heights(ReferenceDtm(str(tmp_path / "noisy.tif"), 2.0), X, 0, 1)
    _, _, Jc = plain.linearize(np.zeros(0), np.zeros(0), X)
    exact = dtm_heights(ReferenceDtm(str(tmp_path / "plane.tif"), 2.0), X, 0, 1)
    _, _, Je = exact.linearize(np.zeros(0), np.zeros(0), X)
    assert np.sqrt(np.mean((Jb - Je) ** 2)) < 0.3 * np.sqrt(np.mean((Jc - Je) ** 2))
    with pytest.raises(TerrainInputError, match="slope_baseline"):
        ReferenceDtm(str(tmp_path / "plane.tif"), 2.0, slope_baseline_m=-1.0)
