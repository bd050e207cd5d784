"""The synthetic imaging block: kernels vs the truth model, navigation errors, distortion, rendering, matching.

Oracles: the numpy model the kernels were written from (read back through
SPICE and the generic driver), the manifest's own numbers evaluated here with
the documented formula, closed-form distortion values from the IK
coefficients, the truth cameras' DTM intersection (true conjugates), and
SPICE itself (pxform, spkez).
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import spiceypy
import xarray as xr
from scipy.ndimage import map_coordinates
from scipy.spatial.transform import Rotation

import lunarmap.synthetic as sim
from lunarmap.camera.factory import camera_from_isd
from lunarmap.errors import BlockMissionError, InvalidInputError, LunarmapError
from lunarmap.labels import load_label
from lunarmap.matching import DetectParams, MatchParams, TiePointParams, find_tiepoints
from lunarmap.orientation.drivers import image_support
from lunarmap.simulate import (block_cameras, block_check_points, block_scene, matching_errors, render_block,
                               true_conjugates)
from lunarmap.spice import SPICE_LOCK, KernelSet, kernels
from lunarmap.synthetic.block_writing import NAVIGATION_KERNELS, SHARED_KERNELS, TRUTH_KERNELS

MATCHED = ("orbit1_nac", "orbit2_tc", "orbit3_frame_a")  # one image per orbit and camera


def rotation_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (rad) of the rotations a b^T, accurate for tiny angles."""
    return np.linalg.norm(Rotation.from_matrix(a @ np.swapaxes(b, -1, -2)).as_rotvec(), axis=-1)


@pytest.fixture(scope="module")
def block(tmp_path_factory) -> sim.BlockMission:
    return sim.write_block_mission(tmp_path_factory.mktemp("block"), seed=0)


@pytest.fixture(scope="module")
def isds(block):
    """TRUTH and NAVIGATION image support of every image."""
    return {kind: {n: image_support(block.label(n), block.metakernel(kind)) for n in block.image_names}
            for kind in ("truth", "navigation")}


@pytest.fixture(scope="module")
def cams(isds):
    return {kind: {n: camera_from_isd(i) for n, i in d.items()} for kind, d in isds.items()}


@pytest.fixture(scope="module")
def scene(block):
    return block_scene(block)


@pytest.fixture(scope="module")
def rendered(block):
    """Three images from three orbits and cameras, rendered at 1 ray per pixel (the full block uses 2)."""
    return render_block(block, names=MATCHED, supersample=1)


# -- files, manifest, layout ---------------------------------------------------------------

def test_files_manifest_and_layout(block):
    folder, man = block.folder, block.manifest
    names = sorted(p.name for p in folder.iterdir() if p.suffix != ".nc")  # rendered images may be there
    expected = sorted([*SHARED_KERNELS, *TRUTH_KERNELS, *NAVIGATION_KERNELS, "truth.tm", "navigation.tm",
                       "block_mission.json", *(f"{n}.lbl" for n in block.image_names)])
    assert names == expected  # no staging folder left behind
    assert json.loads((folder / "block_mission.json").read_text()) == man
    assert len(block.image_names) == 12 and len(man["orbits"]) == 3
    for kind, own in (("truth", TRUTH_KERNELS), ("navigation", NAVIGATION_KERNELS)):
        kset = KernelSet.from_metakernel(block.metakernel(kind))
        assert [Path(p).name for p in kset.paths] == [*SHARED_KERNELS, *own]
    for name, im in man["images"].items():
        assert im["samples"] <= 1000 and im["lines"] <= 1000
        assert 0.9 < im["geometry"]["gsd_m"] < 1.1
        assert 45.0 < im["geometry"]["incidence_deg"] < 65.0  # sunlit, moderate incidence
        cube = load_label(folder / im["label"])["IsisCube"]
        assert cube["Kernels"]["NaifFrameCode"] == im["instrument_id"]
        assert (cube["Core"]["Dimensions"]["Samples"], cube["Core"]["Dimensions"]["Lines"]) == \
            (im["samples"], im["lines"])
    # per orbit: the TC a few seconds before the NAC (pitched forward), the frames after (pitched aft)
    for k in (1, 2, 3):
        dt = {kind: man["images"][f"orbit{k}_{kind}"]["seconds_from_orbit_reference"]
              for kind in ("nac", "tc", "frame_a", "frame_b")}
        assert abs(dt["nac"]) < 1e-4 and -5.0 < dt["tc"] < -2.0 and 2.0 < dt["frame_a"] < dt["frame_b"] < 5.0
    rolls = [o["roll_deg"] for o in man["orbits"]]
    assert np.all(np.abs(np.diff(rolls)) > 15.0) and min(abs(r) for r in rolls) > 1.0  # rolled on every orbit


def test_every_image_centre_sees_the_site_and_convergence(block, cams):
    """Independent geometry from the truth cameras: image centres on the site, cross-orbit convergence 15-45 deg."""
    site = block.model.site_xyz()
    views = {}
    for n, cam in cams["truth"].items():
        im = block.manifest["images"][n]
        g = cam.image_to_ground(im["lines"] / 2, im["samples"] / 2, height=0.0)
        # measured: NAC 0.01 m; TC 4-10 m (its boresight offsets); frames 88-97 m (0.2 frame along
        # track either side, and the cameras' misalignments of a few hundredths of a degree)
        tol = {"nac": 0.1, "tc": 15.0}.get(im["kind"], 120.0)
        assert np.linalg.norm(g - site) < tol, n
        views[n] = cam.sensor_position(im["lines"] / 2, im["samples"] / 2) - site
        views[n] /= np.linalg.norm(views[n])
    conv = {}
    for a in views:
        for b in views:
            if a < b:
                conv[a, b] = np.degrees(np.arccos(views[a] @ views[b]))
                assert conv[a, b] == pytest.approx(block.manifest["convergence_deg"].get(
                    f"{a}|{b}", block.manifest["convergence_deg"].get(f"{b}|{a}")), abs=0.01)
    cross = [v for (a, b), v in conv.items() if a[:6] != b[:6]]
    same = [v for (a, b), v in conv.items() if a[:6] == b[:6]]
    assert 15.0 < min(cross) and max(cross) < 45.0 and max(same) < 15.0


