"""Body shape and planetocentric geodesy (closed form vs the IAU 2015 Moon CRS in PROJ)."""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.camera import (
    MOON_RADIUS,
    MOON_RADIUS_HISTORICAL,
    Shape,
    enu_basis,
    lonlat_height_to_xyz,
    moon_geocentric_crs,
    moon_geographic_crs,
    pyproj_lonlat_height_to_xyz,
    pyproj_xyz_to_lonlat_height,
    xyz_to_lonlat_height,
)
from lunarmap.errors import InvalidInputError


def test_shape_constructors() -> None:
    s = Shape.sphere(1737400.0)
    assert s.is_sphere and s.reference_radius == 1737400.0
    assert np.array_equal(s.axes_at_height(100.0), [1737500.0] * 3)
    assert Shape.moon().a == MOON_RADIUS == 1737400.0
    assert MOON_RADIUS_HISTORICAL == 1736600.0
    e = Shape.ellipsoid(1738100.0, 1737400.0, 1736000.0)
    assert not e.is_sphere and e.reference_radius == pytest.approx(1737166.6666666667)
    assert Shape.ellipsoid(3.0, 2.0, 1.0, reference_radius=2.5).reference_radius == 2.5
    assert Shape.sphere(2.0).axes_at_height(np.array([1.0, 2.0])).shape == (2, 3)
    with pytest.raises(InvalidInputError):
        Shape.ellipsoid(1.0, -1.0, 1.0)
    with pytest.raises(InvalidInputError):
        Shape.sphere(float("nan"))


def test_crs_are_the_iau_2015_moon_sphere() -> None:
    geog = moon_geographic_crs()
    assert geog.ellipsoid.semi_major_metre == MOON_RADIUS
    assert geog.ellipsoid.semi_minor_metre == MOON_RADIUS
    assert len(geog.axis_info) == 3  # lat, lon, height
    assert moon_geocentric_crs().is_geocentric
    assert moon_geocentric_crs().datum == geog.datum


@pytest.fixture(scope="module")
def cloud() -> np.ndarray:
    rng = np.random.default_rng(7)
    lon = rng.uniform(-180.0, 180.0, 5000)
    lat = np.degrees(np.arcsin(rng.uniform(-1.0, 1.0, 5000)))
    h = rng.uniform(-10_000.0, 60_000.0, 5000)
    return lonlat_height_to_xyz(lon, lat, h)


def test_closed_form_matches_pyproj_to_a_micrometre(cloud: np.ndarray) -> None:
    lon, lat, h = xyz_to_lonlat_height(cloud, MOON_RADIUS)
    plon, plat, ph = pyproj_xyz_to_lonlat_height(cloud)
    r = np.linalg.norm(cloud, axis=-1)
    dlon = np.radians((lon - plon + 180.0) % 360.0 - 180.0) * r * np.cos(np.radians(lat))
    dlat = np.radians(lat - plat) * r
    assert np.max(np.abs(dlon)) < 1e-6
    assert np.max(np.abs(dlat)) < 1e-6
    assert np.max(np.abs(h - ph)) < 1e-6
    back = pyproj_lonlat_height_to_xyz(lon, lat, h)
    assert np.max(np.linalg.norm(back - cloud, axis=-1)) < 1e-6


def test_round_trip_and_other_radius(cloud: np.ndarray) -> None:
    lon, lat, h = xyz_to_lonlat_height(cloud, MOON_RADIUS_HISTORICAL)
    assert np.max(np.linalg.norm(lonlat_height_to_xyz(lon, lat, h, MOON_RADIUS_HISTORICAL) - cloud, axis=-1)) < 1e-6
    _, _, h_modern = xyz_to_lonlat_height(cloud)
    assert np.allclose(h - h_modern, 800.0, atol=1e-6)


def test_known_points() -> None:
    lon, lat, h = xyz_to_lonlat_height([[0.0, MOON_RADIUS + 5.0, 0.0], [0.0, 0.0, -MOON_RADIUS]])
    assert lon[0] == 90.0 and lat[0] == 0.0 and h[0] == pytest.approx(5.0)
    assert lat[1] == -90.0 and h[1] == 0.0
    with pytest.raises(InvalidInputError):
        xyz_to_lonlat_height(np.zeros((3, 2)))
    with pytest.raises(InvalidInputError):
        pyproj_xyz_to_lonlat_height([np.nan, 0.0, 0.0])


def test_enu_basis() -> None:
    b = enu_basis(0.0, 0.0)
    assert np.allclose(b, [[0, 1, 0], [0, 0, 1], [1, 0, 0]])
    rng = np.random.default_rng(3)
    lon = rng.uniform(-180, 180, 100)
    lat = rng.uniform(-90, 90, 100)
    b = enu_basis(lon, lat)
    assert b.shape == (100, 3, 3)
    assert np.allclose(b @ np.swapaxes(b, -1, -2), np.eye(3), atol=1e-15)
    assert np.allclose(np.cross(b[:, 0], b[:, 1]), b[:, 2], atol=1e-15)  # right-handed
    up = lonlat_height_to_xyz(lon, lat, 0.0) / MOON_RADIUS
    assert np.allclose(b[:, 2], up, atol=1e-15)
    # north points towards increasing latitude
    step = lonlat_height_to_xyz(lon, lat + 1e-6, 0.0) - lonlat_height_to_xyz(lon, lat, 0.0)
    assert np.all(np.einsum("ni,ni->n", step, b[:, 1]) > 0)
