"""Correction parameters of every sensor model, with distortion: analytic partials vs central finite
differences (oracle: the models' own rigorous ground_to_image, differenced), zero corrections vs the
camera, corrected cameras vs the corrected projection, and the named errors."""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.camera import FrameCamera, InteriorOrientation, LineScanCamera, Shape
from lunarmap.camera.corrections import AffineCorrectedSensor, apply_affine
from lunarmap.camera.distortion import Distortion
from lunarmap.camera.sensor import Corrections, SensorModel
from lunarmap.errors import DistortionPartialsError, InvalidInputError
from lunarmap.simulate.orbits import NAC_LINE_TIME, frame_interior, nac_like_interior, polar_orbit_eo
from lunarmap.simulate.stereo import pointed_camera

# Kaguya TC1-like coefficients (SEL_TC_V01.TI, mm-based) scaled up so that they matter here
KAGUYA = {"x": [-9.6499e-4, 9.8441e-4, 8.5773e-6, -3.7438e-6], "y": [-1.3796e-3, 1.3502e-5, 2.7251e-6, -6.1938e-6],
          "boresight_x": -0.0725, "boresight_y": 0.0214}


def _kaguya_linescan() -> LineScanCamera:
    pitch = 0.007
    io = InteriorOrientation(focal_length=72.45, focal2pixel_lines=(0.0, 1.0 / pitch, 0.0),
                             focal2pixel_samples=(0.0, 0.0, 1.0 / pitch), detector_center_line=0.5,
                             detector_center_sample=800.0, n_lines=1200, n_samples=1600,
                             distortion_model="kaguyalism", distortion_coefficients=KAGUYA, pixel_pitch=pitch,
                             name="TC-like")
    line_time = 0.0065
    eo = polar_orbit_eo(lat_center=10.0, lon=40.0, altitude=100e3, half_span=6.0, step=0.05, roll_deg=5.0)
    return LineScanCamera(io, eo, Shape.moon(), line_times=(-0.5 * io.n_lines * line_time, line_time))


def _cameras():
    return {
        "frame-radial": pointed_camera("frame", 30.0, 10.0, -8.0, interior=frame_interior()),
        "nac-lrolrocnac": pointed_camera("linescan", 30.0, 10.0, 12.0,
                                         interior=nac_like_interior(n_lines=2000, n_samples=1000)),
        "tc-kaguyalism": _kaguya_linescan(),
    }


CAMERAS = _cameras()


def _points(cam, n=40, seed=0):
    rng = np.random.default_rng(seed)
    line = rng.uniform(0, cam.n_lines, n)
    sample = rng.uniform(0, cam.n_samples, n)
    return line, sample, cam.image_to_ground(line, sample, rng.uniform(-800, 800, n))


def _rel_err(analytic, fd):
    return np.max(np.abs(analytic - fd)) / np.max(np.abs(fd))


CASES = [("frame-radial", 0), ("nac-lrolrocnac", 0), ("nac-lrolrocnac", 1), ("nac-lrolrocnac", 2),
         ("tc-kaguyalism", 1)]


@pytest.mark.parametrize("name, degree", CASES)
def test_partials_match_central_differences(name, degree):
    cam = CAMERAS[name]
    assert isinstance(cam, SensorModel)
    corr = cam.corrections(degree=degree)
    assert isinstance(corr, Corrections) and corr.n_params == len(corr.names) == len(corr.units)
    _, _, X = _points(cam)
    rng = np.random.default_rng(1)
    scale = np.array([1.0 if u == "rad" else 0.0 for u in corr.units]) * 3e-5 + \
        np.array([1.0 if u == "m" else 0.0 for u in corr.units]) * 5.0
    p = rng.normal(0.0, 1.0, corr.n_params) * scale
    pix, jc, jx = corr.partials(p, X)
    np.testing.assert_allclose(pix, corr.project(p, X), atol=1e-9)
    # steps that move the image by at most 0.05 px: far above the projection's ~1e-9 px round-off
    # (relative noise ~2e-8), small enough for the central difference's own O(step^2) error
    for k in range(corr.n_params):
        h = 0.05 / np.max(np.abs(jc[:, :, k]))
        d = np.zeros(corr.n_params)
        d[k] = h
        fd = (corr.project(p + d, X) - corr.project(p - d, X)) / (2 * h)
        assert _rel_err(jc[:, :, k], fd) < 1e-6, (name, degree, corr.names[k], _rel_err(jc[:, :, k], fd))
    for k in range(3):
        d = np.zeros(3)
        d[k] = 0.05 / np.max(np.abs(jx[:, :, k]))
        fd = (corr.project(p, X + d) - corr.project(p, X - d)) / (2 * d[k])
        assert _rel_err(jx[:, :, k], fd) < 1e-6, (name, degree, "xyz", k, _rel_err(jx[:, :, k], fd))


