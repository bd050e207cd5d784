"""Line-scan camera: timing convention, closed-form geometry, full-image round trips."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from lunarmap.camera import MOON_RADIUS, LineScanCamera, LineTimes, Shape, xyz_to_lonlat_height
from lunarmap.errors import GeometryError, InvalidInputError, NoIntersectionError
from lunarmap.simulate.orbits import (
    NAC_LINE_TIME,
    NAC_LINES,
    NAC_SAMPLES,
    nac_like_interior,
    orbit_state,
    polar_orbit_eo,
)

R = MOON_RADIUS
ALT = 50_000.0
T0 = -NAC_LINES * NAC_LINE_TIME / 2.0  # image centred on t = 0


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle between vectors, accurate for tiny angles (arccos is not)."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def _camera(lat: float = 0.0, flip: bool = False, k1: float | None = 1.81e-5, roll: float = 0.0,
            detector_center_line: float = 0.5) -> LineScanCamera:
    eo = polar_orbit_eo(lat_center=lat, lon=30.0, altitude=ALT, half_span=12.0, step=0.05, flip=flip,
                        roll_deg=roll)
    io = nac_like_interior(k1=k1, detector_center_line=detector_center_line)
    return LineScanCamera(io, eo, Shape.moon(), line_times=(T0, NAC_LINE_TIME))


@pytest.fixture(scope="module")
def pixels() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(2024)
    return rng.uniform(0, NAC_LINES, 2000), rng.uniform(0, NAC_SAMPLES, 2000)


CASES = {"normal": dict(lat=0.0), "flipped": dict(lat=0.0, flip=True), "lat85": dict(lat=85.0)}


@pytest.fixture(scope="module", params=sorted(CASES))
def camera(request) -> LineScanCamera:
    return _camera(**CASES[request.param])


@pytest.mark.parametrize("height", [0.0, 2000.0, -2000.0])
def test_round_trip_full_image(camera: LineScanCamera, pixels, height: float) -> None:
    line, sample = pixels
    g = camera.image_to_ground(line, sample, height=height)
    assert np.allclose(np.linalg.norm(g, axis=-1), R + height, atol=1e-6)
    l2, s2 = camera.ground_to_image(g)
    assert np.max(np.abs(l2 - line)) <= 1e-4
    assert np.max(np.abs(s2 - sample)) <= 1e-4


def test_image_corners_round_trip(camera: LineScanCamera) -> None:
    line = np.array([0.0, 0.0, NAC_LINES, NAC_LINES, 0.5])
    sample = np.array([0.0, NAC_SAMPLES, 0.0, NAC_SAMPLES, 0.5])
    l2, s2 = camera.ground_to_image(camera.image_to_ground(line, sample))
    assert np.max(np.abs(l2 - line)) <= 1e-4 and np.max(np.abs(s2 - sample)) <= 1e-4


def test_latitude_of_85_degree_case() -> None:
    cam = _camera(lat=85.0)
    _, lat, _ = xyz_to_lonlat_height(cam.image_to_ground(NAC_LINES / 2, NAC_SAMPLES / 2))
    assert lat == pytest.approx(85.0, abs=1e-3)


def test_line_time_convention() -> None:
    cam = _camera()
    # t(L) = t0 + L dt: the first line starts at t0, its centre (L = 0.5) is exposed at t0 + dt/2
    assert cam.image_time(0.0) == T0
    assert cam.image_time(0.5) == pytest.approx(T0 + 0.5 * NAC_LINE_TIME, abs=1e-12)
    assert np.allclose(cam.sensor_position(0.5, 100.0), cam.eo.position_at(T0 + 0.5 * NAC_LINE_TIME))
    # ALE/usgscsm line_scan_rate [[0.5, t_start, dt]]: time = t_start + dt * (L - 0.5 + 0.5)
    lt = LineTimes.from_line_scan_rate([[0.5, T0, NAC_LINE_TIME]])
    assert np.allclose(lt.time([0.0, 0.5, 1000.25]), T0 + NAC_LINE_TIME * np.array([0.0, 0.5, 1000.25]))
    # two segments, usgscsm's piecewise formula time_k + rate_k (L - line_k + 0.5)
    lt2 = LineTimes.from_line_scan_rate([[0.5, 0.0, 1e-3], [100.5, 0.1, 2e-3]], time_offset=1.0)
    assert lt2.time(50.0) == pytest.approx(1.0 + 1e-3 * 50.0)
    assert lt2.time(150.0) == pytest.approx(1.1 + 2e-3 * 50.0)
    assert np.allclose(lt2.line(lt2.time([10.0, 120.0, 300.0])), [10.0, 120.0, 300.0])
    with pytest.raises(InvalidInputError):
        LineTimes.uniform(0.0, -1.0)


def test_nadir_sample_hits_sub_spacecraft_point() -> None:
    # detector line through the principal point, no distortion: the centre sample looks at nadir
    cam = _camera(k1=None, detector_center_line=0.0)
    line = np.array([0.0, 1234.5, 40000.0])
    pos, _ = orbit_state(cam.image_time(line), 0.0, 30.0, ALT)
    g = cam.image_to_ground(line, np.full(3, NAC_SAMPLES / 2))
    assert np.allclose(g, R * pos / np.linalg.norm(pos, axis=-1, keepdims=True), atol=1e-6)
    assert np.allclose(np.linalg.norm(g - pos, axis=-1), ALT, atol=1e-6)
    # and the analytic sub-spacecraft point at t(L) is imaged at (L, centre sample)
    l2, s2 = cam.ground_to_image(R * pos / np.linalg.norm(pos, axis=-1, keepdims=True))
    assert np.allclose(l2, line, atol=1e-6) and np.allclose(s2, NAC_SAMPLES / 2, atol=1e-6)


@pytest.mark.parametrize("offset", [-2500.0, -100.25, 1.0, 2531.0])
def test_off_nadir_angle(offset: float) -> None:
    cam = _camera(k1=None, detector_center_line=0.0)
    line = np.array([5000.0])
    look = cam.look_vector(line, NAC_SAMPLES / 2 + offset)
    pos = cam.sensor_position(line, 0.0)
    nadir = -pos / np.linalg.norm(pos, axis=-1, keepdims=True)
    angle = _angle(look, nadir)
    assert angle == pytest.approx(np.arctan(abs(offset) * 0.007 / 699.62), abs=1e-12)


def test_detector_line_offset_looks_along_track() -> None:
    # detector_center_line 0.5, starting line 0: x = -0.5 px * 7 um; the look leans by atan(0.0035/699.62)
    cam = _camera(k1=None)
    look = cam.look_vector(5000.0, NAC_SAMPLES / 2)
    pos = cam.sensor_position(5000.0, 0.0)
    assert _angle(look, -pos) == pytest.approx(np.arctan(0.0035 / 699.62), rel=1e-9)


def test_flipped_scan_mirrors_samples() -> None:
    normal = _camera(k1=None, detector_center_line=0.0)
    flipped = _camera(k1=None, detector_center_line=0.0, flip=True)
    line = np.array([10.0, 26000.0, 52000.0])
    sample = np.array([100.0, 2532.0, 4000.0])
    l2, s2 = flipped.ground_to_image(normal.image_to_ground(line, sample))
    assert np.allclose(l2, line, atol=1e-5)
    assert np.allclose(s2, NAC_SAMPLES - sample, atol=1e-5)


def test_points_not_seen() -> None:
    cam = _camera()
    before = cam.image_to_ground(0.5, 100.0)
    # move 200 lines (about 110 m) against the flight direction: imaged before the first line
    pos0 = cam.sensor_position(0.0, 0.0)
    pos1 = cam.sensor_position(200.0, 0.0)
    step = (pos1 - pos0) * R / np.linalg.norm(pos0)
    early = before - step
    far_side = -cam.image_to_ground(26000.0, 2000.0)  # antipode: behind the Moon and the camera
    off_track = cam.image_to_ground(26000.0, 2000.0) + np.cross(step, before) / np.linalg.norm(
        np.cross(step, before)) * 5000.0  # 5 km across track, outside the 2.5 km swath
    inside = cam.image_to_ground(300.0, 300.0)
    pts = np.stack([early, far_side, off_track, inside])
    line, sample = cam.ground_to_image(pts)
    assert np.all(np.isnan(line[:3])) and np.all(np.isnan(sample[:3]))
    assert line[3] == pytest.approx(300.0, abs=1e-4)
    line, sample = cam.ground_to_image(pts, within_image=False)
    assert line[0] == pytest.approx(0.5 - 200.0, abs=0.5)
    assert np.isnan(line[1])
    assert np.isfinite(sample[2]) and (sample[2] < 0 or sample[2] > NAC_SAMPLES)
    with pytest.raises(GeometryError, match="3 of 4"):
        cam.ground_to_image(pts, on_miss="raise")


def test_bad_input_and_sky() -> None:
    cam = _camera()
    with pytest.raises(InvalidInputError):
        cam.image_to_ground(np.nan, 1.0)
    with pytest.raises(InvalidInputError):
        cam.ground_to_image(np.array([[1.0, np.inf, 0.0]]))
    sky = _camera(roll=180.0)
    with pytest.raises(NoIntersectionError):
        sky.image_to_ground([1.0, 2.0], [1.0, 2.0])
    with pytest.raises(InvalidInputError, match="line_times"):
        LineScanCamera(cam.interior, cam.eo)


def test_dtm_and_output_shapes() -> None:
    cam = _camera()
    lat = np.linspace(-2, 2, 81)
    lon = np.linspace(29, 31, 41)
    dtm = xr.DataArray(np.full((81, 41), 321.0), dims=("lat", "lon"), coords={"lat": lat, "lon": lon})
    line = np.array([[0.0, 10000.0, 52224.0], [300.0, 20000.0, 40000.0]])
    sample = np.array([[0.0, 2000.0, 5064.0], [17.0, 1000.0, 4000.0]])
    a = cam.image_to_ground(line, sample, dtm=dtm)
    b = cam.image_to_ground(line, sample, height=321.0)
    assert a.shape == (2, 3, 3)
    assert np.max(np.linalg.norm(a - b, axis=-1)) < 1e-3
    l2, s2 = cam.ground_to_image(a)
    assert l2.shape == (2, 3)
    assert np.allclose(l2, line, atol=1e-4) and np.allclose(s2, sample, atol=1e-4)


def test_eo_must_cover_the_image() -> None:
    eo = polar_orbit_eo(half_span=1.0, step=0.05)
    cam = LineScanCamera(nac_like_interior(), eo, line_times=(100.0, NAC_LINE_TIME))
    with pytest.raises(InvalidInputError, match="cover"):
        cam.ground_to_image([[R, 0.0, 0.0]])


@pytest.mark.parametrize("model,coeffs", [
    ("radial", {"coefficients": [0.0, 1e-4, 1e-8]}),
    ("kaguyalism", {"x": [1e-3, 2e-3, -3e-4, 1e-5], "y": [-2e-3, 1e-3, 2e-4, -1e-5],
                    "boresight_x": 0.01, "boresight_y": -0.02}),
])
@pytest.mark.parametrize("flip", [False, True])
@pytest.mark.parametrize("detector_center_line", [2000.0, -1500.0])
def test_round_trip_with_distortion_across_the_line(model, coeffs, flip, detector_center_line) -> None:
    # Distortion that moves the along-track (x) coordinate, with the detector line 10-14 mm off
    # the principal point: the exposure condition is no longer the undistorted plane used to bracket.
    import dataclasses

    io = dataclasses.replace(nac_like_interior(), distortion_model=model, distortion_coefficients=coeffs,
                             detector_center_line=detector_center_line)
    eo = polar_orbit_eo(lat_center=40.0, flip=flip)
    cam = LineScanCamera(io, eo, line_times=(T0, NAC_LINE_TIME))
    rng = np.random.default_rng(5)
    line = rng.uniform(0, NAC_LINES, 2000)
    sample = rng.uniform(0, NAC_SAMPLES, 2000)
    l2, s2 = cam.ground_to_image(cam.image_to_ground(line, sample, height=1000.0))
    assert np.max(np.abs(l2 - line)) <= 1e-4 and np.max(np.abs(s2 - sample)) <= 1e-4


def test_table_error_bound_is_an_upper_bound_and_exact_path_agrees(monkeypatch, pixels) -> None:
    """The per-line EO table's stated error bound holds, and skipping the exact EO step changes nothing."""
    import lunarmap.camera.linescan as ls

    cam = _camera(flip=True)
    tab = cam._build_table()
    assert tab["exact_px"] < ls._TABLE_EXACT_PX          # the fast path is taken for this camera
    # oracle: the rigorous residual with the EO's own interpolation at random (non-node) lines
    rng = np.random.default_rng(5)
    line = rng.uniform(0, NAC_LINES, 5000)
    sample = rng.uniform(0, NAC_SAMPLES, 5000)
    xyz = cam.image_to_ground(line, sample)
    trial = line + rng.uniform(-0.5, 0.5, line.size)
    r_tab, s_tab, _ = cam._residual_table(tab, xyz, trial)
    r_ex, s_ex, _ = cam._residual_exact(xyz, trial)
    assert np.abs(r_tab - r_ex).max() <= tab["exact_px"]
    assert np.abs(s_tab - s_ex).max() <= tab["exact_px"]
    fast = cam.ground_to_image(xyz)
    monkeypatch.setattr(ls, "_TABLE_EXACT_PX", -1.0)    # force the exact Newton step
    exact = cam.ground_to_image(xyz)
    assert np.abs(fast[0] - exact[0]).max() <= 1e-6 and np.abs(fast[1] - exact[1]).max() <= 1e-6
    assert np.hypot(exact[0] - line, exact[1] - sample).max() <= 1e-6


