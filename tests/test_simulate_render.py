"""Simulator: terrain generators and the renderer against closed-form oracles."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from lunarmap.camera import MOON_RADIUS, lonlat_height_to_xyz
from lunarmap.errors import InvalidInputError
from lunarmap.simulate import (
    SimulationWarning,
    add_craters,
    local_grid,
    look_angle_for_emission,
    pointed_camera,
    render_image,
    stereo_pair,
    synthetic_albedo,
    synthetic_dtm,
)

LON0, LAT0 = 30.0, 0.0


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), np.dot(a, b))))


def test_local_grid_spacing_on_the_ground() -> None:
    lat, lon, north, east = local_grid(LON0, 10.0, 100.0, 2.0)
    # Independent path: distance between body-fixed node positions.
    p = lonlat_height_to_xyz(lon[:2], [10.0, 10.0])
    assert np.linalg.norm(p[1] - p[0]) == pytest.approx(2.0, rel=1e-6)
    q = lonlat_height_to_xyz([LON0, LON0], lat[:2])
    assert np.linalg.norm(q[1] - q[0]) == pytest.approx(2.0, rel=1e-6)
    assert east[0] == pytest.approx(-east[-1]) and north.size == lat.size


def test_crater_profile_matches_morphometry() -> None:
    north = east = np.arange(-100.0, 100.5, 0.5)
    flat = np.zeros((north.size, east.size))
    rng = np.random.default_rng(3)
    d = 40.0
    h = add_craters(flat, north, east, 1, d, d, rng)  # d_min == d_max fixes the diameter
    i, j = np.unravel_index(np.argmin(h), h.shape)
    # Floor: d ((r/R)^2 - 1) + h_rim at r = 0 -> -0.2 D + 0.04 D.
    assert h[i, j] == pytest.approx(-0.2 * d + 0.04 * d, abs=0.05)
    # The maximum sits on the rim (r = R) at 0.04 D.
    rr = np.hypot(north[:, None] - north[i], east[None, :] - east[j])
    assert np.max(h) == pytest.approx(0.04 * d, abs=0.05)
    assert np.all(np.abs(rr[h == np.max(h)] - d / 2) < 1.0)


def test_synthetic_dtm_relief_and_albedo() -> None:
    # the rolling terrain alone (no craters): heights of standard deviation `relief` about zero,
    # linear in `relief` for one seed, and no wavelength much shorter than `wavelength`
    a = synthetic_dtm(LON0, LAT0, 200.0, 2.0, relief=3.0, crater_density=0.0, seed=4)
    b = synthetic_dtm(LON0, LAT0, 200.0, 2.0, relief=6.0, crater_density=0.0, seed=4)
    assert a.dims == ("lat", "lon") and np.all(np.isfinite(a.values))
    assert float(a.std()) == pytest.approx(3.0, rel=1e-9) and abs(float(a.mean())) < 1e-9
    np.testing.assert_allclose(b.values, 2.0 * a.values, rtol=1e-12)
    k = np.hypot(np.fft.fftfreq(a.shape[0], 2.0)[:, None], np.fft.rfftfreq(a.shape[1], 2.0)[None, :])
    for dtm, shortest in ((a, 40.0), (synthetic_dtm(LON0, LAT0, 200.0, 2.0, relief=3.0, wavelength=80.0,
                                                    crater_density=0.0, seed=4), 80.0)):
        power = np.abs(np.fft.rfft2(dtm.values)) ** 2
        # the Gaussian roll-off below `wavelength` (default 20 spacings): measured 1e-4 / 2e-7 (40 m)
        assert power[k > 2.0 / shortest].sum() < 1e-3 * power.sum()
        assert power[k > 3.0 / shortest].sum() < 1e-5 * power.sum()
    # craters dig bowls: floors at -0.16 D below the terrain for D >= d_min = 16 m, so below -2.5 m here
    c = synthetic_dtm(LON0, LAT0, 200.0, 2.0, relief=0.0, crater_density=0.05, seed=4)
    assert float(c.min()) < -0.16 * 16.0 + 0.1
    alb = synthetic_albedo(LON0, LAT0, 200.0, 0.5, feature_size=1.0)
    assert float(alb.min()) > 0 and float(alb.max()) < 1
    with pytest.raises(InvalidInputError, match="feature_size"):
        synthetic_albedo(LON0, LAT0, 200.0, 0.5, feature_size=0.6)


def test_rendered_relief_shows_its_parallax() -> None:
    """A mark on top of a 20 m hill, seen 30 deg off nadir, appears where the camera projects the hilltop,
    ~23 px away from where it would appear without the hill: the renderer intersects the DTM."""
    lat, lon, north, east = local_grid(LON0, LAT0, 400.0, 0.25)
    hill = 20.0 * np.exp(-0.5 * (north[:, None] ** 2 + east[None, :] ** 2) / 40.0 ** 2)
    dtm = xr.DataArray(hill, dims=("lat", "lon"), coords={"lat": lat, "lon": lon})
    mark = 0.3 + 0.5 * np.exp(-0.5 * (north[:, None] ** 2 + east[None, :] ** 2) / 1.5 ** 2)
    ortho = xr.DataArray(mark, dims=("lat", "lon"), coords={"lat": lat, "lon": lon})
    cam = pointed_camera("linescan", LON0, LAT0, 30.0, n_lines=96, n_samples=96)
    img = render_image(cam, dtm, ortho, supersample=3).values
    w = np.clip(img - 255.0 * 0.3 * 1.02, 0.0, None)           # the mark above the background
    li, si = np.meshgrid(np.arange(96) + 0.5, np.arange(96) + 0.5, indexing="ij")
    seen = np.array([np.sum(w * li), np.sum(w * si)]) / np.sum(w)
    top = lonlat_height_to_xyz(LON0, LAT0, 20.0)
    on_hill = np.array(cam.ground_to_image(top), dtype=float).ravel()
    no_hill = np.array(cam.ground_to_image(lonlat_height_to_xyz(LON0, LAT0, 0.0)), dtype=float).ravel()
    assert np.hypot(*(on_hill - no_hill)) > 15.0              # the parallax the hill must produce
    assert np.hypot(*(seen - on_hill)) < 0.2, (seen, on_hill, no_hill)


def test_stereo_pair_has_requested_convergence() -> None:
    c1, c2 = stereo_pair("linescan", 30.0, n_lines=64, n_samples=64)
    target = lonlat_height_to_xyz(LON0, LAT0)
    for c in (c1, c2):
        g = c.image_to_ground(32.0, 32.0, height=0.0)
        assert np.linalg.norm(g - target) < 0.01
    v1 = c1.sensor_position(32.0, 32.0) - target
    v2 = c2.sensor_position(32.0, 32.0) - target
    assert _angle_deg(v1, v2) == pytest.approx(30.0, abs=1e-3)
    assert look_angle_for_emission(0.0, 50e3) == 0.0


def _linear_ortho(extent: float = 600.0, spacing: float = 0.5) -> xr.DataArray:
    lat, lon, north, east = local_grid(LON0, LAT0, extent, spacing)
    return xr.DataArray(0.3 + 0.001 * east[None, :] + 0.0005 * north[:, None], dims=("lat", "lon"),
                        coords={"lat": lat, "lon": lon})


def _flat_dtm(extent: float = 600.0, spacing: float = 5.0, slope_e: float = 0.0) -> xr.DataArray:
    lat, lon, north, east = local_grid(LON0, LAT0, extent, spacing)
    return xr.DataArray(slope_e * east[None, :] + 0.0 * north[:, None], dims=("lat", "lon"),
                        coords={"lat": lat, "lon": lon})


def test_render_linear_scene_equals_pixel_centre_value() -> None:
    """A box-filtered linear ortho on flat ground is the ortho at the pixel-centre ray's ground point."""
    cam = pointed_camera("linescan", LON0, LAT0, 15.0, n_lines=40, n_samples=40)
    img = render_image(cam, _flat_dtm(), _linear_ortho(), supersample=4, gain=100.0, chunks=16).values
    li, si = np.meshgrid(np.arange(40) + 0.5, np.arange(40) + 0.5, indexing="ij")
    g = cam.image_to_ground(li.ravel(), si.ravel(), height=0.0)  # sphere intersection, not the DTM path
    lon = np.degrees(np.arctan2(g[:, 1], g[:, 0]))
    lat = np.degrees(np.arctan2(g[:, 2], np.hypot(g[:, 0], g[:, 1])))
    east = np.radians(lon - LON0) * MOON_RADIUS
    north = np.radians(lat - LAT0) * MOON_RADIUS
    truth = 100.0 * (0.3 + 0.001 * east + 0.0005 * north)
    assert np.max(np.abs(img.ravel() - truth)) < 2e-3


