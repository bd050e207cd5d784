"""ISDs from the real kernel sets in ../shared, against USGS ALE's output and SPICE.

LRO NAC: every number is compared with the ISD that ALE computed from the same
kernels. Clementine UVVIS and Kaguya TC have no ALE output; their conventions
(shared kernel README, section 5) are checked with direct spiceypy calls.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import spiceypy

from lunarmap.labels import load_label
from lunarmap.orientation.drivers import image_support
from lunarmap.spice import KernelSet, kernels

pytestmark = pytest.mark.shared

ARCSEC = np.pi / 180 / 3600


def quat_angle(q1, q2) -> np.ndarray:
    """Rotation angle (rad) between quaternion sets, sign-insensitive."""
    q1, q2 = np.asarray(q1, float), np.asarray(q2, float)
    d = np.minimum(np.linalg.norm(q1 - q2, axis=-1), np.linalg.norm(q1 + q2, axis=-1))
    return 4.0 * np.arcsin(np.clip(d / 2.0, 0, 1))


def matrix_angle(m1, m2) -> float:
    r = np.asarray(m1).reshape(3, 3) @ np.asarray(m2).reshape(3, 3).T
    return float(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1)))


@pytest.fixture(scope="module")
def lro_pair(lro_set):
    isd = image_support(lro_set / "M103595705LE_isis3.lbl", lro_set / "lro_nac_M103595705LE.tm")
    ale = json.loads((lro_set / "ale_isd.json").read_text())
    return isd.to_ale_dict(), ale


def test_lro_times_within_1us(lro_pair):
    ours, ale = lro_pair
    assert abs(ours["starting_ephemeris_time"] - ale["starting_ephemeris_time"]) <= 1e-6
    assert abs(ours["center_ephemeris_time"] - ale["center_ephemeris_time"]) <= 1e-6
    for block in ("instrument_position", "instrument_pointing", "body_rotation", "sun_position"):
        t_ours, t_ale = np.array(ours[block]["ephemeris_times"]), np.array(ale[block]["ephemeris_times"])
        assert t_ours.shape == t_ale.shape, block
        assert np.abs(t_ours - t_ale).max() <= 1e-6, block
    lsr_o, lsr_a = np.array(ours["line_scan_rate"]), np.array(ale["line_scan_rate"])
    assert np.abs(lsr_o - lsr_a).max() <= 1e-9


def test_lro_positions_within_1mm(lro_pair):
    ours, ale = lro_pair
    for block, tol_km in (("instrument_position", 1e-6), ("sun_position", 1e-6)):
        p = np.array(ours[block]["positions"]) - np.array(ale[block]["positions"])
        assert np.abs(p).max() <= tol_km, f"{block}: {np.abs(p).max() * 1e6:.3g} mm"
        v = np.array(ours[block]["velocities"]) - np.array(ale[block]["velocities"])
        assert np.abs(v).max() <= 1e-6, block  # 1 mm/s
        assert ours[block]["reference_frame"] == ale[block]["reference_frame"] == 1


def test_lro_rotations_within_1_milliarcsec(lro_pair):
    ours, ale = lro_pair
    for block in ("instrument_pointing", "body_rotation"):
        o, a = ours[block], ale[block]
        assert o["time_dependent_frames"] == a["time_dependent_frames"], block
        assert o["constant_frames"] == a["constant_frames"], block
        ang = quat_angle(o["quaternions"], a["quaternions"])
        assert ang.max() <= 1e-3 * ARCSEC, f"{block}: {ang.max() / ARCSEC:.3g} arcsec"
        assert matrix_angle(o["constant_rotation"], a["constant_rotation"]) <= 1e-3 * ARCSEC
        av = np.array(o["angular_velocities"]) - np.array(a["angular_velocities"])
        assert np.abs(av).max() <= 1e-12


def test_lro_interior_exact(lro_pair):
    ours, ale = lro_pair
    for key in ("focal2pixel_lines", "focal2pixel_samples", "detector_center", "optical_distortion",
                "starting_detector_line", "starting_detector_sample", "detector_line_summing",
                "detector_sample_summing", "focal_length_model", "radii", "image_lines", "image_samples",
                "name_model", "name_sensor", "name_platform", "isis_camera_version", "interpolation_method",
                "reference_height"):
        assert ours[key] == ale[key], key
    assert ours["naif_keywords"] == ale["naif_keywords"]
    assert set(ale) <= set(ours)


def test_cli_isd_writes_same_document(lro_set, tmp_path, lro_pair):
    out = tmp_path / "lro.json"
    res = subprocess.run([sys.executable, "-m", "lunarmap", "isd", str(lro_set / "M103595705LE_isis3.lbl"),
                          "--kernels", str(lro_set / "lro_nac_M103595705LE.tm"), "-o", str(out)],
                         capture_output=True, text=True, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    written = json.loads(out.read_text())
    assert written["instrument_position"]["positions"] == lro_pair[0]["instrument_position"]["positions"]
    assert [p.name for p in tmp_path.iterdir()] == ["lro.json"]  # no temporary files left


def _load(folder):
    return KernelSet.from_metakernel(folder / f"{folder.name}.tm")


def test_clementine_follows_ale_conventions(clementine_set):
    label = clementine_set / "LUA3107H.161_isis3.lbl"
    isd = image_support(label, clementine_set / "clementine_uvvis_LUA3107H161.tm").to_ale_dict()
    inst = load_label(label)["IsisCube"]["Instrument"]
    with kernels(_load(clementine_set)):
        start = spiceypy.str2et(str(inst["StartTime"]))
        center = start + float(inst["ExposureDuration"]) * 1e-3 / 2
        pos = spiceypy.spkez(-40, center, "J2000", "NONE", 301)[0]
        sun = spiceypy.spkez(10, center, "J2000", "LT+S", 301)[0]
        q_sensor = spiceypy.m2q(spiceypy.pxform("J2000", "CLEM_SC_BUS", center))
        const = spiceypy.pxform("CLEM_SC_BUS", "CLEM_UVVIS_A", center)
        q_body = spiceypy.m2q(spiceypy.pxform("J2000", "LUNAR_DE-403_PR_AXES", center))
    assert isd["name_model"] == "USGS_ASTRO_FRAME_SENSOR_MODEL"
    assert isd["center_ephemeris_time"] == pytest.approx(center, abs=1e-6)
    assert np.abs(np.array(isd["instrument_position"]["positions"][0]) - pos[:3]).max() < 1e-6
    assert np.abs(np.array(isd["sun_position"]["positions"][0]) - sun[:3]).max() < 1e-6
    assert isd["instrument_pointing"]["time_dependent_frames"] == [-40000, 1]
    assert isd["instrument_pointing"]["constant_frames"] == [-40021, -40002, -40000]
    assert quat_angle(isd["instrument_pointing"]["quaternions"][0], q_sensor) < 1e-3 * ARCSEC
    assert matrix_angle(isd["instrument_pointing"]["constant_rotation"], const) < 1e-3 * ARCSEC
    assert isd["body_rotation"]["time_dependent_frames"] == [310002, 1]
    assert isd["body_rotation"]["constant_frames"] == [310001, 310003, 310000, 310002]
    assert quat_angle(isd["body_rotation"]["quaternions"][0], q_body) < 1e-3 * ARCSEC
    assert isd["naif_keywords"]["BODY_FRAME_CODE"] == 310001
    # ISIS pixel convention -> CSM: boresight 192.5/144.5 becomes 192/144; OD_K as usgscsm radial
    assert isd["detector_center"] == {"line": 144.0, "sample": 192.0}
    assert isd["optical_distortion"] == {"radial": {"coefficients": [0.0, -2.422842e-05, 0.0]}}
    assert isd["focal2pixel_samples"] == [0.0, 43.47826087, 0.0]


def test_kaguya_follows_ale_conventions(kaguya_set):
    label = kaguya_set / "TC1S2B0_01_06691S820E0465_pds3.lbl"
    isd = image_support(label, kaguya_set / "kaguya_tc_TC1S2B0.tm").to_ale_dict()
    lab = load_label(label)
    with kernels(_load(kaguya_set)):
        start = spiceypy.sct2e(-131, float(lab["CORRECTED_SC_CLOCK_START_COUNT"]))
        dt = 6.5e-3
        stop = start + 400 * dt
        times = np.linspace(start, stop, 401)
        lt = spiceypy.spkez(301, times[7], "J2000", "LT+S", -131)[1]
        state = np.array(spiceypy.spkez(-131, times[7], "J2000", "NONE", 0)[0]) - \
            np.array(spiceypy.spkez(301, times[7] - lt + 1737.4 / 299792.458, "J2000", "NONE", 0)[0])
        q_sensor = spiceypy.m2q(spiceypy.pxform("J2000", "SELENE_M_SPACECRAFT", times[7]))
    assert isd["starting_ephemeris_time"] == pytest.approx(start, abs=1e-6)
    assert isd["center_ephemeris_time"] == pytest.approx((start + stop) / 2, abs=1e-6)
    assert len(isd["instrument_position"]["ephemeris_times"]) == 401
    assert np.abs(np.array(isd["instrument_position"]["positions"][7]) - state[:3]).max() < 1e-6
    assert isd["instrument_pointing"]["time_dependent_frames"] == [-131000, 1]
    assert isd["instrument_pointing"]["constant_frames"] == [-131350, -131320, -131000]
    assert quat_angle(isd["instrument_pointing"]["quaternions"][7], q_sensor) < 1e-3 * ARCSEC
    assert isd["body_rotation"]["time_dependent_frames"] == [10020, 1]
    assert "constant_frames" not in isd["body_rotation"]
    assert isd["starting_detector_sample"] == 0.5 and isd["starting_detector_line"] == 1.0
    assert isd["focal2pixel_lines"] == pytest.approx([0, 1 / 0.007, 0])
    assert isd["focal2pixel_samples"] == pytest.approx([0, 0, -1 / 0.007])
    assert set(isd["optical_distortion"]["kaguyalism"]) == {"x", "y", "boresight_x", "boresight_y"}
    assert isd["line_scan_rate"][0][2] == pytest.approx(dt)


def test_lro_agrees_with_isis_spiceinit_tables(lro_set, lro_pair):
    """ISIS spiceinit's tables in the cube: a second, independent peer computation.

    ISIS covers the whole 52,224-line image with the mission kernels; the sliced
    kernels here cover 0.4 s of it, so the records inside that span are compared
    with the ISD (pointing) and with lunarmap's SPICE layer at ISIS's own epochs.
    """
    from lunarmap.labels import read_isis_table
    from lunarmap.spice import queries

    cube = lro_set / "M103595705LE.cub"
    pointing, meta = read_isis_table(cube, "InstrumentPointing")
    assert list(meta["TimeDependentFrames"]) == lro_pair[1]["instrument_pointing"]["time_dependent_frames"]
    from lunarmap.errors import KernelCoverageError

    ours = lro_pair[0]["instrument_pointing"]
    t0 = ours["ephemeris_times"][0]
    with kernels(_load(lro_set)):
        inside = np.zeros(pointing["ET"].size, dtype=bool)
        for i, et in enumerate(pointing["ET"]):  # which ISIS epochs the sliced kernels cover
            try:
                queries.rotations("J2000", "LRO_LROCNACL", [et])
                inside[i] = True
            except KernelCoverageError:
                pass
        assert inside.sum() > 50
        q_isis = np.column_stack([pointing[f"J2000Q{i}"] for i in range(4)])[inside]
        m = queries.rotations("J2000", "LRO_LROCNACL", pointing["ET"][inside])
        position, _ = read_isis_table(cube, "InstrumentPosition")
        first = position["ET"][0]
        state = queries.states(-85, [first], "J2000", "NONE", 301)[0]
    from lunarmap.orientation import matrix_to_quat

    assert quat_angle(matrix_to_quat(m), q_isis).max() < 1e-3 * ARCSEC
    assert first == pytest.approx(t0, abs=1e-6)
    isis_xyz = np.array([position["J2000X"][0], position["J2000Y"][0], position["J2000Z"][0]])
    assert np.abs(state[:3] - isis_xyz).max() < 1e-6  # km: 1 mm
    assert np.abs(np.array(ours["quaternions"][0]) - q_isis[0]).max() < 1e-12 or \
        np.abs(np.array(ours["quaternions"][0]) + q_isis[0]).max() < 1e-12


def test_isis_table_errors(lro_set, tmp_path):
    from lunarmap.errors import LabelError
    from lunarmap.labels import read_isis_table

    with pytest.raises(LabelError, match="no table 'Nope'"):
        read_isis_table(lro_set / "M103595705LE.cub", "Nope")
    short = tmp_path / "short.cub"
    short.write_bytes((lro_set / "M103595705LE.cub").read_bytes()[:70000])
    with pytest.raises(LabelError, match="past the end"):
        read_isis_table(short, "InstrumentPointing")
