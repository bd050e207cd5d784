"""Ray intersection with ellipsoids and DTMs, against closed forms."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from lunarmap.camera import (
    MOON_RADIUS,
    DtmSampler,
    intersect_dtm,
    intersect_ellipsoid,
    intersect_sphere,
    lonlat_height_to_xyz,
    xyz_to_lonlat_height,
)
from lunarmap.errors import ConvergenceError, InvalidInputError, NoIntersectionError

R = MOON_RADIUS
ALT = 50_000.0


def _fan(n: int, max_angle_deg: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rays from (R+ALT, 0, 0) at off-nadir angles up to max_angle, random azimuths."""
    rng = np.random.default_rng(seed)
    ang = np.radians(rng.uniform(0.0, max_angle_deg, n))
    az = rng.uniform(0.0, 2 * np.pi, n)
    d = np.stack([-np.cos(ang), np.sin(ang) * np.cos(az), np.sin(ang) * np.sin(az)], axis=-1)
    o = np.broadcast_to([R + ALT, 0.0, 0.0], d.shape).copy()
    return o, d, ang


def test_sphere_closed_form() -> None:
    o, d, ang = _fan(1000, 60.0)
    p = intersect_sphere(o, d, R)
    r = R + ALT
    s = r * np.cos(ang) - np.sqrt(R**2 - (r * np.sin(ang)) ** 2)  # law of cosines
    assert np.max(np.abs(np.linalg.norm(p - o, axis=-1) - s)) < 1e-6
    assert np.max(np.abs(np.linalg.norm(p, axis=-1) - R)) < 1e-6
    # nadir ray hits the sub-spacecraft point at distance r - R
    p0 = intersect_ellipsoid([[R + ALT, 0, 0]], [[-1.0, 0, 0]], [R, R, R])
    assert np.allclose(p0, [[R, 0, 0]], atol=1e-9)


def test_ellipsoid_axes_and_scaled_direction() -> None:
    axes = np.array([3.0, 2.0, 1.0])
    o = np.array([[10.0, 0, 0], [0, 10.0, 0], [0, 0, 10.0]])
    p = intersect_ellipsoid(o, -o * 7.0, axes)  # direction length does not matter
    assert np.allclose(p, np.diag(axes))
    # origin inside: the exit point is returned
    p = intersect_ellipsoid([[0.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]], axes)
    assert np.allclose(p, [[0.0, 2.0, 0.0]])
    # per-ray axes (heights)
    p = intersect_ellipsoid(o[:1].repeat(2, 0), -o[:1].repeat(2, 0), axes + np.array([[0.0], [1.0]]))
    assert np.allclose(p[:, 0], [3.0, 4.0])


def test_misses() -> None:
    o = np.array([[R + ALT, 0, 0]] * 3)
    d = np.array([[-1.0, 0, 0], [1.0, 0, 0], [0.0, 1.0, 0.0]])  # nadir, zenith, horizontal
    with pytest.raises(NoIntersectionError, match="2 of 3"):
        intersect_sphere(o, d, R)
    p = intersect_sphere(o, d, R, on_miss="nan")
    assert np.all(np.isfinite(p[0])) and np.all(np.isnan(p[1:]))
    with pytest.raises(InvalidInputError):
        intersect_sphere([[np.nan, 0, 0]], [[1.0, 0, 0]], R)
    with pytest.raises(InvalidInputError):
        intersect_sphere(o, d, R, on_miss="ignore")  # type: ignore[arg-type]


def _grid_dtm(fn, lat0: float, lat1: float, lon0: float, lon1: float, n: int) -> xr.DataArray:
    lat = np.linspace(lat0, lat1, n)
    lon = np.linspace(lon0, lon1, n)
    glat, glon = np.meshgrid(lat, lon, indexing="ij")
    return xr.DataArray(fn(glon, glat), dims=("lat", "lon"), coords={"lat": lat, "lon": lon})