def test_lambert_shading_of_a_tilted_plane() -> None:
    slope = 0.2  # metres per metre, rising to the east
    sun = lonlat_height_to_xyz(LON0 + 40.0, LAT0 + 10.0)  # a direction; the Sun is far
    cam = pointed_camera("frame", LON0, LAT0, 0.0)
    ortho = _linear_ortho(9000.0, 20.0) * 0 + 0.5
    img = render_image(cam, _flat_dtm(9000.0, 20.0, slope), ortho, supersample=1, sun=sun,
                       window=(130, 150, 180, 200)).values
    s = sun / np.linalg.norm(sun)
    lam, phi = np.radians(LON0), np.radians(LAT0)
    east = np.array([-np.sin(lam), np.cos(lam), 0.0])
    up = np.array([np.cos(phi) * np.cos(lam), np.cos(phi) * np.sin(lam), np.sin(phi)])
    n = (up - slope * east) / np.hypot(1.0, slope)
    expected = 255.0 * 0.5 * np.dot(n, s) / np.dot(up, s)
    # Curvature over the small window changes 'up' by < 0.01 deg: tolerance 0.05 grey levels.
    assert np.allclose(img, expected, atol=0.05)


def test_noise_level_and_reproducibility() -> None:
    cam = pointed_camera("linescan", LON0, LAT0, 0.0, n_lines=64, n_samples=64)
    dtm, ortho = _flat_dtm(), _linear_ortho()
    clean = render_image(cam, dtm, ortho, supersample=1, chunks=32).values
    noisy = render_image(cam, dtm, ortho, supersample=1, noise_sigma=2.0, seed=5, chunks=32).values
    again = render_image(cam, dtm, ortho, supersample=1, noise_sigma=2.0, seed=5, chunks=32).values
    assert np.std(noisy - clean) == pytest.approx(2.0, rel=0.05)
    assert np.array_equal(noisy, again)


