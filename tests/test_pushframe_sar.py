"""Push-frame (LRO WAC) and SAR (LRO Mini-RF) sensor models on the real kernel sets.

Oracles: ``spiceypy.sincpt`` for the WAC's image-to-ground (pinhole, framelet times and the IK's focal
plane derived here from the raw IK keywords and the label, not through lunarmap's driver), the IK's field
of view for the WAC's readout window, a closed-form zero-Doppler solution on the sphere for Mini-RF,
and central differences of the models' own rigorous ground-to-image for the analytic partials.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import spiceypy

from lunarmap.camera import PushFrameCamera, SarSensor, camera_from_isd
from lunarmap.errors import IsdFormatError, LabelError
from lunarmap.labels import load_label
from lunarmap.orientation.drivers import LroWacDriver, image_support
from lunarmap.orientation.isd import ImageSupport
from lunarmap.spice import KernelSet, kernels

from conftest import shared_set

pytestmark = pytest.mark.shared

WAC = "lro_wac_uv_wac0000a1c4"
WAC_LABEL = "wac0000a1c4.uv.even_isis3.lbl"
MINIRF = "lro_minirf_03821_16N196_S1"
MINIRF_LABEL = "03821_16N196_S1_isis3.lbl"


@pytest.fixture(scope="module")
def wac():
    folder = shared_set(WAC)
    isd = image_support(folder / WAC_LABEL, folder / f"{WAC}.tm")
    return folder, isd, camera_from_isd(isd)


@pytest.fixture(scope="module")
def minirf():
    folder = shared_set(MINIRF)
    isd = image_support(folder / MINIRF_LABEL, folder / f"{MINIRF}.tm")
    return folder, isd, camera_from_isd(isd)


def _grid(cam, n=9):
    return np.meshgrid(np.linspace(0.5, cam.n_lines - 0.5, n), np.linspace(0.5, cam.n_samples - 0.5, n),
                       indexing="ij")


# -- WAC --------------------------------------------------------------------------------------------------

def test_wac_round_trip(wac):
    """Every pixel comes back to itself unless the neighbouring framelet sees its ground point closer to
    that framelet's centre (the framelets overlap by 0.2-0.6 lines): then it goes to the other
    framelet's pixel, which sees the same ground point."""
    _, _, cam = wac
    assert isinstance(cam, PushFrameCamera) and cam.n_framelets == 260 and cam.framelet_lines == 4
    rng = np.random.default_rng(3)
    L, S = rng.uniform(0, cam.n_lines, 3000), rng.uniform(0, cam.n_samples, 3000)
    for h in (-2000.0, 0.0, 2000.0):
        g = cam.image_to_ground(L, S, h)
        line, sample = cam.ground_to_image(g, within_image=False)
        own = np.floor(line / 4) == np.floor(L / 4)
        assert np.abs(np.hypot(line - L, sample - S)[own]).max() <= 1e-4
        print(f"\nWAC h={h:+.0f} m: {(~own).mean():.1%} of the pixels lie in overlap strips")
        assert 0.02 < (~own).mean() < 0.35       # the overlap strips
        other = cam.image_to_ground(line[~own], sample[~own], h)
        assert np.linalg.norm(other - g[~own], axis=1).max() <= 1e-4      # metres: the same ground point
        assert (np.abs(np.floor(line[~own] / 4) - np.floor(L[~own] / 4)) == 1).all()


