"""Frame camera: pixel convention, closed-form geometry, round trips, bad input."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from lunarmap.camera import (
    MOON_RADIUS,
    FrameCamera,
    InteriorOrientation,
    Shape,
    focal_to_image,
    image_to_focal,
)
from lunarmap.errors import GeometryError, InvalidInputError, NoIntersectionError
from lunarmap.simulate.orbits import frame_interior, polar_orbit_eo

R = MOON_RADIUS
ALT = 50_000.0


def _unit_affine_io(**kw) -> InteriorOrientation:
    base = dict(focal_length=1.0, focal2pixel_lines=(0.0, 10.0, 0.0), focal2pixel_samples=(0.0, 0.0, 10.0),
                detector_center_line=0.5, detector_center_sample=8.0, n_lines=16, n_samples=16)
    base.update(kw)
    return InteriorOrientation(**base)


def test_pixel_to_focal_matches_usgscsm_unit_tests() -> None:
    # usgscsm UtilitiesTests.computeDistortedFocalPlaneCoordinates: line 0.5, sample 4,
    # sample origin 8, line origin 0.5, iTransS (0, 0, 10), iTransL (0, 10, 0) -> (0, -0.4)
    x, y = image_to_focal(_unit_affine_io(), 0.5, 4.0)
    assert x == pytest.approx(0.0) and y == pytest.approx(-0.4)
    # ...Summing: line 2, sample 4, origins (8, 8), summing 2 -> (-0.4, 0)
    io = _unit_affine_io(detector_center_line=8.0, line_summing=2, sample_summing=2)
    x, y = image_to_focal(io, 2.0, 4.0)
    assert x == pytest.approx(-0.4) and y == pytest.approx(0.0)


def test_pixel_focal_round_trip_with_skewed_affine_and_window() -> None:
    io = _unit_affine_io(focal2pixel_lines=(1.5, 9.0, -2.0), focal2pixel_samples=(-3.0, 1.0, 11.0),
                         starting_detector_line=7.0, starting_detector_sample=100.0,
                         line_summing=2, sample_summing=4)
    rng = np.random.default_rng(0)
    line, sample = rng.uniform(0, 300, (2, 100))
    x, y = image_to_focal(io, line, sample)
    l2, s2 = focal_to_image(io, x, y)
    assert np.allclose(l2, line, atol=1e-10) and np.allclose(s2, sample, atol=1e-10)
    # the detector centre maps to the affine's offset point: x = y = 0 when offsets are 0
    x0, y0 = image_to_focal(_unit_affine_io(), 0.5, 8.0)
    assert (x0, y0) == (0.0, 0.0)


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between vectors, accurate for tiny angles (arccos is not)."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def _camera(lat: float = 0.0, flip: bool = False, odk=(0.0, -2.42e-5, 0.0), roll: float = 0.0) -> FrameCamera:
    eo = polar_orbit_eo(lat_center=lat, lon=30.0, altitude=ALT, half_span=0.0, step=1.0, flip=flip,
                        roll_deg=roll)
    return FrameCamera(frame_interior(odk), eo, Shape.moon())


def test_boresight_hits_sub_spacecraft_point() -> None:
    cam = _camera(odk=None)
    p = cam.sensor_position(144.0, 192.0)
    g = cam.image_to_ground(144.0, 192.0)
    assert np.allclose(g, R * p / np.linalg.norm(p), atol=1e-6)
    assert np.linalg.norm(g - p) == pytest.approx(ALT, abs=1e-6)
    assert np.allclose(cam.look_vector(144.0, 192.0), -p / np.linalg.norm(p), atol=1e-12)


@pytest.mark.parametrize("offset", [-150.0, -37.25, 12.5, 191.0])
def test_off_axis_angle(offset: float) -> None:
    cam = _camera(odk=None)
    nadir = -cam.sensor_position(144.0, 192.0)
    nadir /= np.linalg.norm(nadir)
    for line, sample, shift in ((144.0, 192.0 + offset, offset), (144.0 + offset * 0.7, 192.0, offset * 0.7)):
        look = cam.look_vector(line, sample)
        angle = _angle(look, nadir)
        assert angle == pytest.approx(np.arctan(abs(shift) * 0.023 / 89.87), abs=1e-12)


def test_radial_distortion_at_the_corner() -> None:
    # OD_K = (0, k1, 0), k1 < 0: undistorted = distorted * (1 - k1 r^2) (ISIS CameraDistortionMap),
    # so the corner pixel centre looks at atan(r_d (1 - k1 r_d^2) / f) off-axis.
    cam = _camera()
    p = cam.sensor_position(0.5, 0.5)
    nadir = -p / np.linalg.norm(p)
    r_d = np.hypot(143.5, 191.5) * 0.023
    r_u = r_d * (1.0 + 2.42e-5 * r_d**2)
    angle = _angle(cam.look_vector(0.5, 0.5), nadir)
    assert angle == pytest.approx(np.arctan(r_u / 89.87), abs=1e-12)


@pytest.mark.parametrize("lat,flip", [(0.0, False), (0.0, True), (85.0, False)])
@pytest.mark.parametrize("height", [0.0, 2000.0, -2000.0])
def test_round_trip(lat: float, flip: bool, height: float) -> None:
    cam = _camera(lat=lat, flip=flip)
    rng = np.random.default_rng(11)
    line = rng.uniform(0, 288, 2000)
    sample = rng.uniform(0, 384, 2000)
    g = cam.image_to_ground(line, sample, height=height)
    assert np.allclose(np.linalg.norm(g, axis=-1), R + height, atol=1e-6)
    l2, s2 = cam.ground_to_image(g)
    assert np.max(np.abs(l2 - line)) <= 1e-4
    assert np.max(np.abs(s2 - sample)) <= 1e-4


def test_flip_mirrors_the_image() -> None:
    normal, flipped = _camera(odk=None), _camera(odk=None, flip=True)
    g = normal.image_to_ground([10.0, 200.0], [30.0, 350.0])
    l2, s2 = flipped.ground_to_image(g)
    assert np.allclose(l2, [278.0, 88.0], atol=1e-6)
    assert np.allclose(s2, [354.0, 34.0], atol=1e-6)


def test_dtm_of_constant_height() -> None:
    cam = _camera()
    lat = np.linspace(-1, 1, 41)
    lon = np.linspace(29, 31, 41)
    dtm = xr.DataArray(np.full((41, 41), -750.0), dims=("lat", "lon"), coords={"lat": lat, "lon": lon})
    line, sample = np.meshgrid(np.linspace(0, 288, 7), np.linspace(0, 384, 9))
    a = cam.image_to_ground(line, sample, dtm=dtm)
    b = cam.image_to_ground(line, sample, height=-750.0)
    assert a.shape == line.shape + (3,)
    assert np.max(np.linalg.norm(a - b, axis=-1)) < 1e-3


def test_bad_input() -> None:
    cam = _camera()
    with pytest.raises(InvalidInputError, match="NaN"):
        cam.image_to_ground([1.0, np.nan], [1.0, 2.0])
    with pytest.raises(InvalidInputError):
        cam.image_to_ground(1.0, np.inf)
    with pytest.raises(InvalidInputError):
        cam.ground_to_image([[np.nan, 0.0, 0.0]])
    with pytest.raises(InvalidInputError):
        cam.ground_to_image([1.0, 2.0])
    with pytest.raises(InvalidInputError):
        cam.image_to_ground(1.0, 1.0, height=np.nan)


def test_camera_looking_at_the_sky_misses() -> None:
    cam = _camera(roll=180.0)
    with pytest.raises(NoIntersectionError, match="2 of 2"):
        cam.image_to_ground([10.0, 20.0], [10.0, 20.0])
    assert np.all(np.isnan(cam.image_to_ground(10.0, 10.0, on_miss="nan")))


def test_points_not_seen() -> None:
    cam = _camera()
    p = cam.sensor_position(0, 0)
    behind = 2.0 * p  # above the sensor, i.e. behind it
    beside = cam.image_to_ground(144.0, 192.0) + np.array([0.0, 0.0, 20_000.0])  # 20 km off the footprint
    inside = cam.image_to_ground(100.0, 100.0)
    pts = np.stack([behind, beside, inside])
    line, sample = cam.ground_to_image(pts)
    assert np.all(np.isnan(line[:2])) and np.all(np.isfinite(line[2:]))
    line, sample = cam.ground_to_image(pts, within_image=False)
    assert np.isnan(line[0]) and np.isfinite(line[1]) and (line[1] < 0 or line[1] > 288 or sample[1] < 0
                                                          or sample[1] > 384)
    with pytest.raises(GeometryError, match="2 of 3"):
        cam.ground_to_image(pts, on_miss="raise")


def test_shapes_and_explicit_time() -> None:
    eo = polar_orbit_eo(half_span=1.0, step=0.5)
    cam = FrameCamera(frame_interior(), eo, time=0.5)
    assert np.allclose(cam.sensor_position(0, 0), eo.position_at(0.5))
    g = cam.image_to_ground(np.full((2, 3), 100.0), 50.0)
    assert g.shape == (2, 3, 3)
    line, sample = cam.ground_to_image(g)
    assert line.shape == (2, 3) and np.allclose(line, 100.0, atol=1e-6)
