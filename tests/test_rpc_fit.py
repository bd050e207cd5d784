"""fit_rpc against the rigorous models: accuracy on independent checks, flipped images, bad input.

Oracles: the rigorous camera model itself, evaluated at points the fit never
saw -- the check grid (image_to_ground at off-node pixels and heights
between and beyond the layers) and random ground points mapped by the
rigorous ``ground_to_image`` (an iterative solver, independent of the
grid's direction).
"""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.camera import FrameCamera, LineScanCamera, Shape
from lunarmap.camera.geodesy import lonlat_height_to_xyz, xyz_to_lonlat_height
from lunarmap.errors import GeometryError, InvalidInputError, NoIntersectionError
from lunarmap.rpc import (DEFAULT_HEIGHT_RANGE, RpcFitError, RpcGridError, RpcInputError, RpcLimbError,
                          fit_rpc, fit_rpc_delayed)
from lunarmap.simulate.orbits import NAC_LINE_TIME, NAC_LINES, frame_interior, nac_like_interior, polar_orbit_eo


def nac_camera(flip: bool = False, lat: float = 0.0, roll: float = 0.0) -> LineScanCamera:
    eo = polar_orbit_eo(lat_center=lat, lon=30.0, altitude=50_000.0, half_span=12.0, step=0.05, flip=flip,
                        roll_deg=roll)
    return LineScanCamera(nac_like_interior(), eo, Shape.moon(),
                          line_times=(-NAC_LINES * NAC_LINE_TIME / 2.0, NAC_LINE_TIME))


def frame_camera(roll: float = 0.0, altitude: float = 100_000.0) -> FrameCamera:
    eo = polar_orbit_eo(lat_center=20.0, lon=-45.0, altitude=altitude, half_span=1.0, step=0.1, roll_deg=roll)
    return FrameCamera(frame_interior(), eo, Shape.moon(), time=0.0)


@pytest.fixture(scope="module", params=[False, True], ids=["nac", "nac_flipped"])
def nac_fit(request):
    cam = nac_camera(flip=request.param)
    return cam, fit_rpc(cam)


def _rigorous_vs_rfm(cam, model, n=4000, seed=0, heights=DEFAULT_HEIGHT_RANGE):
    """Random pixels -> ground (rigorous) at random heights -> rigorous and RFM ground_to_image."""
    rng = np.random.default_rng(seed)
    line = rng.uniform(0, cam.interior.n_lines, n)
    samp = rng.uniform(0, cam.interior.n_samples, n)
    h = rng.uniform(*heights, n)
    xyz = cam.image_to_ground(line, samp, height=h)
    rl, rs = cam.ground_to_image(xyz, within_image=False)
    ml, ms = model.ground_to_image(xyz, within_image=False)
    return np.hypot(ml - rl, ms - rs), (rl, rs, xyz)


def test_nac_line_scan_check_grid_meets_the_target(nac_fit):
    cam, fit = nac_fit
    c = fit.check
    assert c.rms <= 0.01 and c.max <= 0.05, fit.summary()
    # the check grid is independent: more points, heights between the layers and 10 % beyond
    layers = fit.model.attrs["fit_height_layers_m"]
    span = layers[-1] - layers[0]
    assert c.n_points > 3 * fit.fit.n_points
    assert min(c.heights) == pytest.approx(layers[0] - 0.1 * span, abs=1e-3)
    assert max(c.heights) == pytest.approx(layers[-1] + 0.1 * span, abs=1e-3)
    assert not set(np.round(c.heights, 3)) & set(np.round(layers, 3))
    assert fit.model.attrs["check_rms"] == c.rms


def test_nac_rfm_agrees_with_rigorous_ground_to_image(nac_fit):
    cam, fit = nac_fit
    err, (rl, _, _) = _rigorous_vs_rfm(cam, fit.model)
    assert np.all(np.isfinite(rl))
    assert np.sqrt(np.mean(err ** 2)) <= 0.01 and err.max() <= 0.05


def test_flipped_image_is_mirrored_in_sample():
    """Yawed by 180 degrees, lines still follow time but the detector runs the other way across track."""
    a, b = fit_rpc(nac_camera(False), check=False).model, fit_rpc(nac_camera(True), check=False).model
    lon, lat, h = np.linspace(29.96, 30.04, 5), 0.1, 0.0
    la, sa = a.lonlat_to_image(lon, lat, h)
    lb, sb = b.lonlat_to_image(lon, lat, h)
    assert np.all(np.diff(sa) * np.diff(sb) < 0)
    np.testing.assert_allclose(la, lb, atol=2.0)
    np.testing.assert_allclose(sa + sb, 5064, atol=2.0)


def test_frame_camera_meets_the_target():
    cam = frame_camera()
    fit = fit_rpc(cam)
    assert fit.check.rms <= 0.01 and fit.check.max <= 0.05, fit.summary()
    err, _ = _rigorous_vs_rfm(cam, fit.model, n=2000)
    assert err.max() <= 0.05


def test_rfm_image_to_ground_matches_rigorous(nac_fit):
    cam, fit = nac_fit
    rng = np.random.default_rng(7)
    line = rng.uniform(0, NAC_LINES, 500)
    samp = rng.uniform(0, 5064, 500)
    h = rng.uniform(-5000, 5000, 500)
    rig = cam.image_to_ground(line, samp, height=h)
    rfm = fit.model.image_to_ground(line, samp, h)
    # 0.05 px at ~0.5 m/px on the ground
    assert np.linalg.norm(rfm - rig, axis=-1).max() < 0.05