def _framelet_exact_camera(folder):
    """The WAC camera sampled by SPICE exactly at its framelet times (no ISD attitude interpolation)."""
    class AtFramelets(LroWacDriver):
        def sample_times(self):
            timing = self._timing()
            start, stop, _ = self.image_times()
            k = np.arange(self.image_lines // 4)
            return np.union1d([start, stop], start + timing.exposure_duration / 2 + k * timing.interframe_delay)

    lab = load_label(folder / WAC_LABEL)
    with kernels(KernelSet.from_metakernel(folder / f"{WAC}.tm")):
        isd = AtFramelets(lab, str(folder / WAC_LABEL)).image_support()
    return isd, camera_from_isd(isd, distortion=False)


def test_wac_image_to_ground_equals_sincpt(wac):
    folder, isd_ale, cam_ale = wac
    isd, cam = _framelet_exact_camera(folder)
    inst = load_label(folder / WAC_LABEL)["IsisCube"]["Instrument"]
    rng = np.random.default_rng(5)
    lines, samples = rng.uniform(0, 1040, 60), rng.uniform(0, 128, 60)
    truth, truth_ale = [], []
    with kernels(KernelSet.from_metakernel(folder / f"{WAC}.tm")):
        def ik(key):
            return np.asarray(spiceypy.gdpool(f"INS-85641_{key}", 0, 10), dtype=float)
        # the focal plane from ITRANSL/ITRANSS solved for (x, y), as ALE and usgscsm use them (the IK's TRANSX
        # has the opposite sign of its small cross term: 3.5e-5 of a pixel's rotation, 1.3 m on the ground)
        f, itl, its = ik("FOCAL_LENGTH")[0], ik("ITRANSL"), ik("ITRANSS")
        a = np.array([[itl[1], itl[2]], [its[1], its[2]]])
        bs, bl = ik("BORESIGHT_SAMPLE")[0], ik("BORESIGHT_LINE")[0]
        start = spiceypy.scs2e(-85, str(inst["SpacecraftClockStartCount"])) + 0.020      # ALE: + exposure / 2
        for line, sample in zip(lines, samples):
            k = int(line // 4)
            et = start + 0.020 + k * 0.578125                          # usgscsm: + exposure / 2 again
            # ISIS detector pixel (first centre at 1) of the CSM image pixel: 4x summing, the COLOR readout
            # window from detector sample 264 and the filter's first detector line 244
            det_s = sample * 4 + 264 + 0.5
            det_l = (line - 4 * k) * 4 + 244 + 0.5
            x, y = np.linalg.solve(a, [det_l - bl - itl[0], det_s - bs - its[0]])
            p = spiceypy.sincpt("ELLIPSOID", "MOON", et, "MOON_ME", "NONE", "LRO", "LRO_LROCWAC_UV",
                                np.array([x, y, f]))[0]
            truth.append(np.asarray(p) * 1000.0)
    err = np.linalg.norm(cam.image_to_ground(lines, samples) - np.array(truth), axis=1)
    # through the ISD of ALE's layout: its attitude samples every 0.144 s of the CK, interpolated
    err_ale = np.linalg.norm(camera_from_isd(isd_ale, distortion=False).image_to_ground(lines, samples)
                             - np.array(truth), axis=1)
    print(f"\nWAC vs sincpt: framelet-exact EO {err.max() * 1e3:.3g} mm, ALE-layout ISD {err_ale.max() * 1e3:.3g} mm")
    assert err.max() <= 0.01
    assert err_ale.max() <= 0.1


def test_wac_readout_window_is_inside_the_field_of_view(wac):
    """The starting detector sample 264 (the IK's COLOR_SAMPLE_OFFSET, ALE writes 0) puts the image inside
    the filter's field of view; ALE's 0 puts its middle 27 degrees off and its edge outside."""
    folder, isd, cam = wac
    with kernels(KernelSet.from_metakernel(folder / f"{WAC}.tm")):
        corners = np.asarray(spiceypy.gdpool("INS-85641_FOV_BOUNDARY_CORNERS", 0, 12)).reshape(4, 3)
    half = np.abs(corners[:, 1] / corners[:, 2]).max()               # cross-track half field, tan
    assert isd.starting_detector_sample == 264.0
    from lunarmap.camera.factory import interior_from_isd
    from lunarmap.camera.frame import image_to_focal

    for start, inside in ((264.0, True), (0.0, False)):
        io = interior_from_isd(isd)
        io = type(io)(**{**io.__dict__, "starting_detector_sample": start})
        x, y = image_to_focal(io, np.array([2.0, 2.0]), np.array([0.0, 128.0]))
        tan = np.abs(y) / abs(io.focal_length)
        assert (tan <= half * 1.02).all() == inside


def test_wac_vis_label(wac, tmp_path):
    """A VIS label (14-line framelets, no summing, filter 3 = -85631): built from the same kernels."""
    folder, _, _ = wac
    text = (folder / WAC_LABEL).read_text().replace("InstrumentId              = WAC-UV",
                                                     "InstrumentId              = WAC-VIS")
    text = text.replace("Lines   = 1040", "Lines   = 1036").replace("FilterNumber = (1, 2)", "FilterNumber = (3, 4)")
    label = tmp_path / "vis.lbl"
    label.write_text(text)
    isd = image_support(label, folder / f"{WAC}.tm")
    assert isd.push_frame.framelet_height == 14 and isd.line_summing == 1
    assert isd.starting_detector_line == 703.0 and isd.starting_detector_sample == 160.0
    cam = camera_from_isd(isd)
    assert cam.n_framelets == 74
    g = cam.image_to_ground(7.0, 64.0, 0.0)
    assert np.abs(np.array(cam.ground_to_image(g)) - [7.0, 64.0]).max() <= 1e-4
    # 1040 UV lines are not whole 14-line VIS framelets: refused by name before any geometry
    label.write_text(text.replace("Lines   = 1036", "Lines   = 1040"))
    with pytest.raises(LabelError, match="image_lines 1040 is not a whole number of framelets"):
        image_support(label, folder / f"{WAC}.tm")


def test_wac_partials_match_central_differences(wac):
    _, _, cam = wac
    rng = np.random.default_rng(2)
    k = rng.integers(0, cam.n_framelets, 30)
    L = 4 * k + rng.uniform(1.5, 2.5, 30)           # near framelet centres: no framelet changes in the steps
    S = rng.uniform(5, 123, 30)
    X = cam.image_to_ground(L, S, rng.uniform(-1000, 1000, 30))
    for degree in (0, 1):
        corr = cam.corrections(degree=degree)
        p = rng.normal(0.0, 1.0, corr.n_params) * np.where(np.array(corr.units) == "rad", 2e-5, 20.0)
        pix, jc, jx = corr.partials(p, X)
        np.testing.assert_allclose(pix, corr.project(p, X), atol=1e-9)
        for j in range(corr.n_params):
            h = 0.02 / np.max(np.abs(jc[:, :, j]))
            d = np.zeros(corr.n_params)
            d[j] = h
            fd = (corr.project(p + d, X) - corr.project(p - d, X)) / (2 * h)
            assert np.abs(jc[:, :, j] - fd).max() / np.abs(fd).max() < 1e-6, corr.names[j]
        for j in range(3):
            d = np.zeros(3)
            d[j] = 0.02 / np.max(np.abs(jx[:, :, j]))
            fd = (corr.project(p, X + d) - corr.project(p, X - d)) / (2 * d[j])
            assert np.abs(jx[:, :, j] - fd).max() / np.abs(fd).max() < 1e-6
        moved = corr.apply(p)
        np.testing.assert_allclose(np.column_stack(moved.ground_to_image(X, within_image=False)),
                                   corr.project(p, X), atol=1e-5)


# -- Mini-RF --------------------------------------------------------------------------------------------

def _lagrange_usgscsm(times, coeffs, t):
    """usgscsm's getRangeCoefficients written independently: nodes assumed at t0 + i (t_last - t0) / m."""
    from scipy.interpolate import BarycentricInterpolator

    m = len(times)
    step = (times[-1] - times[0]) / m
    s = (t - times[0]) / step
    index = int(min(max(np.floor(s), 0), m - 2))
    order = 8 if 3 <= index < m - 4 else 6 if 2 <= index < m - 3 else 4 if 1 <= index < m - 2 else 2
    nodes = np.arange(index - order // 2 + 1, index - order // 2 + 1 + order)
    return BarycentricInterpolator(nodes, coeffs[nodes])(s)


def test_minirf_image_to_ground_equals_closed_form(minirf):
    folder, isd, cam = minirf
    assert isinstance(cam, SarSensor) and cam.look_direction == "right"
    rng = np.random.default_rng(4)
    L, S = rng.uniform(0, cam.n_lines, 40), rng.uniform(0, cam.n_samples, 40)
    times = isd.sar.range_conversion_times
    coeffs = isd.sar.range_conversion_coefficients
    R = 1737400.0
    for h in (-2000.0, 0.0, 2000.0):
        ours = cam.image_to_ground(L, S, h)
        for i in range(L.size):
            et = isd.starting_ephemeris_time + (L[i] - 0.5) * isd.sar.line_exposure_duration
            c = _lagrange_usgscsm(times, coeffs, et)
            g = (S[i] - 0.5) * isd.sar.scaled_pixel_width
            rho = c[0] + c[1] * g + c[2] * g * g + c[3] * g ** 3
            P = cam.eo.position_at(et - cam.eo.epoch)
            V = cam.velocity_at(et - cam.eo.epoch)
            # the circle |G - P| = rho in the plane (G - P).V = 0, on the sphere R + h: G = P + rho (cos a n + sin a w)
            vhat = V / np.linalg.norm(V)
            n = -(P - np.dot(P, vhat) * vhat)
            n /= np.linalg.norm(n)
            w = np.cross(n, vhat)                   # right of the track, looking along the velocity from above
            cos_a = ((R + h) ** 2 - np.dot(P, P) - rho ** 2) / (2 * rho * np.dot(P, n))
            G = P + rho * (cos_a * n + np.sqrt(1 - cos_a ** 2) * w)
            assert np.linalg.norm(ours[i] - G) <= 0.01, (h, i, np.linalg.norm(ours[i] - G))


def test_minirf_round_trip_and_partials(minirf):
    _, _, cam = minirf
    L, S = _grid(cam)
    for h in (-2000.0, 0.0, 2000.0):
        g = cam.image_to_ground(L, S, h)
        line, sample = cam.ground_to_image(g)
        assert np.abs(np.hypot(line - L, sample - S)).max() <= 1e-4
    rng = np.random.default_rng(6)
    X = cam.image_to_ground(rng.uniform(50, 650, 20), rng.uniform(50, 2300, 20), rng.uniform(-900, 900, 20))
    for degree in (0, 1):
        corr = cam.corrections(degree=degree)
        p = rng.normal(0.0, 30.0, corr.n_params)
        pix, jc, jx = corr.partials(p, X)
        np.testing.assert_allclose(pix, corr.project(p, X), atol=1e-7)
        for j in range(corr.n_params):
            d = np.zeros(corr.n_params)
            d[j] = 0.05 / np.max(np.abs(jc[:, :, j]))
            fd = (corr.project(p + d, X) - corr.project(p - d, X)) / (2 * d[j])
            assert np.abs(jc[:, :, j] - fd).max() / np.abs(fd).max() < 1e-6, corr.names[j]
        for j in range(3):
            d = np.zeros(3)
            d[j] = 0.05 / np.max(np.abs(jx[:, :, j]))
            fd = (corr.project(p, X + d) - corr.project(p, X - d)) / (2 * d[j])
            assert np.abs(jx[:, :, j] - fd).max() / np.abs(fd).max() < 1e-6
    # the point mirrored to the other side of the track (same range, same Doppler) is not seen
    g = cam.image_to_ground(350.0, 1000.0, 0.0)
    t = cam.image_time(350.0)
    P, V = cam.eo.position_at(t), cam.velocity_at(t)
    vhat = V / np.linalg.norm(V)
    up = P - np.dot(P, vhat) * vhat
    side = np.cross(vhat, up / np.linalg.norm(up))
    mirror = g - 2 * np.dot(g - P, side) * side
    assert np.isnan(cam.ground_to_image(mirror)[0])
    assert not np.isnan(cam.ground_to_image(g)[0])


# -- bad input --------------------------------------------------------------------------------------------

def test_bad_push_frame_and_sar_isds_are_named(wac, minirf, tmp_path):
    _, wac_isd, _ = wac
    _, sar_isd, _ = minirf
    doc = wac_isd.to_ale_dict()
    doc["framelet_height"] = 12                                   # 12 / 4 = 3 lines: 1040 is not a multiple
    path = tmp_path / "framelets.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(IsdFormatError, match=r"framelets\.json: key 'image_lines' 1040 is not a whole number"):
        ImageSupport.read_json(path)
    doc["framelet_height"] = 18
    path.write_text(json.dumps(doc))
    with pytest.raises(IsdFormatError, match="key 'framelet_height' 18 less num_lines_overlap 0 is not a multiple"):
        ImageSupport.read_json(path)
    doc = sar_isd.to_ale_dict()
    del doc["range_conversion_coefficients"]
    path = tmp_path / "sar.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(IsdFormatError, match=r"sar\.json: key 'range_conversion_coefficients' is missing"):
        ImageSupport.read_json(path)
    doc = sar_isd.to_ale_dict()
    doc["range_conversion_coefficients"] = doc["range_conversion_coefficients"][:-1]
    path.write_text(json.dumps(doc))
    with pytest.raises(IsdFormatError, match="has 19 sets for 20 range_conversion_times"):
        ImageSupport.read_json(path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["framelets.json", "sar.json"]   # nothing else written


def test_pickled_cameras_project_the_same(wac, minirf):
    import pickle

    for _, _, cam in (wac, minirf):
        L, S = _grid(cam, 5)
        g = cam.image_to_ground(L, S, 100.0)
        copy = pickle.loads(pickle.dumps(cam))
        np.testing.assert_array_equal(copy.image_to_ground(L, S, 100.0), g)
        np.testing.assert_array_equal(np.array(copy.ground_to_image(g)), np.array(cam.ground_to_image(g)))