def test_bracketed_fallback_gives_the_same_answer(monkeypatch) -> None:
    """Points the fast secant gives up on go through the safeguarded bracketed secant."""
    import lunarmap.camera.linescan as ls

    cam = _camera(lat=85.0)
    rng = np.random.default_rng(6)
    line = rng.uniform(0, NAC_LINES, 3000)
    sample = rng.uniform(0, NAC_SAMPLES, 3000)
    xyz = cam.image_to_ground(line, sample, height=1500.0)
    monkeypatch.setattr(ls, "_MAX_FAST", 0)              # no fast-path step converges
    l2, s2 = cam.ground_to_image(xyz)
    assert np.hypot(l2 - line, s2 - sample).max() <= 1e-6


def test_pickle_leaves_the_eo_table_behind_and_answers_the_same() -> None:
    import pickle

    cam = _camera()
    rng = np.random.default_rng(8)
    line, sample = rng.uniform(0, NAC_LINES, 500), rng.uniform(0, NAC_SAMPLES, 500)
    xyz = cam.image_to_ground(line, sample)
    before = cam.ground_to_image(xyz)
    assert cam._table is not None
    data = pickle.dumps(cam)
    assert len(data) < 2_000_000                        # the per-line table alone is > 10 MB
    back = pickle.loads(data)
    assert back._table is None and cam._table is not None   # the original keeps its cache
    after = back.ground_to_image(xyz)
    assert np.abs(after[0] - before[0]).max() <= 1e-9 and np.abs(after[1] - before[1]).max() <= 1e-9