def test_jacobian_xyz_matches_rigorous_finite_differences(nac_fit):
    """The RFM's analytic partials reproduce the rigorous model's sensitivity to ground motion."""
    cam, fit = nac_fit
    xyz = cam.image_to_ground([1000.0, 26000.0, 51000.0], [100.0, 2500.0, 5000.0], height=1000.0)
    _, _, jac = fit.model.ground_partials(xyz)
    eps = 1.0  # metre
    for k in range(3):
        d = np.zeros(3)
        d[k] = eps
        fd = (np.stack(cam.ground_to_image(xyz + d, within_image=False), -1)
              - np.stack(cam.ground_to_image(xyz - d, within_image=False), -1)) / (2 * eps)
        np.testing.assert_allclose(jac[:, :, k], fd, atol=2e-4)  # pixels per metre (about 2 px/m here)


def test_denominators_stay_positive_and_regularisation_is_reported(nac_fit):
    _, fit = nac_fit
    assert fit.min_denominator >= 0.1
    m = fit.model
    # denominators on the normalised cube, heights 25 % beyond the fit range
    g = np.stack(np.meshgrid(*[np.linspace(-1, 1, 9)] * 2, np.linspace(-1.25, 1.25, 11)), -1).reshape(-1, 3)
    from lunarmap.rpc import rpc_terms
    t = rpc_terms(*g.T)
    assert (t @ m.coefficients[1]).min() > 0 and (t @ m.coefficients[3]).min() > 0
    assert m.attrs["regularization"] == fit.regularization > 0


def test_unattainable_denominator_bound_raises():
    with pytest.raises(RpcFitError, match="denominators"):
        fit_rpc(frame_camera(), check=False, min_denominator=5.0)


@pytest.mark.parametrize("height_range, match", [((1000.0, 1000.0), "positive height interval"),
                                                 ((2000.0, -2000.0), "positive height interval"),
                                                 ((np.nan, 100.0), "NaN"),
                                                 (("a", 1.0), "two numbers")])
def test_bad_height_ranges(height_range, match):
    with pytest.raises(RpcInputError, match=match) as exc:
        fit_rpc(frame_camera(), height_range, check=False)
    assert isinstance(exc.value, InvalidInputError) and isinstance(exc.value, ValueError)


def test_unknown_option_is_rejected():
    with pytest.raises(RpcInputError, match="n_layer"):
        fit_rpc(frame_camera(), n_layer=5)


def test_grid_missing_the_body():
    cam = frame_camera(roll=180.0)  # looks at the sky
    with pytest.raises(RpcGridError, match="misses the body") as exc:
        fit_rpc(cam)
    assert isinstance(exc.value, NoIntersectionError)


def test_footprint_across_the_limb():
    # from 100 km the limb is 71.1 degrees off nadir; the frame spans +-2.8 degrees
    with pytest.raises(RpcLimbError, match="crosses the limb"):
        fit_rpc(frame_camera(roll=71.0))
    # all rays hit but graze the surface: refused by the emission limit
    with pytest.raises(RpcLimbError, match="emission"):
        fit_rpc(frame_camera(roll=67.5))


def test_footprint_over_the_pole():
    with pytest.raises(RpcFitError, match="pole") as exc:
        fit_rpc(nac_camera(lat=90.0), check=False)
    assert isinstance(exc.value, GeometryError)


def test_near_pole_image_fits():
    fit = fit_rpc(nac_camera(lat=85.0), (-3000.0, 3000.0))
    assert fit.check.rms <= 0.01 and fit.check.max <= 0.05, fit.summary()


def test_dask_tiles_equal_serial():
    cam = nac_camera()
    serial = fit_rpc(cam)
    tiled = fit_rpc_delayed(cam, tile_lines=24).compute(scheduler="threads")
    np.testing.assert_array_equal(tiled.model.coefficients, serial.model.coefficients)
    np.testing.assert_array_equal(tiled.model.offsets, serial.model.offsets)
    assert tiled.check == serial.check and tiled.fit == serial.fit


def test_heights_are_above_the_shape_reference_radius():
    """A camera over a 1736.0 km sphere: the RFM's heights refer to that radius."""
    eo = polar_orbit_eo(lat_center=20.0, lon=-45.0, altitude=100_000.0, radius=1736000.0, half_span=1.0, step=0.1)
    cam = FrameCamera(frame_interior(), eo, Shape.sphere(1736000.0), time=0.0)
    m = fit_rpc(cam, (-2000.0, 2000.0), check=False).model
    assert m.radius == 1736000.0
    xyz = cam.image_to_ground(144.0, 192.0, height=500.0)
    lon, lat, h = xyz_to_lonlat_height(xyz, 1736000.0)
    assert h == pytest.approx(500.0, abs=1e-6)
    line, samp = m.lonlat_to_image(lon, lat, h)
    assert abs(line - 144.0) < 1e-3 and abs(samp - 192.0) < 1e-3
    np.testing.assert_allclose(m.image_to_ground(144.0, 192.0, 500.0), xyz, atol=1e-3)
    assert np.allclose(lonlat_height_to_xyz(lon, lat, h, 1736000.0), xyz)
