"""The synthetic LUNARMAP-SIM mission: its kernels read back through SPICE equal the truth model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import spiceypy

import lunarmap.synthetic as sim
from lunarmap.labels import load_label
from lunarmap.spice import SPICE_LOCK, KernelSet, kernels
from lunarmap.synthetic.bodies import MOON_RADIUS_KM, j2000_to_iau_moon, moon_state_ssb, sun_state_ssb
from lunarmap.synthetic.mission import CK_STEP, SPK_STEP
from lunarmap.synthetic.writing import metakernel_text

ROOT = Path(__file__).resolve().parents[1]
TICK = 1.0 / 65536.0  # s, one clock tick


def rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (rad) of the rotation between two rotation matrices, accurate for tiny angles."""
    r = a @ b.T
    return float(np.linalg.norm([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]) / 2.0)


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sim")
    mk = sim.write_mission(folder, seed=0)
    return mk, sim.build_mission(0), sim.load_manifest(mk)


@pytest.fixture(scope="module")
def kset(written):
    return KernelSet.from_metakernel(written[0])


@pytest.fixture()
def loaded(kset):
    with kernels(kset):
        yield


def test_files_manifest_and_template(written):
    mk, mission, man = written
    folder = mk.parent
    names = sorted(p.name for p in folder.iterdir())
    expected = sorted([*sim.KERNEL_FILES, *(f"{n}.lbl" for n in sim.IMAGE_NAMES), sim.MANIFEST_NAME,
                       sim.METAKERNEL_NAME])
    assert names == expected  # and no staging folder left behind
    assert sum((folder / n).stat().st_size for n in names) < 5e6
    # the meta-kernel is a copy of the project's template, which names exactly the written kernels
    template = ROOT / "kernels_meta" / "synthetic_mission.tm"
    assert mk.read_text() == template.read_text() == metakernel_text()
    assert man["spacecraft"] == {"name": "LUNARMAP-SIM", "id": -990, "sclk_id": -990}
    assert man["frames"]["SIM_SC_BUS"]["id"] == sim.BUS_FRAME_ID == -990000
    assert set(man["images"]) == set(sim.IMAGE_NAMES)
    for name, im in man["images"].items():
        assert (folder / im["label"]).is_file()
        assert im["camera_type"] == ("LINESCAN" if name.startswith("sim_nac") else "FRAME")
        assert man["coverage"]["start_et"] + 60 < im["start_et"] < im["stop_et"] < man["coverage"]["end_et"]
    cov = man["coverage"]
    assert cov["end_et"] - cov["start_et"] >= 3 * mission.orbit.period
    assert cov["start_utc"].startswith("2026-")