def test_round_trip_at_the_first_lines_with_a_large_boresight_offset():
    """Kaguya TC's distortion moves the boresight by ~10 lines: with an EO covering only the image,
    the undistorted exposure plane of the first lines lies beyond the searched lines, and those
    points used to come back NaN (regression)."""
    from lunarmap.camera import InteriorOrientation, LineScanCamera, Shape

    pitch, line_time, n_lines = 0.007, 0.0065, 400
    io = InteriorOrientation(focal_length=72.45, focal2pixel_lines=(0.0, 1.0 / pitch, 0.0),
                             focal2pixel_samples=(0.0, 0.0, 1.0 / pitch), detector_center_line=0.0,
                             detector_center_sample=1604.0, starting_detector_line=1.0, n_lines=n_lines,
                             n_samples=3208, distortion_model="kaguyalism",
                             distortion_coefficients={"x": [-9.6499e-4, 9.8441e-4, 8.5773e-6, -3.7438e-6],
                                                      "y": [-1.3796e-3, 1.3502e-5, 2.7251e-6, -6.1938e-6],
                                                      "boresight_x": -0.0725, "boresight_y": 0.0214},
                             pixel_pitch=pitch, name="TC-like")
    half = 0.5 * n_lines * line_time
    eo = polar_orbit_eo(lat_center=-20.0, lon=40.0, altitude=100e3, half_span=half, step=0.01)
    cam = LineScanCamera(io, eo, Shape.moon(), line_times=(-half, line_time))
    lines = np.array([0.0, 0.5, 1.0, 2.0, 3.0, 5.0, 200.0, 399.5, 400.0])
    samples = np.linspace(0.0, 3208.0, lines.size)
    back_l, back_s = cam.ground_to_image(cam.image_to_ground(lines, samples, height=500.0))
    np.testing.assert_allclose(back_l, lines, atol=1e-6)
    np.testing.assert_allclose(back_s, samples, atol=1e-6)