def test_dtm_sampler_is_bilinear_and_wraps() -> None:
    dtm = _grid_dtm(lambda lon, lat: 3.0 * lon - 2.0 * lat + 0.5 * lon * lat, -2, 2, 350, 360, 11)
    s = DtmSampler(dtm)
    lon = np.array([-5.0, 355.3, 351.0])
    lat = np.array([0.3, -1.7, 1.99])
    lon360 = np.mod(lon, 360.0)
    assert np.allclose(s(lon, lat), 3.0 * lon360 - 2.0 * lat + 0.5 * lon360 * lat)
    assert np.isnan(s(np.array([10.0]), np.array([0.0]))[0])
    # descending latitude, transposed dims
    flipped = dtm.isel(lat=slice(None, None, -1)).transpose("lon", "lat")
    assert np.allclose(DtmSampler(flipped)(lon, lat), s(lon, lat))
    with pytest.raises(InvalidInputError):
        DtmSampler(dtm.rename(lat="y"))


def test_constant_dtm_equals_sphere() -> None:
    o, d, _ = _fan(500, 3.0)
    dtm = _grid_dtm(lambda lon, lat: np.full_like(lon, 1234.5), -5, 5, -5, 5, 21)
    p = intersect_dtm(o, d, dtm, R)
    q = intersect_sphere(o, d, R + 1234.5)
    assert np.max(np.linalg.norm(p - q, axis=-1)) < 1e-3


def _plane_dtm(normal: np.ndarray, point: np.ndarray, n: int = 801, half: float = 0.2) -> xr.DataArray:
    """Heights of the 3-D plane through ``point`` with ``normal``, sampled radially."""
    def height(lon, lat):
        u = lonlat_height_to_xyz(lon, lat, 0.0) / R
        return (normal @ point) / (u @ normal) - R
    return _grid_dtm(height, -half, half, -half, half, n)


@pytest.mark.parametrize("tilt_deg", [10.0, 45.0, 70.0])
def test_tilted_plane_dtm_matches_ray_plane(tilt_deg: float) -> None:
    t = np.radians(tilt_deg)
    normal = np.array([np.cos(t), np.sin(t) * 0.6, np.sin(t) * 0.8])
    point = np.array([R + 500.0, 0.0, 0.0])
    dtm = _plane_dtm(normal, point)
    o, d, _ = _fan(400, 4.0, seed=tilt_deg.__hash__() % 100)
    p = intersect_dtm(o, d, dtm, R, on_miss="nan")
    s = (normal @ point - o @ normal) / (d @ normal)
    exact = o + s[:, None] * d
    ok = np.isfinite(p[:, 0])
    assert ok.all()  # every exact intersection lies inside the 0.4 degree tile
    assert np.max(np.linalg.norm(p[ok] - exact[ok], axis=-1)) < 5e-3
    # the heights of the solution agree with the DTM to the 1 mm tolerance
    lon, lat, h = xyz_to_lonlat_height(p[ok])
    assert np.max(np.abs(DtmSampler(dtm)(lon, lat) - h)) < 1e-3


def test_dtm_miss_and_convergence_errors() -> None:
    dtm = _grid_dtm(lambda lon, lat: np.zeros_like(lon), -1, 1, -1, 1, 5)
    o = np.array([[R + ALT, 0, 0], [0.0, R + ALT, 0.0], [R + ALT, 0, 0]])
    d = np.array([[-1.0, 0, 0], [0.0, -1.0, 0.0], [1.0, 0, 0]])  # on DTM, off DTM, at the sky
    with pytest.raises(NoIntersectionError, match="2 of 3"):
        intersect_dtm(o, d, dtm, R)
    p = intersect_dtm(o, d, dtm, R, on_miss="nan")
    assert np.allclose(p[0], [R, 0, 0], atol=1e-3) and np.all(np.isnan(p[1:]))
    rough = _grid_dtm(lambda lon, lat: 3000.0 * np.sin(40 * lon) * np.cos(30 * lat), -1, 1, -1, 1, 401)
    with pytest.raises(ConvergenceError):
        intersect_dtm(o[:1], [[-1.0, 0.3, 0.2]], rough, R, max_iter=2)