def test_loads_from_another_working_directory(kset, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert [Path(p).name for p in kset.paths] == list(sim.KERNEL_FILES)
    with kernels(kset):
        assert spiceypy.ktotal("ALL") == len(sim.KERNEL_FILES)
        assert spiceypy.bodn2c("LUNARMAP-SIM") == -990
        assert spiceypy.namfrm("SIM_SC_BUS") == -990000
    with SPICE_LOCK:
        assert spiceypy.ktotal("ALL") == 0  # write_mission and kernels() leave nothing loaded


def test_spacecraft_ephemeris_matches_model(loaded, written):
    _, mission, _ = written
    rng = np.random.default_rng(11)
    et = rng.uniform(mission.start_et, mission.end_et, 400)
    et = et + np.where(np.abs(np.mod(et - mission.start_et, SPK_STEP)) < 0.01, 0.5, 0.0)  # off the nodes
    got = np.array([spiceypy.spkez(-990, t, "J2000", "NONE", 301)[0] for t in et])
    truth = mission.state(et)
    assert np.abs(got[:, :3] - truth[:, :3]).max() < 1e-6  # km: 1 mm (measured ~1e-11 km)
    assert np.abs(got[:, 3:] - truth[:, 3:]).max() < 1e-6  # km/s: 1 mm/s (measured ~1e-12 km/s)
    alt = np.linalg.norm(truth[:, :3], axis=1) - MOON_RADIUS_KM
    assert 45.0 < alt.min() and alt.max() < 55.0


def test_orbit_is_polar_and_near_circular(written):
    _, mission, man = written
    st = mission.state(np.linspace(mission.start_et, mission.end_et, 2000))
    h = np.cross(st[:, :3], st[:, 3:])
    pole = j2000_to_iau_moon(mission.start_et)[2]
    incl = np.degrees(np.arccos(h @ pole / np.linalg.norm(h, axis=1)))
    assert np.abs(incl - 90.0).max() < 0.01
    assert 0.0005 < man["orbit"]["eccentricity"] < 0.005


def test_attitude_matches_model_between_ck_records(loaded, written):
    """Linear CK interpolation at record midpoints (its worst case) stays below 1 nrad.

    The nominal rotation is at an almost constant rate about an almost fixed
    axis, which type-3 interpolation reproduces exactly; what remains is the
    wobble's angular acceleration a ~ 1.75e-4 rad * (2 pi / 1500 s)^2 ~ 3e-9
    rad/s^2, giving a h^2 / 8 ~ 1e-10 rad for h = 0.5 s (measured 1.6e-10).
    """
    _, mission, _ = written
    grid = mission.ck_grid()
    mids = grid[:-1:37] + 0.5 * CK_STEP
    worst = max(rotation_angle(spiceypy.pxform("J2000", "SIM_SC_BUS", t), mission.bus_matrix(t)) for t in mids)
    assert worst < 1e-9
    rng = np.random.default_rng(5)
    for t in rng.uniform(mission.start_et, mission.end_et, 50):
        _, av = spiceypy.xf2rav(spiceypy.sxform("J2000", "SIM_SC_BUS", t))
        assert np.linalg.norm(av - mission.attitude.angular_velocity(np.array([t]))[0]) < 1e-10  # rad/s


def test_nadir_pointing_and_yaw_flip(loaded, written):
    _, mission, man = written
    flip = man["yaw_flip"]
    t0, t1 = flip["start_et"], flip["end_et"]
    assert 0.2 * mission.orbit.period < t1 - t0 < mission.orbit.period
    probes = [mission.start_et + 100.0, t0 - CK_STEP / 2, t0, t0 + 0.3, 0.5 * (t0 + t1), t1 - 0.3, t1,
              t1 + CK_STEP / 2, mission.end_et - 100.0]
    inside = [False, False, True, True, True, True, False, False, False]
    for t, flipped in zip(probes, inside):
        c = spiceypy.pxform("J2000", "SIM_SC_BUS", t)
        st = spiceypy.spkez(-990, t, "J2000", "NONE", 301)[0]
        r, v = np.array(st[:3]), np.array(st[3:])
        assert c[2] @ (-r / np.linalg.norm(r)) > np.cos(np.deg2rad(0.05))  # +z at the Moon's centre
        vx = (c @ v)[0] / np.linalg.norm(v)
        assert (vx < -0.999) if flipped else (vx > 0.999), (t - t0, vx)
        assert rotation_angle(c, mission.bus_matrix(t)) < 1e-9
    for name, im in man["images"].items():
        assert im["yaw_flipped"] == (name == "sim_nac_flipped")
        assert im["yaw_flipped"] == (t0 <= im["start_et"] and im["stop_et"] < t1)
        assert im["spacecraft_direction"] == (-1 if im["yaw_flipped"] else 1)


def test_frame_chain_and_instrument_mounting(loaded, written):
    _, mission, _ = written
    t = mission.start_et + 4321.123
    for inst in (sim.NAC_ID, sim.FRAME_CAMERA_ID):
        frame = spiceypy.frmnam(inst)
        mount = spiceypy.pxform("SIM_SC_BUS", frame, t)
        assert rotation_angle(mount, mission.mounting(inst)) < 1e-15
        assert 0.01 < np.degrees(rotation_angle(mount, np.eye(3))) < 0.1  # a few hundredths of a degree
        chain = spiceypy.pxform(frame, "IAU_MOON", t)
        model = j2000_to_iau_moon(t) @ mission.instrument_matrix(inst, t).T
        assert rotation_angle(chain, model) < 1e-9
    assert rotation_angle(spiceypy.pxform("J2000", "IAU_MOON", t), j2000_to_iau_moon(t)) < 1e-12
    np.testing.assert_allclose(spiceypy.bodvrd("MOON", "RADII", 3)[1], [1737.4] * 3)


def test_instrument_kernels(loaded):
    shape, frame, bsight, n, bounds = spiceypy.getfov(sim.NAC_ID, 4)
    assert (shape, frame, n) == ("RECTANGLE", "SIM_NAC", 4)
    np.testing.assert_array_equal(bsight, [0.0, 0.0, 1.0])
    # corners (x/f, y/f, 1): the detector line spans 5064 pixels along +y, one pixel along +x
    assert np.ptp(bounds[:, 1]) == pytest.approx(5064 * 0.007 / 699.62, rel=1e-12)
    assert np.ptp(bounds[:, 0]) == pytest.approx(0.007 / 699.62, rel=1e-12)
    p = "INS-990100_"
    assert spiceypy.gdpool(p + "FOCAL_LENGTH", 0, 1)[0] == pytest.approx(699.62)
    assert spiceypy.gdpool(p + "PIXEL_PITCH", 0, 1)[0] == pytest.approx(0.007)
    assert spiceypy.gipool(p + "PIXEL_SAMPLES", 0, 1)[0] == 5064
    assert spiceypy.gipool(p + "PIXEL_LINES", 0, 1)[0] == 1
    assert spiceypy.gdpool(p + "BORESIGHT_SAMPLE", 0, 1)[0] == 2548.0
    assert spiceypy.gdpool(p + "OD_K", 0, 1)[0] == pytest.approx(1.81e-5)
    np.testing.assert_allclose(spiceypy.gdpool(p + "ITRANSS", 0, 3), [0.0, 0.0, 1 / 0.007])
    assert spiceypy.gcpool(p + sim.KW_CAMERA_TYPE, 0, 1)[0] == "LINESCAN"
    assert spiceypy.gcpool(p + sim.KW_DISTORTION_MODEL, 0, 1)[0] == "lrolrocnac"
    assert spiceypy.gcpool(p + "LIGHTTIME_CORRECTION", 0, 1)[0] == "NONE"
    f = "INS-990200_"
    shape, frame, _, n, bounds = spiceypy.getfov(sim.FRAME_CAMERA_ID, 4)
    assert (shape, frame, n) == ("RECTANGLE", "SIM_FRAME", 4)
    assert (spiceypy.gipool(f + "PIXEL_SAMPLES", 0, 1)[0], spiceypy.gipool(f + "PIXEL_LINES", 0, 1)[0]) == (384, 288)
    np.testing.assert_allclose(spiceypy.gdpool(f + "OD_K", 0, 3), [0.0, -2.42e-5, 0.0])
    assert spiceypy.gcpool(f + sim.KW_DISTORTION_MODEL, 0, 1)[0] == "radial"
    assert spiceypy.gcpool(f + sim.KW_CAMERA_TYPE, 0, 1)[0] == "FRAME"


@pytest.mark.parametrize("name", sim.IMAGE_NAMES)
def test_boresight_hits_where_the_image_name_says(loaded, written, name):
    _, mission, man = written
    im = man["images"][name]
    spoint, _, _ = spiceypy.sincpt("Ellipsoid", "MOON", im["center_et"], "IAU_MOON", "NONE", "LUNARMAP-SIM",
                                   im["frame"], [0.0, 0.0, 1.0])
    lat = np.degrees(spiceypy.reclat(spoint)[2])
    assert lat == pytest.approx(im["target_latitude_deg"], abs=0.05)
    # sunlit, not grazing except near the pole
    incidence = np.degrees(spiceypy.ilumin("Ellipsoid", "MOON", im["center_et"], "IAU_MOON", "LT+S",
                                           "LUNARMAP-SIM", spoint)[3])
    assert incidence < (88.0 if name == "sim_nac_85n" else 60.0)


def test_frame_pair_overlaps(loaded, written):
    _, _, man = written
    pts = []
    for name in ("sim_frame_a", "sim_frame_b"):
        im = man["images"][name]
        pts.append(spiceypy.sincpt("Ellipsoid", "MOON", im["center_et"], "IAU_MOON", "NONE", "LUNARMAP-SIM",
                                   "SIM_FRAME", [0.0, 0.0, 1.0])[0])
    footprint = 384 * 0.023 / 89.874 * 50.0  # km along track (samples run along +x)
    assert 0.3 < np.linalg.norm(pts[1] - pts[0]) / footprint < 0.5  # ~60 % overlap


@pytest.mark.parametrize("name", sim.IMAGE_NAMES)
def test_labels(loaded, written, name):
    mk, mission, man = written
    im = man["images"][name]
    cube = load_label(mk.parent / im["label"])["IsisCube"]
    dims, inst = cube["Core"]["Dimensions"], cube["Instrument"]
    assert (dims["Samples"], dims["Lines"], dims["Bands"]) == (im["samples"], im["lines"], 1)
    assert inst["SpacecraftName"] == "LUNARMAP-SIM" and inst["TargetName"] == "MOON"
    assert inst["InstrumentId"] == im["instrument"]
    assert cube["Kernels"]["NaifFrameCode"] == im["instrument_id"]
    assert spiceypy.scs2e(-990, str(inst["SpacecraftClockStartCount"])) == pytest.approx(im["start_et"], abs=1e-7)
    assert spiceypy.str2et(str(inst["StartTime"])) == pytest.approx(im["start_et"], abs=1e-6)
    if im["camera_type"] == "LINESCAN":
        assert im["lines"] == 52224
        line_time = float(inst["LineExposureDuration"]) / 1000.0
        assert line_time == pytest.approx(im["line_time_s"], rel=1e-12)
        # square ground pixels: line time = ground pixel size / ground-track speed
        alt, speed = mission.ground_geometry(im["center_et"])
        assert line_time == pytest.approx(alt * 0.007 / 699.62 / speed, rel=1e-4)
        assert 2.5e-4 < line_time < 3.5e-4
    else:
        assert float(inst["ExposureDuration"]) == pytest.approx(im["exposure_s"] * 1000.0)


def test_clock_round_trip(loaded, written):
    _, mission, _ = written
    for t in np.random.default_rng(2).uniform(mission.start_et, mission.end_et, 20):
        assert abs(spiceypy.scs2e(-990, spiceypy.sce2s(-990, t)) - t) <= TICK  # strings truncate to a tick
        assert spiceypy.sct2e(-990, spiceypy.sce2c(-990, t)) == pytest.approx(t, abs=1e-6)
    assert spiceypy.sce2s(-990, mission.sclk_zero_et + 1.5) == "1/0000000001:32768"


def test_sun_and_moon(loaded, written):
    _, mission, _ = written
    t = mission.start_et + 1000.0
    state, lt = spiceypy.spkez(10, t, "J2000", "LT+S", 301)
    assert 480.0 < lt < 520.0
    truth = sun_state_ssb(t - lt)[:3] - moon_state_ssb(t)[:3]
    cosang = np.dot(state[:3], truth) / np.linalg.norm(state[:3]) / np.linalg.norm(truth)
    assert cosang > np.cos(2e-4)  # stellar aberration is ~1e-4 rad
    moon = spiceypy.spkez(301, t, "J2000", "NONE", 0)[0]
    # at 1.5e8 km, double precision and the hourly Hermite records leave a few mm
    np.testing.assert_allclose(moon[:3], moon_state_ssb(t)[:3], rtol=0, atol=1e-5)  # km
    np.testing.assert_allclose(moon[3:], moon_state_ssb(t)[3:], rtol=0, atol=1e-9)  # km/s


def test_same_seed_gives_identical_files_other_seed_differs(written, tmp_path):
    mk, _, _ = written
    again = sim.write_mission(tmp_path / "again", seed=0)
    for f in mk.parent.iterdir():
        assert (again.parent / f.name).read_bytes() == f.read_bytes(), f.name
    other = sim.build_mission(1)
    assert other.nac_angles_deg != sim.build_mission(0).nac_angles_deg
    assert other.attitude.wobble_phase != sim.build_mission(0).attitude.wobble_phase


def test_failed_write_leaves_no_partial_set(tmp_path, monkeypatch):
    import lunarmap.synthetic.writing as writing

    def broken(*args, **kwargs):
        raise OSError("simulated disk failure after the kernels were written")

    monkeypatch.setattr(writing, "_image_records", broken)
    (tmp_path / "keep.txt").write_text("unrelated")
    with pytest.raises(OSError, match="simulated"):
        sim.write_mission(tmp_path, seed=0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.txt"]
    with SPICE_LOCK:
        assert spiceypy.ktotal("ALL") == 0
