"""The ten kernel sets of issue 26 (shared kernel README section 8) against USGS ALE's ISD rules.

ALE's ISDs of these sets are held out of ``../shared``; the oracle here recomputes what ALE's drivers
compute, with direct spiceypy calls following the rules of README section 8 (times from the labels,
aberration corrections, frame chains), independently of lunarmap's SPICE layer and drivers. The
acceptance bounds are the issue's: times 1 microsecond, positions 1 cm, rotations 0.001 arcsec.
``pytest -s`` prints the largest differences per set (the README's table).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import pytest
import spiceypy

from lunarmap.labels import load_label
from lunarmap.orientation.drivers import image_support
from lunarmap.spice import KernelSet

from conftest import shared_set

pytestmark = pytest.mark.shared

ARCSEC = np.pi / 180 / 3600


def quat_angle(q1, q2) -> np.ndarray:
    q1, q2 = np.asarray(q1, float), np.asarray(q2, float)
    d = np.minimum(np.linalg.norm(q1 - q2, axis=-1), np.linalg.norm(q1 + q2, axis=-1))
    return 4.0 * np.arcsin(np.clip(d / 2.0, 0, 1))


def matrix_angle(m1, m2) -> float:
    r = np.asarray(m1).reshape(3, 3) @ np.asarray(m2).reshape(3, 3).T
    return float(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1)))


def _inst(lab):
    return lab["IsisCube"]["Instrument"]


def _wac(lab):
    inst = _inst(lab)
    start = spiceypy.scs2e(-85, str(inst["SpacecraftClockStartCount"])) + float(inst["ExposureDuration"]) * 1e-3 / 2
    frames = 1040 // (16 // 4)
    stop = start + frames * float(inst["InterframeDelay"]) * 1e-3
    return start, stop, np.linspace(start, stop, 1041)


def _minirf(lab):
    inst = _inst(lab)
    dt = float(inst["LineExposureDuration"])
    start = spiceypy.str2et(str(inst["StartTime"])) - dt
    stop = start + 702 * dt
    return start, stop, np.linspace(start, stop, 701)


def _ohrc(lab):
    inst = _inst(lab)
    start, stop = spiceypy.str2et(str(inst["StartTime"])), spiceypy.str2et(str(inst["StopTime"]))
    return start, stop, np.linspace(start, stop, 101)


def _tmc(lab):
    start = spiceypy.str2et(str(_inst(lab)["StartTime"]))
    stop = start + 100 * float(_inst(lab)["LineExposureDuration"]) * 1e-3
    return start, stop, np.linspace(start, stop, 101)


def _m3_isis(lab):
    start = spiceypy.scs2e(-86, str(_inst(lab)["SpacecraftClockStartCount"]))
    stop = start + 5 * 0.05088
    return start, stop, np.linspace(start, stop, 6)


def _m3_pds3(folder):
    def times(lab):
        rows = (folder / "M3T20090630T083407_V03_TIM_cropped.TAB").read_text().split("\n")
        utc = min(r.split()[1] for r in rows if r.strip())
        start = spiceypy.scs2e(-86, spiceypy.sce2s(-86, spiceypy.str2et(utc) - 0.05088 / 2))
        stop = start + 5 * 0.05088
        return start, stop, np.linspace(start, stop, 6)
    return times


def _mi(lab):
    inst = _inst(lab)
    start = spiceypy.str2et(str(inst["StartTime"]))
    stop = start + 320 * float(inst["CorrectedSamplingInterval"]) * 1e-3
    return start, stop, np.linspace(start, stop, 321)


def _lo(lab):
    t = spiceypy.str2et(str(_inst(lab)["StartTime"]))
    return t, t, np.array([t])


def _clem(lab):
    start = spiceypy.str2et(str(_inst(lab)["StartTime"]))
    stop = start + float(_inst(lab)["ExposureDuration"]) * 1e-3
    return start, stop, np.array([(start + stop) / 2])


@dataclass
class Spec:
    folder: str
    label: str
    model: str
    times: Callable | None     # label -> (start, stop, epochs)
    correction: str            # aberration correction of the sensor position (spacecraft as target)
    spacecraft: int
    pointing: str              # first time-dependent frame of the pointing ("NADIR": M3's nadir rule)
    sensor: str                # sensor frame (constant rotation pointing -> sensor)
    body: str                  # time-dependent body frame
    body_code: int             # naif_keywords.BODY_FRAME_CODE


SETS = [
    Spec("lro_wac_uv_wac0000a1c4", "wac0000a1c4.uv.even_isis3.lbl", "USGS_ASTRO_PUSH_FRAME_SENSOR_MODEL", _wac,
         "NONE", -85, "LRO_LROCWAC", "LRO_LROCWAC_UV", "MOON_PA_DE421", 31001),
    Spec("lro_minirf_03821_16N196_S1", "03821_16N196_S1_isis3.lbl", "USGS_ASTRO_SAR_SENSOR_MODEL", _minirf,
         "LT+S", -85, "LRO_SC_BUS", "LRO_MINIRF", "MOON_PA_DE421", 31001),
    Spec("chandrayaan2_ohrc_20251109T1108358871", "ch2_ohr_nrp_20251109T1108358871_d_img_d18_isis.lbl",
         "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL", _ohrc, "LT+S", -152, "CH2_ORBITER", "CH2_OHRC_ISIS", "IAU_MOON",
         10020),
    Spec("chandrayaan2_tmc2_20251220T0922071606", "ch2_tmc_ncn_20251220T0922071606_d_img_d18_isis.lbl",
         "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL", _tmc, "LT+S", -152, "CH2_ORBITER", "CH2_TMC_NADIR_ISIS",
         "IAU_MOON", 10020),
    Spec("chandrayaan1_m3_M3T20090630T083407", "M3T20090630T083407_V03_RDN_isis.lbl",
         "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL", _m3_isis, "NONE", -86, "CH1_SPACECRAFT", "CHANDRAYAAN-1_M3",
         "MOON_PA_DE421", 31001),
    Spec("chandrayaan1_m3_M3T20090630T083407", "M3T20090630T083407_V03_L1B_cropped_pds3.lbl",
         "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL", None, "NONE", -86, "NADIR", "NADIR", "MOON_PA_DE421", 31001),
    Spec("kaguya_mi_MNA_2B2_01_04192S136E3573", "MNA_2B2_01_04192S136E3573_isis3.lbl",
         "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL", _mi, "LT+S", -131, "SELENE_M_SPACECRAFT", "LISM_MI_N_HEAD",
         "MOON_PA_DE421", 31001),
    Spec("lunar_orbiter_3133_med_res", "3133_med_res_isis.lbl", "USGS_ASTRO_FRAME_SENSOR_MODEL", _lo, "NONE", -533,
         "LUNAR_ORBITER_3", "LO3_MED_RESOLUTION_CAMERA", "LUNAR_DE-403_PR_AXES", 310001),
    Spec("clementine_hires_LHA0775Q001", "LHA0775Q.001_isis3.lbl", "USGS_ASTRO_FRAME_SENSOR_MODEL", _clem, "LT+S",
         -40, "CLEM_SC_BUS", "CLEM_HIRES", "LUNAR_DE-403_PR_AXES", 310001),
    Spec("clementine_nir_LNB4653M093", "LNB4653M.093_isis3.lbl", "USGS_ASTRO_FRAME_SENSOR_MODEL", _clem, "LT+S", -40,
         "CLEM_SC_BUS", "CLEM_NIR", "LUNAR_DE-403_PR_AXES", 310001),
    Spec("clementine_lwir_LLA5391Q209", "LLA5391Q.209_isis3.lbl", "USGS_ASTRO_FRAME_SENSOR_MODEL", _clem, "LT+S", -40,
         "CLEM_SC_BUS", "CLEM_LWIR", "LUNAR_DE-403_PR_AXES", 310001),
]


def _nadir_quaternions(states: np.ndarray) -> np.ndarray:
    """ALE's nadir pointing: ``m2q(twovec(-p, 3, v, 1))`` (M3's ITRANSL[0] < ITRANSL[1])."""
    return np.array([spiceypy.m2q(spiceypy.twovec(-s[:3], 3, s[3:], 1)) for s in states])


def oracle(spec: Spec, folder, lab) -> dict:
    """What ALE computes for the set (README section 8), with direct spiceypy calls."""
    times_of = spec.times or _m3_pds3(folder)
    spiceypy.kclear()
    for path in KernelSet.from_metakernel(folder / f"{folder.name}.tm").paths:
        spiceypy.furnsh(str(path))
    try:
        start, stop, t = times_of(lab)
        ends = t[[0, -1]] if t.size > 1 else t
        states = np.array([spiceypy.spkez(spec.spacecraft, et, "J2000", spec.correction, 301)[0] for et in t])
        sun = np.array([spiceypy.spkez(10, et, "J2000", "LT+S", 301)[0] for et in ends])
        if spec.pointing == "NADIR":
            q_point = _nadir_quaternions(states)
            const = np.eye(3)
        else:
            q_point = np.array([spiceypy.m2q(spiceypy.pxform("J2000", spec.pointing, et)) for et in t])
            const = np.array(spiceypy.pxform(spec.pointing, spec.sensor, float(t[0])))
        q_body = np.array([spiceypy.m2q(spiceypy.pxform("J2000", spec.body, et)) for et in ends])
    finally:
        spiceypy.kclear()
    return {"start": start, "stop": stop, "times": t, "positions": states[:, :3], "velocities": states[:, 3:],
            "sun": sun[:, :3], "q_pointing": q_point, "constant": const, "q_body": q_body}


@pytest.fixture(scope="module", params=SETS, ids=[s.label.split(".")[0].split("_isis")[0] for s in SETS])
def pair(request):
    spec = request.param
    folder = shared_set(spec.folder)
    lab = load_label(folder / spec.label)
    ours = image_support(folder / spec.label, folder / f"{folder.name}.tm").to_ale_dict()
    return spec, ours, oracle(spec, folder, lab)


def test_new_set_matches_ale_rules(pair):
    spec, ours, ale = pair
    assert ours["name_model"] == spec.model
    dt = max(abs(ours["center_ephemeris_time"] - 0.5 * (ale["start"] + ale["stop"])),
             np.abs(np.array(ours["instrument_position"]["ephemeris_times"]) - ale["times"]).max())
    if "starting_ephemeris_time" in ours:
        dt = max(dt, abs(ours["starting_ephemeris_time"] - ale["start"]))
    if "ending_ephemeris_time" in ours:
        dt = max(dt, abs(ours["ending_ephemeris_time"] - ale["stop"]))
    pointing = ours["instrument_pointing"]
    assert np.array_equal(pointing["ephemeris_times"], ours["instrument_position"]["ephemeris_times"])
    dp = np.abs(np.array(ours["instrument_position"]["positions"]) - ale["positions"]).max() * 1e3      # m
    dv = np.abs(np.array(ours["instrument_position"]["velocities"]) - ale["velocities"]).max() * 1e3    # m/s
    ds = np.abs(np.array(ours["sun_position"]["positions"]) - ale["sun"]).max() * 1e3
    da = max(quat_angle(pointing["quaternions"], ale["q_pointing"]).max(),
             matrix_angle(pointing.get("constant_rotation", np.eye(3).ravel()), ale["constant"])) / ARCSEC
    db = quat_angle(ours["body_rotation"]["quaternions"], ale["q_body"]).max() / ARCSEC
    print(f"\n{spec.label}: {len(ale['times'])} epochs; times {dt:.2g} s, positions {dp:.2g} m, velocities "
          f"{dv:.2g} m/s, Sun {ds:.2g} m, pointing {da:.2g}\", body {db:.2g}\"")
    assert dt <= 1e-6
    assert dp <= 0.01 and ds <= 0.01 and dv <= 1e-3
    assert da <= 1e-3 and db <= 1e-3
    assert ours["naif_keywords"]["BODY_FRAME_CODE"] == spec.body_code