@pytest.mark.parametrize("name", sorted(CAMERAS))
def test_zero_corrections_and_ground_partials_equal_the_camera(name):
    cam = CAMERAS[name]
    line, sample, X = _points(cam, seed=2)
    corr = cam.corrections()
    np.testing.assert_allclose(corr.project(np.zeros(corr.n_params), X), np.column_stack([line, sample]), atol=1e-6)
    li, sa, jac = cam.ground_partials(X)
    np.testing.assert_allclose(np.column_stack([li, sa]), np.column_stack([line, sample]), atol=1e-6)
    assert jac.shape == (X.shape[0], 2, 3)
    d = np.array([0.0, 0.0, 2.0])
    fd = (np.stack(cam.ground_to_image(X + d, within_image=False), -1)
          - np.stack(cam.ground_to_image(X - d, within_image=False), -1)) / 4.0
    assert _rel_err(jac[:, :, 2], fd) < 1e-6


@pytest.mark.parametrize("name, degree", CASES)
def test_applied_corrections_give_a_camera_that_projects_the_same(name, degree):
    cam = CAMERAS[name]
    corr = cam.corrections(degree=degree)
    _, _, X = _points(cam, seed=3)
    rng = np.random.default_rng(4)
    p = rng.normal(0.0, 1.0, corr.n_params) * np.where(np.array(corr.units) == "rad", 3e-5, 5.0)
    new = corr.apply(p)
    assert type(new) is type(cam) and new is not cam and new.eo is not cam.eo
    li, sa = new.ground_to_image(X, within_image=False)
    np.testing.assert_allclose(np.column_stack([li, sa]), corr.project(p, X), atol=1e-6)
    # the original is untouched
    np.testing.assert_allclose(corr.project(np.zeros(corr.n_params), X),
                               np.column_stack(cam.ground_to_image(X, within_image=False)), atol=1e-6)


def test_frame_corrections_closed_form():
    """A position correction c equals moving the ground point by -c; a rotation about the boresight
    turns focal-plane vectors about the principal point (no distortion: exact)."""
    cam = pointed_camera("frame", 30.0, 10.0, 0.0, interior=frame_interior(odk=None))
    corr = cam.corrections()
    _, _, X = _points(cam, seed=5)
    c = np.array([3.0, -2.0, 1.5])
    np.testing.assert_allclose(corr.project(np.r_[0, 0, 0, c], X), corr.project(np.zeros(6), X - c), atol=1e-9)
    a = 1e-3
    p = corr.project(np.r_[0, 0, a, 0, 0, 0], X)
    q = corr.project(np.zeros(6), X)
    io = cam.interior
    # interior: samples along focal x, lines along focal y; v' = Rz(a) v turns (x, y) by +a
    xs, ys = q[:, 1] - io.detector_center_sample, q[:, 0] - io.detector_center_line
    want_s = np.cos(a) * xs - np.sin(a) * ys + io.detector_center_sample
    want_l = np.sin(a) * xs + np.cos(a) * ys + io.detector_center_line
    np.testing.assert_allclose(p, np.column_stack([want_l, want_s]), atol=1e-9)


def test_affine_corrections_eq13_and_wrapper():
    """RFM-style affine corrections on any sensor: Eq. 13 literally, its partials, and the corrected sensor."""
    cam = CAMERAS["nac-lrolrocnac"]
    from lunarmap.camera.corrections import AffineCorrections

    corr = AffineCorrections(cam, origin=(0.0, 0.0))
    _, _, X = _points(cam, seed=6)
    r, c = cam.ground_to_image(X, within_image=False)
    p = np.array([1.5, 2e-4, -3e-4, -0.7, 1e-4, 5e-4])
    want = np.column_stack([r + 1.5 + 2e-4 * c - 3e-4 * r, c - 0.7 + 1e-4 * c + 5e-4 * r])
    np.testing.assert_allclose(corr.project(p, X), want, atol=1e-9)
    np.testing.assert_allclose(apply_affine(p, np.column_stack([r, c]), np.zeros(2)), want, atol=1e-12)
    pix, jc, jx = corr.partials(p, X)
    for k in range(6):
        h = 1e-3 if k in (0, 3) else 1e-7
        d = np.zeros(6)
        d[k] = h
        fd = (corr.project(p + d, X) - corr.project(p - d, X)) / (2 * h)
        assert _rel_err(jc[:, :, k], fd) < 1e-6
    new = corr.apply(p)
    assert isinstance(new, AffineCorrectedSensor) and isinstance(new, SensorModel)
    li, sa = new.ground_to_image(X, within_image=False)
    np.testing.assert_allclose(np.column_stack([li, sa]), want, atol=1e-9)
    back = new.image_to_ground(li, sa, height=np.linalg.norm(X, axis=1) - cam.reference_radius)
    np.testing.assert_allclose(back, X, atol=1e-4)