def test_projected_orthoimage_equals_latlon_one() -> None:
    """Peer check: the same albedo on an equirectangular map grid (through PROJ) renders identically."""
    cam = pointed_camera("linescan", LON0, LAT0, 10.0, n_lines=32, n_samples=32)
    ll = _linear_ortho()
    r = MOON_RADIUS
    proj = xr.DataArray(ll.values, dims=("y", "x"),
                        coords={"y": np.radians(ll.lat.values) * r, "x": np.radians(ll.lon.values) * r},
                        attrs={"crs": f"+proj=eqc +R={r} +units=m +no_defs +type=crs"})
    a = render_image(cam, _flat_dtm(), ll, supersample=2).values
    b = render_image(cam, _flat_dtm(), proj, supersample=2).values
    assert np.max(np.abs(a - b)) < 1e-3


def test_pixels_outside_the_dtm_are_nan_with_a_warning() -> None:
    cam = pointed_camera("linescan", LON0, LAT0, 0.0, n_lines=64, n_samples=64)  # 32 m footprint
    small = _flat_dtm(20.0, 1.0)
    with pytest.warns(SimulationWarning, match="NaN"):
        img = render_image(cam, small, _linear_ortho(), supersample=1).values
    assert np.isnan(img).any() and np.isfinite(img).any()


def test_render_rejects_bad_arguments() -> None:
    cam = pointed_camera("linescan", LON0, LAT0, 0.0, n_lines=16, n_samples=16)
    with pytest.raises(InvalidInputError, match="supersample"):
        render_image(cam, _flat_dtm(), _linear_ortho(), supersample=0)
    with pytest.raises(InvalidInputError, match="sun"):
        render_image(cam, _flat_dtm(), _linear_ortho(), sun="moon")
    with pytest.raises(InvalidInputError, match="dims"):
        render_image(cam, _flat_dtm(), _linear_ortho().rename(lat="a", lon="b"))
