"""LRO NAC from its PDS3 EDR label (issue 16), against USGS ALE's ISD and the ISIS-label path.

ALE's published ISD for M103595705LE (made by ALE from the ISIS label) is the
independent oracle; the NAC-R and summed variants (no real product in the shared
data) are checked against direct spiceypy calls and against the ISIS label edited
the same way (what ``lronac2isis`` would have written).
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import spiceypy

from lunarmap.errors import KernelCoverageError, LabelError, UnknownInstrumentError
from lunarmap.labels import load_label
from lunarmap.orientation.drivers import LroNacPds3Driver, driver_for, image_support
from lunarmap.spice import KernelSet, kernels

pytestmark = pytest.mark.shared

ARCSEC = np.pi / 180 / 3600
PDS3 = "M103595705LE_pds3.lbl"
ISIS = "M103595705LE_isis3.lbl"
MK = "lro_nac_M103595705LE.tm"
TIME_BLOCKS = ("instrument_position", "instrument_pointing", "body_rotation", "sun_position")


def quat_angle(q1, q2) -> np.ndarray:
    """Rotation angle (rad) between quaternion sets, sign-insensitive."""
    q1, q2 = np.asarray(q1, float), np.asarray(q2, float)
    d = np.minimum(np.linalg.norm(q1 - q2, axis=-1), np.linalg.norm(q1 + q2, axis=-1))
    return 4.0 * np.arcsin(np.clip(d / 2.0, 0, 1))


def worst(ours: dict, ref: dict) -> dict[str, float]:
    """Largest time (s), position (mm), velocity (mm/s) and rotation (arcsec) differences."""
    out = {"time_s": max(abs(ours["starting_ephemeris_time"] - ref["starting_ephemeris_time"]),
                         abs(ours["center_ephemeris_time"] - ref["center_ephemeris_time"]))}
    for block in TIME_BLOCKS:
        t_o, t_r = np.array(ours[block]["ephemeris_times"]), np.array(ref[block]["ephemeris_times"])
        assert t_o.shape == t_r.shape, block
        out["time_s"] = max(out["time_s"], float(np.abs(t_o - t_r).max()))
    for block in ("instrument_position", "sun_position"):
        out[f"{block}_mm"] = float(np.abs(np.subtract(ours[block]["positions"], ref[block]["positions"])).max()) * 1e6
        out[f"{block}_velocity_mm_s"] = float(
            np.abs(np.subtract(ours[block]["velocities"], ref[block]["velocities"])).max()) * 1e6
    for block in ("instrument_pointing", "body_rotation"):
        assert ours[block]["time_dependent_frames"] == ref[block]["time_dependent_frames"], block
        assert ours[block]["constant_frames"] == ref[block]["constant_frames"], block
        out[f"{block}_arcsec"] = float(quat_angle(ours[block]["quaternions"], ref[block]["quaternions"]).max()) / ARCSEC
        c_o = np.reshape(ours[block]["constant_rotation"], (3, 3))
        c_r = np.reshape(ref[block]["constant_rotation"], (3, 3))
        cos = np.clip((np.trace(c_o @ c_r.T) - 1) / 2, -1, 1)
        out[f"{block}_constant_arcsec"] = float(np.arccos(cos)) / ARCSEC
    return out


def assert_within_acceptance(diff: dict[str, float]) -> None:
    """Issue 16: times <= 1 us, positions <= 1 mm, rotations <= 0.001 arcsec."""
    assert diff["time_s"] <= 1e-6, diff
    for key, value in diff.items():
        if key.endswith("_mm") or key.endswith("_mm_s"):
            assert value <= 1.0, (key, value)
        if key.endswith("_arcsec"):
            assert value <= 1e-3, (key, value)


INTERIOR = ("focal2pixel_lines", "focal2pixel_samples", "detector_center", "optical_distortion",
            "starting_detector_line", "starting_detector_sample", "detector_line_summing",
            "detector_sample_summing", "focal_length_model", "radii", "image_lines", "image_samples",
            "name_model", "name_sensor", "name_platform", "isis_camera_version", "interpolation_method",
            "reference_height", "line_scan_rate", "naif_keywords")


@pytest.fixture(scope="module")
def pds3_cli_isd(lro_set, tmp_path_factory):
    """The ISD ``lunarmap isd`` writes from the PDS3 EDR label (as a user would run it)."""
    out_dir = tmp_path_factory.mktemp("pds3_cli")
    out = out_dir / "nac_pds3.json"
    res = subprocess.run([sys.executable, "-m", "lunarmap", "isd", str(lro_set / PDS3),
                          "--kernels", str(lro_set / MK), "-o", str(out)],
                         capture_output=True, text=True, cwd=out_dir)
    assert res.returncode == 0, res.stderr
    assert [p.name for p in out_dir.iterdir()] == ["nac_pds3.json"]  # no temporary file left
    return json.loads(out.read_text())


def test_pds3_label_is_claimed_by_the_pds3_driver(lro_set):
    lab = load_label(lro_set / PDS3)
    driver = driver_for(lab, str(lro_set / PDS3))
    assert isinstance(driver, LroNacPds3Driver)
    assert (driver.nac, driver.ikid, driver.image_lines, driver.image_samples) == ("NACL", -85600, 400, 5064)


def test_pds3_isd_matches_ale_within_acceptance(pds3_cli_isd, lro_set):
    ale = json.loads((lro_set / "ale_isd.json").read_text())
    diff = worst(pds3_cli_isd, ale)
    assert_within_acceptance(diff)
    for key in INTERIOR:
        assert pds3_cli_isd[key] == ale[key], key
    assert set(ale) <= set(pds3_cli_isd)


def test_pds3_isd_equals_isis_label_isd(pds3_cli_isd, lro_set):
    isis = image_support(lro_set / ISIS, lro_set / MK).to_ale_dict()
    isis = json.loads(json.dumps(isis))  # the same float round trip as the CLI's file
    assert_within_acceptance(worst(pds3_cli_isd, isis))
    # in fact identical, apart from where the ISD came from
    assert pds3_cli_isd["lunarmap"]["driver"] == "lro_nac_pds3" and isis["lunarmap"]["driver"] == "lro_nac"
    strip = [{k: v for k, v in d.items() if k != "lunarmap"} for d in (pds3_cli_isd, isis)]
    assert strip[0] == strip[1]


def _edited(src, dst, *pairs):
    text = src.read_text()
    for old, new in pairs:
        assert old in text, old
        text = text.replace(old, new)
    dst.write_text(text)
    return dst


def test_right_camera_and_summing_follow_the_label(lro_set, tmp_path):
    """NAC-R with 2x summing: frame -85610 from FRAME_ID, summing from CROSSTRACK_SUMMING."""
    pds3 = _edited(lro_set / PDS3, tmp_path / "nacr_pds3.lbl", ("FRAME_ID                           = LEFT",
                                                               "FRAME_ID                           = RIGHT"),
                   ("CROSSTRACK_SUMMING                 = 1", "CROSSTRACK_SUMMING                 = 2"))
    isis = _edited(lro_set / ISIS, tmp_path / "nacr_isis3.lbl", ("InstrumentId                = NACL",
                                                                "InstrumentId                = NACR"),
                   ("CAMERA LEFT", "CAMERA RIGHT"), ("SpatialSumming              = 1",
                                                     "SpatialSumming              = 2"),
                   ("NaifFrameCode = -85600", "NaifFrameCode = -85610"))
    ours = image_support(pds3, lro_set / MK).to_ale_dict()
    via_isis = image_support(isis, lro_set / MK).to_ale_dict()
    assert_within_acceptance(worst(ours, via_isis))
    assert ours["name_sensor"] == via_isis["name_sensor"] == "LUNAR RECONNAISSANCE ORBITER NARROW ANGLE CAMERA RIGHT"
    assert ours["detector_line_summing"] == ours["detector_sample_summing"] == 2
    for key in INTERIOR:
        assert ours[key] == via_isis[key], key
    # independent oracle: SPICE's own NAC-R frame and IK at the ISD's epochs
    times = np.array(ours["instrument_pointing"]["ephemeris_times"])
    with kernels(KernelSet.from_metakernel(lro_set / MK)):
        q_nacr = np.array([spiceypy.m2q(spiceypy.pxform("J2000", "LRO_LROCNACR", t)) for t in times[::40]])
        boresight = spiceypy.gdpool("INS-85610_BORESIGHT_SAMPLE", 0, 1)[0]
        od_k = spiceypy.gdpool("INS-85610_OD_K", 0, 1)[0]
    assert ours["instrument_pointing"]["time_dependent_frames"][0] == -85610
    assert ours["instrument_pointing"]["constant_frames"][0] == -85610
    assert quat_angle(np.array(ours["instrument_pointing"]["quaternions"])[::40], q_nacr).max() <= 1e-3 * ARCSEC
    assert ours["detector_center"]["sample"] == boresight - 0.5
    assert ours["optical_distortion"] == {"lrolrocnac": {"coefficients": [od_k]}}


def test_time_outside_the_kernels_is_a_coverage_error(lro_set, tmp_path):
    late = _edited(lro_set / PDS3, tmp_path / "late_pds3.lbl", ("1/270649237:07208", "1/270652837:07208"))
    with pytest.raises(KernelCoverageError, match="-85"):
        image_support(late, lro_set / MK)


@pytest.mark.parametrize("pairs, error, match", [
    ((("FRAME_ID                           = LEFT", "FRAME_ID                           = WAC"),),
     UnknownInstrumentError, "FRAME_ID 'WAC'.*not the WAC"),
    ((("FRAME_ID                           = LEFT", "FRAME_ID                           = RIGHT"),
      ('PRODUCT_VERSION_ID                 = "v1.8"', 'PRODUCT_VERSION_ID                 = "v1.25"')),
     LabelError, "mirrored"),
    ((("END_OBJECT                         = IMAGE",
       "END_OBJECT                         = IMAGE\nOBJECT = IMAGE_MAP_PROJECTION\nEND_OBJECT = IMAGE_MAP_PROJECTION"),),
     LabelError, "map-projected"),
    ((("LRO:SPACECRAFT_CLOCK_PREROLL_COUNT", "LRO:SPACECRAFT_CLOCK_PREROLL_COUNTX"),),
     LabelError, "lacks keyword LRO:SPACECRAFT_CLOCK_PREROLL_COUNT"),
    ((("1.028800 <ms>", "0.0010288 <s>"),), LabelError, "line exposure duration is in 's'"),
    ((("    LINES                          = 400\n", ""),), LabelError, "lacks IMAGE/LINES"),
])
def test_bad_pds3_labels_raise_named_errors(lro_set, tmp_path, pairs, error, match):
    bad = _edited(lro_set / PDS3, tmp_path / "bad_pds3.lbl", *pairs)
    with pytest.raises(error, match=match):
        image_support(bad, lro_set / MK)


def test_kaguya_isis_label_is_refused_by_name(kaguya_set):
    label = kaguya_set / "TC1S2B0_01_06691S820E0465_isis3.lbl"
    with pytest.raises(UnknownInstrumentError, match="Kaguya TC is supported from its PDS3"):
        driver_for(load_label(label), str(label))