def test_pushbroom_pixels_are_square_and_about_a_metre(block, cams):
    for n in ("orbit1_nac", "orbit2_tc", "orbit3_nac"):
        cam = cams["truth"][n]
        g = cam.image_to_ground([256.0, 257.0, 256.0], [256.0, 256.0, 257.0], height=0.0)
        along, across = np.linalg.norm(g[1] - g[0]), np.linalg.norm(g[2] - g[0])
        assert along == pytest.approx(across, rel=0.02) and 0.9 < across < 1.15


# -- kernels vs the model ---------------------------------------------------------------------

def test_truth_kernels_reproduce_the_model(block, isds):
    """Through image_support: positions to < 1 mm, sensor attitude to < 1 nrad (measured 7e-4 mm, 1e-10 rad)."""
    m = block.model
    worst_p = worst_a = 0.0
    for n, isd in isds["truth"].items():
        eo = isd.exterior_orientation()
        et = isd.times
        worst_p = max(worst_p, np.abs(eo.positions - m.position_body_fixed(et)).max())
        cam_id = block.manifest["images"][n]["instrument_id"]
        worst_a = max(worst_a, rotation_angle(eo.rotation_at(eo.times), m.sensor_to_body(cam_id, et)).max())
    assert worst_p < 1e-3 and worst_a < 1e-9


def test_truth_kernels_between_records(block):
    """SPICE directly, off the SPK and CK record epochs (interpolation's worst case)."""
    m = block.model
    rng = np.random.default_rng(3)
    with kernels(KernelSet.from_metakernel(block.truth_metakernel)):
        for p in m.passes:
            ts = rng.uniform(p.start_et + 1, p.end_et - 1, 20) + 0.123
            got = np.array([spiceypy.spkez(-990, t, "J2000", "NONE", 301)[0] for t in ts])
            assert np.abs(got[:, :3] - m.state(ts)[:, :3]).max() < 1e-6  # km
            c = np.array([spiceypy.pxform("J2000", "SIM_SC_BUS", t) for t in ts])
            assert rotation_angle(c, m.bus_matrix(ts)).max() < 1e-9
            # the bus is rolled by the pass's roll about its +x axis relative to nadir pointing
            nadir = np.array([m.nadir.matrix(t) for t in ts])
            roll = Rotation.from_matrix(c @ np.swapaxes(nadir, 1, 2)).as_rotvec()
            np.testing.assert_allclose(roll[:, 0], -np.radians(p.roll_deg), atol=1e-9)
            assert np.abs(roll[:, 1:]).max() < 1e-9


def _manifest_errors(man: dict, et: float) -> tuple[np.ndarray, np.ndarray]:
    """The documented navigation error model evaluated from the manifest's numbers (position m, bus rotation rad)."""
    nav = man["navigation_errors"]
    orb = next(o for o in nav["orbits"] if o["window_et"][0] <= et <= o["window_et"][1])
    dt = et - orb["reference_et"]

    def noise(b: dict) -> np.ndarray:
        a, per, ph = (np.array(b[k]) for k in ("amplitude", "period_s", "phase_rad"))
        return np.sum(a * np.sin(2 * np.pi * (et - b["epoch_et"]) / per + ph), axis=1)

    dp = np.array(orb["position_offset_m"]) + dt * np.array(orb["position_drift_m_per_s"]) + \
        noise(nav["position_noise"])
    th = np.array(orb["attitude_offset_rad"]) + dt * np.array(orb["attitude_drift_rad_per_s"]) + \
        noise(nav["attitude_noise"])
    return dp, th