class _NoPartials(Distortion):
    name = "custom"

    def undistort(self, x, y):
        return np.asarray(x, float), np.asarray(y, float)

    def distort(self, x, y):
        return np.asarray(x, float), np.asarray(y, float)


def test_distortion_without_partials_is_refused_by_name(monkeypatch):
    cam = pointed_camera("frame", 30.0, 10.0, 0.0, interior=frame_interior())
    cam.distortion = _NoPartials()
    with pytest.raises(DistortionPartialsError, match="_NoPartials.*no analytic partial"):
        cam.corrections()
    from lunarmap.adjust import SensorImageModel

    with pytest.raises(DistortionPartialsError, match="image 0: distortion model _NoPartials"):
        SensorImageModel([cam])


def test_bad_correction_inputs():
    cam = CAMERAS["nac-lrolrocnac"]
    with pytest.raises(InvalidInputError, match="degree must be 0, 1 or 2"):
        cam.corrections(degree=3)
    corr = cam.corrections(degree=1)
    _, _, X = _points(cam, n=3)
    with pytest.raises(InvalidInputError, match="takes 12 correction parameters, got 6"):
        corr.project(np.zeros(6), X)
    with pytest.raises(InvalidInputError, match="NaN"):
        corr.project(np.full(12, np.nan), X)
    with pytest.raises(InvalidInputError, match="ground point"):
        corr.project(np.zeros(12), np.full((2, 3), np.nan))
    frame = CAMERAS["frame-radial"]
    assert isinstance(frame, FrameCamera)
    # a frame camera has no time: the degree asked for by a mixed block is ignored
    assert frame.corrections(degree=2).n_params == 6
    assert NAC_LINE_TIME > 0


def test_linescan_point_without_a_time_projects_to_nan_not_an_error():
    """A ground point for which the line-scan time search finds no finite time (the Newton step divides by a zero
    slope) projects to NaN in its row only -- as a frame camera's point behind it does -- so that quality
    control can set it aside; it used to stop the whole block with ``InvalidInputError`` from the orientation."""
    cam = CAMERAS["nac-lrolrocnac"]
    corr = cam.corrections(1)
    X = _points(cam, n=5)[2]
    good = corr.project(np.zeros(corr.n_params), X)
    t = corr._solve_time(np.zeros(corr.n_params), X)
    t[2] = np.nan
    pix = corr._geometry(np.zeros(corr.n_params), X, t, True)
    assert np.all(np.isnan(pix[0][2])) and np.all(np.isnan(pix[1][2]))
    keep = np.arange(5) != 2
    line = cam.line_times.line(t)
    np.testing.assert_allclose(np.column_stack([line, pix[0][:, 1]])[keep], good[keep], atol=1e-9)


@pytest.mark.parametrize("name", ["nac-lrolrocnac", "tc-kaguyalism"])
def test_linescan_warm_time_search_ends_where_a_cold_one_does(name, monkeypatch):
    """The time search starts from the previous call's times for points that moved < 1 km (an adjustment's
    iterations), and cold for the rest; oracle: the corrected camera's own ground_to_image and a fresh
    corrections object (cold for every point), on a sequence of moves as an adjustment makes them."""
    cam = CAMERAS[name]
    corr = cam.corrections(degree=1)
    _, _, X = _points(cam, n=60, seed=5)
    rng = np.random.default_rng(6)
    scale = np.where(np.array(corr.units) == "rad", 3e-5, 5.0)
    cold_points: list[int] = []
    start = type(corr)._start_times

    def counting(self, pts):
        cold_points.append(pts.shape[0])
        return start(self, pts)

    monkeypatch.setattr(type(corr), "_start_times", counting)
    far = np.zeros(len(X), dtype=bool)
    far[::4] = True                                  # a quarter of the points jump 5 km: these start cold
    moves = [np.zeros_like(X), rng.normal(0.0, 10.0, X.shape),
             np.where(far[:, None], 5000.0 / np.sqrt(3.0), rng.normal(0.0, 3.0, X.shape))]
    expected_cold = [len(X), 0, int(far.sum())]
    Y = X
    for move, n_cold in zip(moves, expected_cold):
        Y = Y + move
        p = rng.normal(0.0, 1.0, corr.n_params) * scale
        cold_points.clear()
        got = corr.project(p, Y)
        assert sum(cold_points) == n_cold
        fresh = cam.corrections(degree=1).project(p, Y)
        np.testing.assert_allclose(got, fresh, atol=1e-7)
        # the camera's own search sees only its orientation's time span: compare where it finds a time
        oracle = np.column_stack(corr.apply(p).ground_to_image(Y, within_image=False))
        seen = np.isfinite(oracle[:, 0])
        assert seen.sum() >= 0.7 * len(Y)
        np.testing.assert_allclose(got[seen], oracle[seen], atol=1e-6)
