"""Check-point errors: along/cross/height and east/north/up against constructed errors, a solved block and triangulation."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from lunarmap.adjust import NavigationSpec, build_block, solve_block
from lunarmap.camera.geodesy import enu_basis, lonlat_height_to_xyz
from lunarmap.errors import CheckPointError, EvaluationInputError
from lunarmap.evaluate import (along_track_azimuth, block_check_errors, check_point_errors, site_network,
                               track_basis, triangulate)
from lunarmap.simulate import APOLLO11_LIKE, lroc_site


@pytest.fixture(scope="module")
def site():
    return lroc_site(APOLLO11_LIKE[:3], n_tie=40, n_control=5, n_check=10, sigma_px=0.2, seed=4)


def test_errors_recover_constructed_offsets():
    rng = np.random.default_rng(1)
    lon, lat = rng.uniform(20, 21, 6), rng.uniform(-1, 1, 6)
    ref = lonlat_height_to_xyz(lon, lat, 0.0)
    E = enu_basis(lon, lat)
    az = 30.0
    a = np.radians(az)
    along = np.sin(a) * E[:, 0] + np.cos(a) * E[:, 1]
    cross = np.cos(a) * E[:, 0] - np.sin(a) * E[:, 1]
    d = rng.normal(0, 1, (6, 3))
    est = ref + d[:, :1] * along + d[:, 1:2] * cross + d[:, 2:] * E[:, 2]
    cov = np.broadcast_to(np.diag([4.0, 1.0, 9.0]), (6, 3, 3))
    ds = check_point_errors(est, ref, cov, along_track=az)
    # small offsets on a sphere: the tangent-plane components are exact to (d / R)
    np.testing.assert_allclose(ds.error.values, d, atol=1e-5)
    np.testing.assert_allclose(ds.error_enu.values[:, 2], d[:, 2], atol=1e-5)
    T = track_basis(ref, az)
    sig = np.sqrt(np.einsum("kij,jl,kil->ki", T, np.diag([4.0, 1.0, 9.0]), T))
    np.testing.assert_allclose(ds.sigma.values, sig, rtol=1e-12)
    np.testing.assert_allclose(ds.attrs["rms"], np.sqrt(np.mean(d ** 2, axis=0)), atol=1e-5)
    assert ds.attrs["overall_rms"] == pytest.approx(np.sqrt(np.sum(np.mean(d ** 2, axis=0))), abs=1e-5)
    # latitude / longitude errors in degrees: 1 m north is 1 / R rad
    north = check_point_errors(ref + E[:, 1], ref, along_track=0.0)
    np.testing.assert_allclose(north.error_lat.values, np.degrees(1.0 / 1737.4e3), rtol=1e-6)
    np.testing.assert_allclose(north.error.values[:, 0], 1.0, atol=1e-6)      # along = north at azimuth 0


def test_along_track_axis_of_polar_orbits_is_north(site):
    az = along_track_azimuth(site.true_cameras, site.true_xyz.mean(axis=0))
    assert min(az, 360 - az) < 0.5


def test_block_check_errors_match_the_block_and_its_sigma(site):
    net = site_network(site)
    nav = NavigationSpec(orbit={n: n for n in site.names}, position_sigma=20.0, attitude_sigma=50e-6,
                         attitude_rate_sigma=2e-6, position_rate_sigma=0.01)
    res = solve_block(build_block(site.nav_cameras, net, degree=1, navigation=nav))
    ds = block_check_errors(res)
    old = res.check_points()               # BlockResult's own east/north/up
    np.testing.assert_allclose(ds.error_enu.values, old.error.values, atol=1e-9)
    np.testing.assert_allclose(ds.sigma_enu.values, old.sigma.values, rtol=1e-9)
    assert ds.attrs["along_track_source"] == "sensors"
    print("check points after adjustment: RMS along/cross/height", np.round(ds.attrs["rms"], 3),
          "expected", np.round(ds.attrs["expected_rms"], 3), "normalised", round(ds.attrs["normalized_rms"], 2))
    assert 0.3 < ds.attrs["normalized_rms"] < 2.5
    before = block_check_errors(res, points=res.block.problem.points)
    assert before.attrs["overall_rms"] > 5 * ds.attrs["overall_rms"]


def _check_dataset(site, images=None) -> xr.Dataset:
    net = site_network(site)
    chk = np.flatnonzero(net.point_type == "check")
    sel = np.isin(net.measure_point, chk)
    pmap = -np.ones(net.n_points, np.int64)
    pmap[chk] = np.arange(chk.size)
    return xr.Dataset({"point_id": ("observation", pmap[net.measure_point[sel]]),
                       "image_id": ("observation", net.measure_image[sel]),
                       "line": ("observation", net.line_sample[sel, 0]),
                       "sample": ("observation", net.line_sample[sel, 1]),
                       "sigma_line": ("observation", net.measure_sigma[sel, 0]),
                       "sigma_sample": ("observation", net.measure_sigma[sel, 1])},
                      coords={"image": net.image_id.astype(object), "point": net.point_id[chk].astype(object)})


def test_triangulation_through_true_cameras_is_normalised():
    """Errors / predicted sigma of check points intersected through the true cameras, pooled over 6 sites."""
    z = []
    for seed in range(6):
        s = lroc_site(APOLLO11_LIKE[:3], n_tie=5, n_control=0, n_check=40, sigma_px=0.2, seed=seed)
        tri = triangulate(s.true_cameras, _check_dataset(s))
        assert tri.n_rays.min() == 3 and not tri.skipped
        chk = np.flatnonzero(s.point_type == "check")
        ds = check_point_errors(tri.xyz, s.true_xyz[chk], tri.covariance, names=tri.point_id, sensors=s.true_cameras)
        z.append(ds.normalized.values)
    z = np.concatenate(z)
    rms = np.sqrt(np.mean(z ** 2, axis=0))
    print("triangulated check points, errors / sigma RMS along/cross/height", np.round(rms, 3),
          "pooled", round(float(np.sqrt(np.mean(z ** 2))), 3))
    assert np.all((rms > 0.8) & (rms < 1.2))


def test_bad_input_outside_images_single_image_no_points(site):
    meas = _check_dataset(site)
    # move every measurement of the first check point in A1 and A2 outside the images: it has one ray left
    first = (meas.point_id.values == 0) & np.isin(meas.image_id.values, [0, 1])
    meas["line"].values[first] = -50.0
    tri = triangulate(site.true_cameras, meas)
    assert len(tri.skipped) == 1 and "1 ray(s)" in tri.skipped[0] and tri.xyz.shape[0] == 9
    with pytest.raises(EvaluationInputError, match="at least two images"):
        triangulate(site.true_cameras, meas, images=["A1"])
    with pytest.raises(EvaluationInputError, match="no sensor model"):
        triangulate(site.true_cameras, meas, images=["A1", "B9"])
    meas["line"].values[:] = 1e7
    with pytest.raises(CheckPointError, match="no point has two rays"):
        triangulate(site.true_cameras, meas)
    with pytest.raises(CheckPointError, match="no check point"):
        check_point_errors(np.zeros((0, 3)), np.zeros((0, 3)))
    with pytest.raises(EvaluationInputError, match="estimated points"):
        check_point_errors(np.zeros((2, 3)), np.zeros((3, 3)))