def test_navigation_kernels_differ_by_the_documented_errors(block, isds):
    """NAVIGATION - TRUTH at every ISD epoch equals the manifest's offset + drift + random part.

    Position to < 1 mm (measured ~2e-6 mm); attitude: R_nav R_true^T = Rv(B C_true^T th) to < 1 nrad
    (measured ~4e-10 rad), with B C_true^T from SPICE (pxform bus -> IAU_MOON of the truth kernels).
    """
    man = block.manifest
    truth_set = KernelSet.from_metakernel(block.truth_metakernel)
    worst_p = worst_a = 0.0
    for n in block.image_names:
        t_isd, n_isd = isds["truth"][n], isds["navigation"][n]
        et = t_isd.times[:: max(1, t_isd.times.size // 7)]
        idx = np.searchsorted(t_isd.times, et)
        eo_t, eo_n = t_isd.exterior_orientation(), n_isd.exterior_orientation()
        with kernels(truth_set):
            bus_to_bf = np.array([spiceypy.pxform("SIM_SC_BUS", "IAU_MOON", t) for t in et])
        for k, (i, t) in enumerate(zip(idx, et)):
            dp, th = _manifest_errors(man, t)
            worst_p = max(worst_p, np.abs(eo_n.positions[i] - eo_t.positions[i] - dp).max())
            w = bus_to_bf[k] @ th
            r_t, r_n = eo_t.rotation_at(eo_t.times[i]), eo_n.rotation_at(eo_n.times[i])
            worst_a = max(worst_a, rotation_angle(r_n @ r_t.T, Rotation.from_rotvec(w).as_matrix()))
        # the per-image record is the same model at the centre time
        rec = man["images"][n]["navigation_error"]
        dp, th = _manifest_errors(man, rec["et"])
        np.testing.assert_allclose(rec["position_m"], dp, rtol=0, atol=1e-9)
        np.testing.assert_allclose(rec["attitude_bus_rad"], th, rtol=0, atol=1e-15)
    assert worst_p < 1e-3 and worst_a < 1e-9


def test_navigation_error_magnitudes(block, cams):
    """Offsets and drifts within the documented ranges; images displaced by tens of metres on the ground."""
    nav = block.manifest["navigation_errors"]
    mag = nav["magnitudes"]
    for o in nav["orbits"]:
        for key in ("position_offset_m", "position_drift_m_per_s", "attitude_offset_rad", "attitude_drift_rad_per_s"):
            lo, hi = mag[key]
            assert lo <= np.linalg.norm(o[key]) <= hi, key
    for kind in ("position_noise", "attitude_noise"):
        a = np.array(nav[kind]["amplitude"])
        rms = np.sqrt(np.sum(a ** 2 / 2, axis=1))
        np.testing.assert_allclose(rms, mag[kind + ("_m" if kind.startswith("position") else "_rad")], rtol=1e-12)
    shifts = []
    for n in block.image_names:
        im = block.manifest["images"][n]
        lc, sc = im["lines"] / 2, im["samples"] / 2
        g_t = cams["truth"][n].image_to_ground(lc, sc, height=0.0)
        g_n = cams["navigation"][n].image_to_ground(lc, sc, height=0.0)
        shifts.append(np.linalg.norm(g_n - g_t))
    assert 10.0 < np.median(shifts) and max(shifts) < 80.0
    # images of one orbit do not share exactly the same error (drift and random part)
    e = [np.array(block.manifest["images"][f"orbit1_{k}"]["navigation_error"]["position_m"]) for k in ("tc", "nac")]
    assert np.linalg.norm(e[0] - e[1]) > 0.1


# -- cameras and distortion -------------------------------------------------------------------

def test_generic_driver_reads_every_block_camera(block, isds):
    spec = {c.name: c for c in sim.BLOCK_CAMERAS}
    for n, isd in isds["truth"].items():
        cam = spec[block.manifest["images"][n]["camera"]]
        assert isd.model == ("linescan" if cam.camera_type == "LINESCAN" else "frame")
        assert isd.focal_length == cam.focal_length_mm
        (model, block_), = isd.optical_distortion.items()
        assert model == cam.distortion_model
    tc = isds["truth"]["orbit1_tc"].optical_distortion["kaguyalism"]
    with kernels(KernelSet.from_metakernel(block.truth_metakernel)):
        np.testing.assert_array_equal(tc["x"], spiceypy.gdpool("INS-990400_DISTORTION_COEF_X", 0, 4))
        np.testing.assert_array_equal(tc["y"], spiceypy.gdpool("INS-990400_DISTORTION_COEF_Y", 0, 4))
        bore = spiceypy.gdpool("INS-990400_BORESIGHT", 0, 3)
    assert tc["boresight_x"] == pytest.approx(bore[0] * 345.0 / bore[2], rel=1e-12)
    assert tc["boresight_x"] == pytest.approx(0.37 * -0.0725, rel=1e-9)  # TC1's offset, scaled


def _shift(isd, line, sample):
    """Pixel shift (line, sample) from the distorted camera's pixel to the undistorted camera's, same ground point."""
    cd, cu = camera_from_isd(isd), camera_from_isd(isd, distortion=False)
    g = cd.image_to_ground(line, sample, height=0.0)
    lu, su = cu.ground_to_image(g, within_image=False)
    return lu - np.asarray(line), su - np.asarray(sample)


def test_distortion_present_and_about_one_pixel(block, isds):
    """With vs without distortion at the edges, against closed forms of the IK coefficients."""
    with kernels(KernelSet.from_metakernel(block.truth_metakernel)):
        k_nac = spiceypy.gdpool("INS-990300_OD_K", 0, 1)[0]
        k_fr = spiceypy.gdpool("INS-990500_OD_K", 0, 3)[1]
        b = spiceypy.gdpool("INS-990400_DISTORTION_COEF_Y", 0, 4)
        by = spiceypy.gdpool("INS-990400_BORESIGHT", 0, 3)[1] * 345.0
    p = 0.007
    # NAC (lrolrocnac): samples along +y; uy = y / (1 + k1 y^2)
    s = np.array([0.5, 256.0, 511.5])
    dl, ds = _shift(isds["truth"]["orbit2_nac"], np.full(3, 256.0), s)
    y = (s - 256.0) * p
    np.testing.assert_allclose(ds, (y / (1 + k_nac * y ** 2) - y) / p, atol=2e-3)
    assert 0.9 < abs(ds[0]) < 1.1 and abs(ds[1]) < 1e-3 and np.abs(dl).max() < 0.01
    # frame (radial OD_K): u = d (1 - k1 r^2) at the corners
    q = 0.023
    line, sample = np.array([0.5, 192.0, 383.5]), np.array([0.5, 192.0, 0.5])
    dl, ds = _shift(isds["truth"]["orbit2_frame_a"], line, sample)
    x, yy = (sample - 192.0) * q, (line - 192.0) * q
    scale = -k_fr * (x ** 2 + yy ** 2)
    np.testing.assert_allclose(ds, x * scale / q, atol=2e-3)
    np.testing.assert_allclose(dl, yy * scale / q, atol=2e-3)
    assert 0.9 < np.hypot(dl[0], ds[0]) < 1.1 and np.hypot(dl[1], ds[1]) < 1e-3
    # TC (kaguyalism): samples along -y; across-track shift -(poly_b(r) + by) / p, ~1 px edge-to-centre
    dl, ds = _shift(isds["truth"]["orbit2_tc"], np.full(3, 256.0), s)
    r = np.abs(s - 256.0) * p
    poly = b[0] + b[1] * r + b[2] * r ** 2 + b[3] * r ** 3
    # 0.01 px: the x terms move the point ~3.7 lines along track, where the ground maps to slightly
    # different samples (measured differences up to 0.0055 px)
    np.testing.assert_allclose(ds, -(poly + by) / p, atol=1e-2)
    assert 0.8 < ds[0] - ds[1] < 1.2 and 0.8 < ds[2] - ds[1] < 1.2
    assert 3.0 < np.abs(dl).min() and np.abs(dl).max() < 5.0  # TC1's along-track offsets, scaled


def test_linescan_ground_to_image_over_the_whole_image(cams):
    """Regression: mixed in/out-of-table secant steps crashed LineScanCamera.ground_to_image (TC near line 0)."""
    for n in ("orbit2_tc", "orbit2_nac"):
        cam = cams["truth"][n]
        line = np.repeat(np.arange(-1.0, 513.5, 0.5), 5)
        sample = np.tile(np.linspace(1.0, 511.0, 5), line.size // 5)
        g = cam.image_to_ground(line, sample, height=0.0)
        lb, sb = cam.ground_to_image(g, within_image=False)
        inner = (line >= 4.0) & (line <= 508.0)
        assert np.all(np.isfinite(lb[inner]))
        assert np.abs(lb[inner] - line[inner]).max() < 1e-6 and np.abs(sb[inner] - sample[inner]).max() < 1e-6


# -- rendering ----------------------------------------------------------------------------------

def test_every_image_sees_the_site(block):
    out = render_block(block, supersample=1, crop=48, write=False)
    assert set(out.images) == set(block.image_names) and out.seconds > 0
    for n, img in out.images.items():
        v = img.values
        assert v.shape == (48, 48) and np.all(np.isfinite(v)), n
        assert 60.0 < v.mean() < 200.0 and v.std() > 5.0
        im = block.manifest["images"][n]
        assert img["line"].values[0] == im["lines"] // 2 - 24 + 0.5  # crops keep full-image coordinates


def test_rendered_files_and_dtm(block, rendered, scene):
    for n in MATCHED:
        on_disk = xr.open_dataarray(rendered.paths[n]).load()
        np.testing.assert_array_equal(on_disk.values, rendered.images[n].values)
        assert on_disk.attrs["image"] == n and on_disk.attrs["kernels"] == "truth.tm"
        assert np.all(np.isfinite(on_disk.values))
    dtm = xr.open_dataarray(rendered.paths["dtm"]).load()
    np.testing.assert_array_equal(dtm.values, scene[0].values)
    assert dtm.attrs["units"] == "m" and 5.0 < float(dtm.max() - dtm.min()) < 100.0
    assert not list(block.folder.glob(".*.tmp"))


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    return float(np.sum(a * b) / np.sqrt(np.sum(a * a) * np.sum(b * b)))


@pytest.mark.parametrize("pair", [("orbit1_nac", "orbit3_frame_a"), ("orbit2_tc", "orbit1_nac")])
def test_images_agree_at_true_conjugates(block, rendered, cams, scene, pair):
    """Windows at true conjugates (truth cameras through the DTM) correlate; 3 px off they do not."""
    a, b = pair
    ca, cb = cams["truth"][a], cams["truth"][b]
    ia, ib = rendered.images[a].values, rendered.images[b].values
    i, j = np.meshgrid(np.arange(40, ia.shape[0] - 40, 37), np.arange(40, ia.shape[1] - 40, 37), indexing="ij")
    l1, s1 = i.ravel() + 0.5, j.ravel() + 0.5
    l2, s2 = true_conjugates(ca, cb, l1, s1, scene[0])
    dl_l, ds_l = true_conjugates(ca, cb, l1 + 1.0, s1, scene[0])
    dl_s, ds_s = true_conjugates(ca, cb, l1, s1 + 1.0, scene[0])
    u = np.arange(-7, 8)
    ul, us = np.meshgrid(u, u, indexing="ij")
    good, wrong = [], []
    for k in range(l1.size):
        if not (np.isfinite(l2[k]) and 10 < l2[k] < ib.shape[0] - 10 and 10 < s2[k] < ib.shape[1] - 10):
            continue
        w1 = ia[i.ravel()[k] - 7:i.ravel()[k] + 8, j.ravel()[k] - 7:j.ravel()[k] + 8]
        # image-2 window through the local affine map of the true conjugates
        lw = l2[k] + (dl_l[k] - l2[k]) * ul + (dl_s[k] - l2[k]) * us
        sw = s2[k] + (ds_l[k] - s2[k]) * ul + (ds_s[k] - s2[k]) * us
        good.append(_ncc(w1, map_coordinates(ib, [lw - 0.5, sw - 0.5], order=1)))
        wrong.append(_ncc(w1, map_coordinates(ib, [lw + 2.5, sw + 2.5], order=1)))
    assert len(good) >= 20
    # measured: median 0.957 / 0.961, minimum 0.93 / 0.92; 3 px off: median 0.12 / 0.14
    assert np.median(good) > 0.92 and min(good) > 0.8 and np.median(good) - np.median(wrong) > 0.6


# -- matching with the navigation cameras ---------------------------------------------------------

def test_matching_with_navigation_cameras(block, rendered, cams, scene):
    """find_tiepoints predicting with the NAVIGATION cameras: tie points agree with the truth.

    The navigation cameras predict the cross-orbit conjugates tens of pixels off (hence search=128);
    matched positions agree with the truth (image-1 point through the truth camera onto the truth DTM,
    back into image 2 with the truth camera) to a few tenths of a pixel.
    """
    images = {n: rendered.images[n] for n in MATCHED}
    nav = {n: cams["navigation"][n] for n in MATCHED}
    tru = {n: cams["truth"][n] for n in MATCHED}
    # the navigation prediction error the matcher has to absorb
    for a, b in (("orbit1_nac", "orbit2_tc"), ("orbit1_nac", "orbit3_frame_a"), ("orbit2_tc", "orbit3_frame_a")):
        g = tru[a].image_to_ground(256.0, 256.0, dtm=scene[0])
        lt, st = tru[b].ground_to_image(g)
        ln, sn = nav[b].ground_to_image(nav[a].image_to_ground(256.0, 256.0, height=0.0))
        assert np.hypot(ln - lt, sn - st) > 10.0
    params = TiePointParams(detect=DetectParams(per_cell=1), match=MatchParams(search=128.0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # points predicted outside the other image
        tp = find_tiepoints(images, nav, params=params, scheduler="sync")
    names = list(tp["image"].values)
    pid, iid = tp["point_id"].values, tp["image_id"].values
    line, sample = tp["line"].values, tp["sample"].values
    first: dict[int, int] = {}
    rows: dict[tuple[str, str], list[tuple[int, int]]] = {}  # (image a, image b) -> (row in a, row in b)
    for k in np.argsort(pid, kind="stable"):
        if pid[k] in first:
            rows.setdefault((names[iid[first[pid[k]]]], names[iid[k]]), []).append((first[pid[k]], k))
        else:
            first[pid[k]] = k
    errors, per_pair = [], {}
    for (a, b), rr in rows.items():
        r0, r1 = np.array(rr).T
        dl, ds = matching_errors(tru[a], tru[b], line[r0], sample[r0], line[r1], sample[r1], scene[0])
        errors.append(np.hypot(dl, ds))
        key = tuple(sorted((a, b)))
        per_pair[key] = per_pair.get(key, 0) + len(rr)
    assert len(per_pair) == 3 and min(per_pair.values()) >= 30, per_pair
    err = np.concatenate(errors)
    # measured: 176 / 101 / 101 matches per pair; median 0.041 px, 95th percentile 0.22 px, max 0.48 px
    assert np.median(err) < 0.1 and np.percentile(err, 95) < 0.35 and err.max() < 1.0


# -- check points -----------------------------------------------------------------------------------

def test_check_points(block, cams, scene):
    n = 12
    ds = block_check_points(block, n, sigma_px=0.3, seed=4, dtm=scene[0], cameras=cams["truth"])
    assert ds.sizes["point"] == n and ds.sizes["observation"] == n * 12
    assert list(ds["image"].values) == list(block.image_names)
    xyz = ds["xyz"].values
    # on the truth DTM: every truth camera's ray through the true measurement meets the DTM at the point
    for k, name in enumerate(block.image_names):
        sel = ds["image_id"].values == k
        lt, st = ds["line_true"].values[sel], ds["sample_true"].values[sel]
        g = cams["truth"][name].image_to_ground(lt, st, dtm=scene[0])
        assert np.linalg.norm(g - xyz[ds["point_id"].values[sel]], axis=1).max() < 0.05
        assert np.all((lt > 20) & (lt < block.manifest["images"][name]["lines"] - 20))
    from lunarmap.camera.intersect import DtmSampler

    h = DtmSampler(scene[0])(ds["longitude"].values, ds["latitude"].values)
    np.testing.assert_allclose(ds["height"].values, h, atol=1e-6)
    resid = np.concatenate([(ds["line"] - ds["line_true"]).values, (ds["sample"] - ds["sample_true"]).values])
    assert 0.2 < resid.std() < 0.4 and abs(resid.mean()) < 0.1
    again = block_check_points(block, n, sigma_px=0.3, seed=4, dtm=scene[0], cameras=cams["truth"])
    xr.testing.assert_identical(ds, again)


# -- bad input, atomicity, reproducibility -------------------------------------------------------

@pytest.mark.parametrize("kwargs", [
    {"seed": -1}, {"seed": 1.5}, {"seed": "0"}, {"orbits": 1}, {"orbits": 5}, {"site_latitude_deg": 89.0},
    {"site_latitude_deg": float("nan")}, {"navigation": {"position_offset_m": (50.0, 20.0)}},
    {"navigation": {"attitude_noise_rad": -1.0}}, {"navigation": {"noise_periods_s": (1.0, 5.0)}},
    {"navigation": {"no_such_parameter": 1.0}}, {"navigation": 3},
])
def test_bad_arguments_write_nothing(tmp_path, kwargs):
    dest = tmp_path / "new"
    with pytest.raises(InvalidInputError):
        sim.write_block_mission(dest, **kwargs)
    assert not dest.exists()


def test_missing_or_broken_folders(tmp_path, block):
    missing = tmp_path / "nowhere"
    for call in (lambda: sim.open_block_mission(missing), lambda: render_block(missing),
                 lambda: block_check_points(missing), lambda: block_cameras(missing)):
        with pytest.raises(BlockMissionError, match="does not exist") as err:
            call()
        assert isinstance(err.value, FileNotFoundError) and isinstance(err.value, LunarmapError)
    with pytest.raises(BlockMissionError, match="block_mission.json is missing"):
        sim.open_block_mission(tmp_path)
    a_file = tmp_path / "file"
    a_file.write_text("x")
    with pytest.raises(BlockMissionError, match="not a folder"):
        sim.write_block_mission(a_file)
    with pytest.raises(BlockMissionError, match="does not exist"):
        render_block(block, tmp_path / "no_output", names=["orbit1_nac"], crop=16)
    with pytest.raises(InvalidInputError, match="unknown image"):
        render_block(block, names=["orbit9_nac"], write=False)
    with pytest.raises(InvalidInputError, match="supersample"):
        render_block(block, supersample=0, write=False)
    with pytest.raises(InvalidInputError, match="kernel set"):
        block.metakernel("estimated")
    for bad, what in (({"n": 0}, "n must"), ({"sigma_px": -1.0}, "sigma_px"), ({"seed": -2}, "seed"),
                      ({"margin_px": float("nan")}, "margin_px"), ({}, "no camera given")):
        with pytest.raises(InvalidInputError, match=what):
            block_check_points(block, **{"n": 3, **bad}, cameras={})


def test_incomplete_folder_is_named(tmp_path):
    bm = sim.write_block_mission(tmp_path / "b", seed=2)
    (bm.folder / "orbit2_tc.lbl").unlink()
    with pytest.raises(BlockMissionError, match="orbit2_tc.lbl is missing"):
        sim.open_block_mission(bm.folder)


def test_failed_write_leaves_nothing(tmp_path, monkeypatch):
    import lunarmap.synthetic.block_writing as bw

    def broken(*args, **kwargs):
        raise OSError("simulated disk failure after the kernels were written")

    monkeypatch.setattr(bw, "_image_records", broken)
    with pytest.raises(OSError, match="simulated"):
        sim.write_block_mission(tmp_path / "new", seed=0)
    assert not (tmp_path / "new").exists()
    (tmp_path / "keep").mkdir()
    (tmp_path / "keep" / "x.txt").write_text("unrelated")
    with pytest.raises(OSError, match="simulated"):
        sim.write_block_mission(tmp_path / "keep", seed=0)
    assert sorted(p.name for p in (tmp_path / "keep").iterdir()) == ["x.txt"]
    with SPICE_LOCK:
        assert spiceypy.ktotal("ALL") == 0


def test_same_seed_same_files_other_seed_differs(block, tmp_path):
    again = sim.write_block_mission(tmp_path / "again", seed=0)
    for f in block.folder.iterdir():
        if f.suffix in (".tm", ".lbl", ".json", ".tf", ".ti", ".tls", ".tsc", ".tpc"):
            assert (again.folder / f.name).read_bytes() == f.read_bytes(), f.name
    other = sim.build_block_model(1)
    assert not np.allclose(other.navigation.position_offset, block.model.navigation.position_offset)
    assert sim.open_block_mission(again.folder).manifest == again.manifest


def test_manifest_that_does_not_match_its_model_is_refused(tmp_path):
    bm = sim.write_block_mission(tmp_path / "b", seed=2)
    man = json.loads((bm.folder / "block_mission.json").read_text())
    man["seed"] = 3  # another seed rebuilds another model than the one the kernels hold
    (bm.folder / "block_mission.json").write_text(json.dumps(man))
    with pytest.raises(BlockMissionError, match="does not match"):
        sim.open_block_mission(bm.folder)
    (bm.folder / "block_mission.json").write_text("{not json")
    with pytest.raises(BlockMissionError, match="not a valid block-mission manifest"):
        sim.open_block_mission(bm.folder)


# -- several sites per orbit ---------------------------------------------------------------------------

SITE_KINDS = ("nac", "tc", "frame_a", "frame_b")


@pytest.fixture(scope="module")
def block2(tmp_path_factory) -> sim.BlockMission:
    """Two sites 8 degrees of latitude apart, seen on two orbits: 16 images."""
    return sim.write_block_mission(tmp_path_factory.mktemp("block2"), seed=0, orbits=2, sites=2)


@pytest.fixture(scope="module")
def isds2(block2):
    return {kind: {n: image_support(block2.label(n), block2.metakernel(kind)) for n in block2.image_names}
            for kind in ("truth", "navigation")}


@pytest.fixture(scope="module")
def cams2(isds2):
    return {kind: {n: camera_from_isd(i) for n, i in d.items()} for kind, d in isds2.items()}


def _latlon(xyz: np.ndarray) -> tuple[float, float]:
    return float(np.degrees(np.arcsin(xyz[2] / np.linalg.norm(xyz)))), float(np.degrees(np.arctan2(xyz[1], xyz[0])))


def test_two_sites_files_names_and_manifest(block2):
    man = block2.manifest
    expected = [f"s{s}_orbit{o}_{k}" for s in (1, 2) for o in (1, 2) for k in SITE_KINDS]
    assert list(block2.image_names) == expected and block2.n_sites == 2
    names = sorted(p.name for p in block2.folder.iterdir() if p.suffix != ".nc")
    assert names == sorted([*SHARED_KERNELS, *TRUTH_KERNELS, *NAVIGATION_KERNELS, "truth.tm", "navigation.tm",
                            "block_mission.json", *(f"{n}.lbl" for n in expected)])
    assert man["parameters"]["sites"] == 2 and man["parameters"]["site_spacing_deg"] == -8.0
    assert [s["latitude_deg"] for s in man["sites"]] == [57.0, 49.0]
    assert man["sites"][1]["images"] == expected[8:] and man["site"]["latitude_deg"] == 57.0
    for n in expected:
        im = man["images"][n]
        assert im["site"] == int(n[1]) and im["orbit"] == int(n[8])
        assert abs(im["seconds_from_orbit_reference"]) < 6.0  # relative to its own site's pass
        assert 0.9 < im["geometry"]["gsd_m"] < 1.1 and 20.0 < im["geometry"]["incidence_deg"] < 65.0
    # one pass per (orbit, site), in time order; windows separated by slews; northbound: site 2 (south) first
    passes = man["passes"]
    assert [(p["orbit"], p["site"]) for p in passes] == [(1, 2), (1, 1), (2, 2), (2, 1)]
    for a, b in zip(passes, passes[1:]):
        assert b["window_et"][0] - a["window_et"][1] >= 20.0
    for o in man["orbits"]:  # the navigation reference: midway between the orbit's two sites
        mine = [p["reference_et"] for p in passes if p["orbit"] == o["orbit"]]
        assert o["reference_et"] == pytest.approx(0.5 * sum(mine), abs=1e-6)
        assert 140.0 < abs(mine[1] - mine[0]) < 160.0  # 8 degrees of a 113-minute orbit
    # convergence only between images of one site
    assert all(a[:2] == b[:2] for a, b in (k.split("|") for k in man["convergence_deg"]))
    assert sim.open_block_mission(block2.folder).manifest == man
    # site 1 of a two-site block is where the one-site block's site is
    one = sim.build_block_model(0, orbits=2)
    assert block2.model.site(1).longitude_deg == pytest.approx(one.site_longitude_deg, abs=1e-9)
    assert block2.model.pass_of(1, 1).epoch == pytest.approx(one.passes[0].epoch, abs=1e-6)


def test_two_sites_truth_kernels_reproduce_the_model(block2, isds2):
    """Through image_support (every image) and SPICE directly between records, in every pass window.

    Measured through image_support: positions 1.1e-3 mm, attitudes 1.3e-10 rad.
    """
    m = block2.model
    worst_p = worst_a = 0.0
    for n, isd in isds2["truth"].items():
        eo = isd.exterior_orientation()
        worst_p = max(worst_p, np.abs(eo.positions - m.position_body_fixed(isd.times)).max())
        cam_id = block2.manifest["images"][n]["instrument_id"]
        worst_a = max(worst_a, rotation_angle(eo.rotation_at(eo.times), m.sensor_to_body(cam_id, isd.times)).max())
    assert worst_p < 1e-3 and worst_a < 1e-9
    rng = np.random.default_rng(5)
    kset = KernelSet.from_metakernel(block2.truth_metakernel)
    with kernels(kset):
        for p in m.passes:
            ts = rng.uniform(p.start_et + 1, p.end_et - 1, 10) + 0.123
            got = np.array([spiceypy.spkez(-990, t, "J2000", "NONE", 301)[0] for t in ts])
            assert np.abs(got[:, :3] - m.state(ts)[:, :3]).max() < 1e-6  # km
            c = np.array([spiceypy.pxform("J2000", "SIM_SC_BUS", t) for t in ts])
            assert rotation_angle(c, m.bus_matrix(ts)).max() < 1e-9
            nadir = np.array([m.nadir.matrix(t) for t in ts])
            roll = Rotation.from_matrix(c @ np.swapaxes(nadir, 1, 2)).as_rotvec()
            np.testing.assert_allclose(roll[:, 0], -np.radians(p.roll_deg), atol=1e-9)
        # the attitude kernels cover exactly the pass windows (the slews between sites are gaps)
        for ck in (block2.folder / TRUTH_KERNELS[1], block2.folder / NAVIGATION_KERNELS[1]):
            cover = spiceypy.ckcov(str(ck), -990000, False, "INTERVAL", 0.0, "TDB")
            got = np.array([spiceypy.wnfetd(cover, i) for i in range(spiceypy.wncard(cover))])
            want = np.array(sorted([p.start_et, p.end_et] for p in m.passes))
            np.testing.assert_allclose(got, want, atol=1e-3)


def test_two_sites_navigation_errors_are_per_orbit(block2, isds2):
    """NAVIGATION - TRUTH at every ISD epoch is the manifest's per-orbit model, about one epoch for both sites."""
    man = block2.manifest
    truth_set = KernelSet.from_metakernel(block2.truth_metakernel)
    worst_p = worst_a = 0.0
    for n in block2.image_names:
        t_isd, n_isd = isds2["truth"][n], isds2["navigation"][n]
        idx = np.unique(np.linspace(0, t_isd.times.size - 1, 5).astype(int))
        et = t_isd.times[idx]
        eo_t, eo_n = t_isd.exterior_orientation(), n_isd.exterior_orientation()
        with kernels(truth_set):
            bus_to_bf = np.array([spiceypy.pxform("SIM_SC_BUS", "IAU_MOON", t) for t in et])
        for k, (i, t) in enumerate(zip(idx, et)):
            dp, th = _manifest_errors(man, t)
            worst_p = max(worst_p, np.abs(eo_n.positions[i] - eo_t.positions[i] - dp).max())
            w = bus_to_bf[k] @ th
            r_t, r_n = eo_t.rotation_at(eo_t.times[i]), eo_n.rotation_at(eo_n.times[i])
            worst_a = max(worst_a, rotation_angle(r_n @ r_t.T, Rotation.from_rotvec(w).as_matrix()))
        rec = man["images"][n]["navigation_error"]
        np.testing.assert_allclose(rec["position_m"], _manifest_errors(man, rec["et"])[0], rtol=0, atol=1e-9)
    assert worst_p < 1e-3 and worst_a < 1e-9
    # the drifts act over the ~75 s from the orbit's reference to each site: the multi-site magnitudes keep
    # the sites' errors of one orbit within tens of metres of each other
    nav = man["navigation_errors"]
    assert nav["magnitudes"]["position_drift_m_per_s"] == [0.02, 0.1]
    for o in nav["orbits"]:
        assert len(o["pass_windows_et"]) == 2
        e = [np.array(man["images"][f"s{s}_orbit{o['orbit']}_nac"]["navigation_error"]["position_m"]) for s in (1, 2)]
        assert 0.5 < np.linalg.norm(e[0] - e[1]) < 20.0  # measured 8.5 and 9.6 m (errors of 34-43 m)


def test_two_sites_every_image_sees_its_site_and_no_other(block2, cams2):
    """Truth cameras: each image centre on its site; no image of one site sees any of the other's footprints."""
    m = block2.model
    grids = {}
    for n, cam in cams2["truth"].items():
        im = block2.manifest["images"][n]
        g = cam.image_to_ground(im["lines"] / 2, im["samples"] / 2, height=0.0)
        tol = {"nac": 0.1, "tc": 15.0}.get(im["kind"], 120.0)  # measured 0.012 m, 4-8 m, 90-92 m
        assert np.linalg.norm(g - m.site_xyz(site=im["site"])) < tol, n
        lat, _ = _latlon(g)
        assert lat == pytest.approx(block2.manifest["sites"][im["site"] - 1]["latitude_deg"], abs=0.01)
        L, S = np.meshgrid(np.linspace(0.5, im["lines"] - 0.5, 9), np.linspace(0.5, im["samples"] - 0.5, 9))
        grids[n] = cam.image_to_ground(L.ravel(), S.ravel(), height=0.0)
    for a in block2.image_names:
        for b in block2.image_names:
            if a == b:
                continue
            la, sa = cams2["truth"][b].ground_to_image(grids[a], on_miss="nan")
            seen = np.count_nonzero(np.isfinite(la) & np.isfinite(sa))
            if a[:2] == b[:2]:
                assert seen > 0, (a, b)  # images of one site overlap (so the test can fail)
            else:
                assert seen == 0, (a, b)
    # rolled on every orbit, differently per site (each site sits differently between the tracks)
    rolls = {(p.orbit, p.site): p.roll_deg for p in m.passes}
    assert abs(rolls[1, 1] - rolls[2, 1]) > 15.0 and abs(rolls[1, 2] - rolls[2, 2]) > 15.0
    assert abs(rolls[1, 1] - rolls[1, 2]) > 1.0  # measured: 10.1 / 12.1 and -10.1 / -12.1 degrees


def test_two_sites_scenes_render_and_check_points(block2, tmp_path):
    """Each image rendered from its own site's scene (a scene of another site would leave NaN pixels)."""
    names = ["s1_orbit1_tc", "s1_orbit2_frame_b", "s2_orbit1_frame_a", "s2_orbit2_nac"]
    out = render_block(block2, tmp_path, names=names, supersample=1, crop=32)
    assert set(out.scenes) == {1, 2} and set(out.images) == set(names)
    (d1, _), (d2, _) = out.scenes[1], out.scenes[2]
    for dtm, site in ((d1, 1), (d2, 2)):
        s = block2.model.site(site)
        assert float(dtm["lat"].mean()) == pytest.approx(s.latitude_deg, abs=1e-3)
        assert float(dtm["lon"].mean()) == pytest.approx(s.longitude_deg, abs=1e-3)
    assert d1.shape != d2.shape or not np.allclose(d1.values, d2.values)  # independent scenes
    for n, img in out.images.items():
        assert np.all(np.isfinite(img.values)) and 60.0 < img.values.mean() < 200.0 and img.values.std() > 5.0, n
        assert img.attrs["site"] == int(n[1])
    for k in (1, 2):
        on_disk = xr.open_dataarray(out.paths[f"dtm_s{k}"]).load()
        np.testing.assert_array_equal(on_disk.values, (d1, d2)[k - 1].values)
        assert out.paths[f"dtm_s{k}"].name == f"dtm_s{k}.nc"
    assert "dtm" not in out.paths
    # check points of site 2: on its DTM and seen by its images
    cp = block_check_points(block2, 5, seed=1, site=2, dtm=d2)
    assert list(cp["image"].values) == list(block2.site_image_names(2)) and cp.attrs["site"] == 2
    from lunarmap.camera.intersect import DtmSampler

    np.testing.assert_allclose(cp["height"].values, DtmSampler(d2)(cp["longitude"].values, cp["latitude"].values),
                               atol=1e-6)
    assert np.all(np.abs(cp["latitude"].values - 49.0) < 0.05)
    with pytest.raises(InvalidInputError, match="2 sites"):
        block_check_points(block2, 3)
    with pytest.raises(InvalidInputError, match="one site"):
        block_check_points(block2, 3, names=["s1_orbit1_nac", "s2_orbit1_nac"])
    with pytest.raises(InvalidInputError, match="not site 1"):
        block_check_points(block2, 3, names=["s2_orbit1_nac"], site=1)
    with pytest.raises(InvalidInputError, match="site must be"):
        block_scene(block2, 3)


@pytest.mark.parametrize("kwargs", [
    {"sites": 0}, {"sites": 49}, {"sites": 2.0}, {"sites": 2, "site_spacing_deg": 0.5},
    {"sites": 2, "site_spacing_deg": 3.0},    # 45-s pass windows 56 s apart: no time to slew
    {"sites": 2, "site_spacing_deg": 25.0}, {"sites": 2, "site_spacing_deg": float("nan")},
    {"sites": 8, "site_spacing_deg": -20.0},  # 57 ... -83: the last sites are too near the pole
    {"sites": 3, "site_spacing_deg": 10.0},   # 57, 67, 77: too near the pole
    {"sites": 2, "site_half_width_s": 5.0},   # the TC and frame camera see the site outside the window
])
def test_bad_site_arguments_write_nothing(tmp_path, kwargs):
    dest = tmp_path / "new"
    with pytest.raises(InvalidInputError, match="site"):
        sim.write_block_mission(dest, **kwargs)
    assert not dest.exists()


@pytest.mark.slow
def test_two_site_workflow_run(tmp_path):
    """The whole chain on 2 sites x 2 orbits x NAC: per-site control, navigation groups across the sites."""
    from lunarmap.workflows import load_config, run, write_example

    names = ["s1_orbit1_nac", "s1_orbit2_nac", "s2_orbit1_nac", "s2_orbit2_nac"]
    cfg = write_example(tmp_path, quick=True, sites=2, names=names, n_control=4, n_check=8)
    conf = load_config(cfg)
    assert conf.dtm is None and "4 images over 2 sites" in conf.name
    assert [im.group for im in conf.images] == ["1-nac", "2-nac", "1-nac", "2-nac"]  # per (orbit, camera)
    res = run(cfg, scheduler="sync", report=False)
    s = res.summary
    before, after = np.array(s["check_rms_before_m"]), np.array(s["check_rms_after_m"])
    # measured: 3-D check RMS 42.9 m before, 1.5 m after; normalized RMS 1.05
    assert np.sqrt(np.sum(before ** 2)) > 10 * np.sqrt(np.sum(after ** 2)) and s["converged"]
    assert 0.5 < s["check_normalized_rms"] < 1.5
    # the 4 pairs across the sites never become match steps (footprint caps apart), the 2 within a site do
    assert res.counts()["match"] == (2, 0) and s["pairs_apart"] == 4 and s["pairs_candidate"] == 2
    from lunarmap.adjust import read_network

    net = read_network(tmp_path / "points.nc")  # a datum for each site's sub-block
    assert {(str(p)[:4], str(t)) for p, t in zip(net.point_id, net.point_type)} == \
        {("s1_C", "control"), ("s2_C", "control"), ("s1_K", "check"), ("s2_K", "check")}
    notes = {r.item: r.note for r in res.done if r.step == "match"}
    assert len(notes) == 2
    for item, note in notes.items():  # pairs within a site are matched
        a, b = item.split(" -> ")
        assert a[:2] == b[:2] and not note.startswith("skipped"), (item, note)


def test_short_pass_windows_give_many_sites_with_their_slews():
    """Sites 2.5 degrees apart with 12-s windows: 16 sites, 192 images, every camera inside its window."""
    from lunarmap.synthetic.block import MIN_SLEW_S, build_block_model

    m = build_block_model(0, sites=16, site_spacing_deg=-2.5, site_half_width_s=12.0)
    assert len(m.images) == 192 and m.sites[-1].latitude_deg == pytest.approx(57.0 - 15 * 2.5)
    w = sorted((p.start_et, p.end_et) for p in m.passes)
    assert all(b[0] - a[1] >= MIN_SLEW_S for a, b in zip(w, w[1:]))
    assert all(abs((p.end_et - p.start_et) - 24.0) < 1e-9 for p in m.passes)
    for im in m.images:                      # every image's mid time lies in its pass window
        p = m.pass_of(im.orbit, im.site)
        assert p.start_et < im.center_et < p.end_et
