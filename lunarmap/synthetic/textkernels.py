"""Contents of the synthetic mission's text kernels (LSK, SCLK, PCK, FK, IKs).

Each function returns ``(comments, sections)`` for
:func:`lunarmap.spice.writer.write_text_kernel`; nothing here touches SPICE.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from ..spice.writer import Append, KernelDate, Value
from . import ids
from .bodies import (
    EARTH_MOON_NUT_PREC_ANGLES,
    MOON_GM,
    MOON_NUT_PREC_DEC,
    MOON_NUT_PREC_PM,
    MOON_NUT_PREC_RA,
    MOON_PM,
    MOON_POLE_DEC,
    MOON_POLE_RA,
    MOON_RADIUS_KM,
    SUN_GM,
    SUN_RADIUS_KM,
)
from .cameras import CameraSpec

__all__ = ["lsk", "sclk", "pck", "fk", "ik", "LEAP_SECONDS", "SCLK_MODULI", "SCLK_ZERO_TDB"]

Sections = Sequence[tuple[str, Mapping[str, Value]]]

#: TAI-UTC (s) and the UTC date from which it holds, 1972 through 2017 (IERS Bulletin C).
LEAP_SECONDS = (
    (10, "1972-JAN-1"), (11, "1972-JUL-1"), (12, "1973-JAN-1"), (13, "1974-JAN-1"),
    (14, "1975-JAN-1"), (15, "1976-JAN-1"), (16, "1977-JAN-1"), (17, "1978-JAN-1"),
    (18, "1979-JAN-1"), (19, "1980-JAN-1"), (20, "1981-JUL-1"), (21, "1982-JUL-1"),
    (22, "1983-JUL-1"), (23, "1985-JUL-1"), (24, "1988-JAN-1"), (25, "1990-JAN-1"),
    (26, "1991-JAN-1"), (27, "1992-JUL-1"), (28, "1993-JUL-1"), (29, "1994-JUL-1"),
    (30, "1996-JAN-1"), (31, "1997-JUL-1"), (32, "1999-JAN-1"), (33, "2006-JAN-1"),
    (34, "2009-JAN-1"), (35, "2012-JUL-1"), (36, "2015-JUL-1"), (37, "2017-JAN-1"),
)

#: Clock fields: seconds (32 bit) and 1/65536 s ticks.
SCLK_MODULI = (4294967296, 65536)
#: Calendar date (TDB) at which the clock reads 1/0000000000:00000.
SCLK_ZERO_TDB = "2026-01-01T00:00:00"


def lsk() -> tuple[str, Sections]:
    """Leap-seconds kernel: the public leap-second table through 2017 and the DELTET constants."""
    delta_at: list[Any] = []
    for n, date in LEAP_SECONDS:
        delta_at += [n, KernelDate(date)]
    data: dict[str, Value] = {
        "DELTET/DELTA_T_A": 32.184,
        "DELTET/K": 1.657e-3,
        "DELTET/EB": 1.671e-2,
        "DELTET/M": [6.239996, 1.99096871e-7],
        "DELTET/DELTA_AT": delta_at,
    }
    comments = ("Leap-seconds kernel of the synthetic LUNARMAP-SIM mission, written by\n"
                "lunarmap.synthetic. TAI-UTC steps from 1972 to 2017-JAN-1 (37 s) and the\n"
                "standard constants of SPICE's TDB-TDT approximation.")
    return comments, [("", data)]


def sclk(zero_et: float) -> tuple[str, Sections]:
    """Type-1 SCLK with one partition, parallel time TDB, 65536 ticks per second.

    Parameters
    ----------
    zero_et : float
        TDB seconds past J2000 at which the clock reads zero.
    """
    n = -ids.SCLK_ID
    data: dict[str, Value] = {
        "SCLK_KERNEL_ID": [KernelDate(SCLK_ZERO_TDB.replace("T", "/"))],
        f"SCLK_DATA_TYPE_{n}": [1],
        f"SCLK01_TIME_SYSTEM_{n}": [1],
        f"SCLK01_N_FIELDS_{n}": [2],
        f"SCLK01_MODULI_{n}": list(SCLK_MODULI),
        f"SCLK01_OFFSETS_{n}": [0, 0],
        f"SCLK01_OUTPUT_DELIM_{n}": [2],
        f"SCLK_PARTITION_START_{n}": [0.0],
        f"SCLK_PARTITION_END_{n}": [float(SCLK_MODULI[0] * SCLK_MODULI[1] - 1)],
        # (encoded SCLK ticks, parallel time, seconds per most significant count)
        f"SCLK01_COEFFICIENTS_{n}": [0.0, float(zero_et), 1.0],
    }
    comments = (f"Spacecraft clock of LUNARMAP-SIM (id {ids.SCLK_ID}): one partition, fields\n"
                "seconds:ticks with 65536 ticks per second, running exactly with TDB from\n"
                f"zero at {SCLK_ZERO_TDB} TDB. Clock strings look like 1/0006912000:32768.")
    return comments, [("", data)]


def pck() -> tuple[str, Sections]:
    """Text PCK: a spherical Moon of radius 1737.4 km with the IAU rotation model, and the Sun."""
    angles = [v for pair in EARTH_MOON_NUT_PREC_ANGLES for v in pair]
    moon: dict[str, Value] = {
        "BODY3_NUT_PREC_ANGLES": angles,
        "BODY301_POLE_RA": list(MOON_POLE_RA),
        "BODY301_POLE_DEC": list(MOON_POLE_DEC),
        "BODY301_PM": list(MOON_PM),
        "BODY301_LONG_AXIS": [0.0],
        "BODY301_NUT_PREC_RA": list(MOON_NUT_PREC_RA),
        "BODY301_NUT_PREC_DEC": list(MOON_NUT_PREC_DEC),
        "BODY301_NUT_PREC_PM": list(MOON_NUT_PREC_PM),
        "BODY301_RADII": [MOON_RADIUS_KM] * 3,
        "BODY301_GM": [MOON_GM],
    }
    sun: dict[str, Value] = {"BODY10_RADII": [SUN_RADIUS_KM] * 3, "BODY10_GM": [SUN_GM]}
    comments = ("Planetary constants of the synthetic LUNARMAP-SIM mission: the Moon as a\n"
                "sphere of the IAU mean radius, rotating by the IAU/WGCCRE model (pole and\n"
                "prime meridian with the Earth-Moon nutation/precession terms E1..E13, in\n"
                "degrees and degrees per day or Julian century), as in NAIF's pck00009.")
    return comments, [("Moon (the nutation angles belong to barycentre 3).", moon), ("Sun.", sun)]


def _tk(frame_id: int, name: str, relative: str, angles_deg: Sequence[float]) -> dict[str, Value]:
    return {
        f"FRAME_{name}": frame_id,
        f"FRAME_{frame_id}_NAME": name,
        f"FRAME_{frame_id}_CLASS": 4,
        f"FRAME_{frame_id}_CLASS_ID": frame_id,
        f"FRAME_{frame_id}_CENTER": ids.SPACECRAFT_ID,
        f"TKFRAME_{frame_id}_RELATIVE": relative,
        f"TKFRAME_{frame_id}_SPEC": "ANGLES",
        f"TKFRAME_{frame_id}_UNITS": "DEGREES",
        f"TKFRAME_{frame_id}_AXES": [1, 2, 3],
        f"TKFRAME_{frame_id}_ANGLES": [float(a) for a in angles_deg],
    }


def fk(nac_angles_deg: Sequence[float], frame_angles_deg: Sequence[float]) -> tuple[str, Sections]:
    """Frames kernel: names, the CK bus frame and the two instrument TK frames.

    Parameters
    ----------
    nac_angles_deg, frame_angles_deg : sequence of 3 float
        TK ``ANGLES`` about axes (1, 2, 3) of each instrument frame relative
        to the bus, degrees (SPICE's bus-to-instrument matrix is then
        ``[-a3]_3 [-a2]_2 [-a1]_1`` in frame-rotation convention, see
        :meth:`lunarmap.synthetic.SimMission.mounting`).
    """
    names: dict[str, Value] = {
        "NAIF_BODY_NAME": Append([ids.SPACECRAFT_NAME, ids.NAC_NAME, ids.FRAME_CAMERA_NAME]),
        "NAIF_BODY_CODE": Append([ids.SPACECRAFT_ID, ids.NAC_ID, ids.FRAME_CAMERA_ID]),
    }
    b = ids.BUS_FRAME_ID
    bus: dict[str, Value] = {
        f"FRAME_{ids.BUS_FRAME}": b,
        f"FRAME_{b}_NAME": ids.BUS_FRAME,
        f"FRAME_{b}_CLASS": 3,
        f"FRAME_{b}_CLASS_ID": b,
        f"FRAME_{b}_CENTER": ids.SPACECRAFT_ID,
        f"CK_{b}_SCLK": ids.SCLK_ID,
        f"CK_{b}_SPK": ids.SPACECRAFT_ID,
    }
    comments = ("Frames of the synthetic LUNARMAP-SIM mission.\n"
                f"  {ids.BUS_FRAME} ({b}): spacecraft bus, CK frame relative to J2000; +z nadir,\n"
                "      +x roughly along the ground-track velocity (reversed while yaw-flipped).\n"
                f"  {ids.NAC_FRAME} ({ids.NAC_ID}): pushbroom camera, fixed to the bus, boresight +z,\n"
                "      detector line along +y.\n"
                f"  {ids.FRAME_CAMERA_FRAME} ({ids.FRAME_CAMERA_ID}): framing camera, fixed to the bus.\n"
                "Both instrument frames are misaligned from the bus by a few hundredths of a degree.")
    return comments, [
        ("Names and ids.", names),
        ("Spacecraft bus (CK frame).", bus),
        ("Pushbroom camera.", _tk(ids.NAC_ID, ids.NAC_FRAME, ids.BUS_FRAME, nac_angles_deg)),
        ("Framing camera.", _tk(ids.FRAME_CAMERA_ID, ids.FRAME_CAMERA_FRAME, ids.BUS_FRAME,
                                frame_angles_deg)),
    ]


def ik(cam: CameraSpec) -> tuple[str, Sections]:
    """Instrument kernel of one camera, in the style of the LRO LROC IK plus ISIS IAK keywords."""
    p = f"INS{cam.naif_id}_"
    corners = cam.fov_corners()
    geometry: dict[str, Value] = {
        p + "FOCAL_LENGTH": cam.focal_length_mm,
        p + "PIXEL_PITCH": cam.pixel_pitch_mm,
        p + "PIXEL_SIZE": [cam.pixel_pitch_mm, cam.pixel_pitch_mm],
        p + "PIXEL_SAMPLES": cam.samples,
        p + "PIXEL_LINES": cam.lines,
        p + "BORESIGHT_SAMPLE": cam.boresight_sample,
        p + "BORESIGHT_LINE": cam.boresight_line,
        p + "IFOV": cam.pixel_pitch_mm / cam.focal_length_mm,
        p + "TRANSX": list(cam.transx),
        p + "TRANSY": list(cam.transy),
        p + "ITRANSS": list(cam.itranss),
        p + "ITRANSL": list(cam.itransl),
        p + "OD_K": list(cam.od_k) if len(cam.od_k) > 1 else cam.od_k[0],
    }
    fov: dict[str, Value] = {
        p + "FOV_FRAME": cam.frame_name,
        p + "FOV_SHAPE": "RECTANGLE",
        p + "BORESIGHT": [0.0, 0.0, 1.0],
        p + "FOV_CLASS_SPEC": "CORNERS",
        p + "FOV_BOUNDARY_CORNERS": np.asarray(corners).ravel().tolist(),
    }
    lunarmap: dict[str, Value] = {
        p + ids.KW_CAMERA_TYPE: cam.camera_type,
        p + ids.KW_DISTORTION_MODEL: cam.distortion_model,
        p + ids.KW_LIGHTTIME_CORRECTION: "NONE",
        p + "CK_FRAME_ID": ids.BUS_FRAME_ID,
        p + "CK_REFERENCE_ID": 1,
        p + "PLATFORM_ID": ids.SPACECRAFT_ID,
    }
    comments = (f"Instrument kernel of {cam.name} (NAIF id {cam.naif_id}) of the synthetic\n"
                f"LUNARMAP-SIM mission: {cam.description}\n"
                "Units: FOCAL_LENGTH, PIXEL_PITCH mm; TRANSX/TRANSY mm per pixel;\n"
                "ITRANSS/ITRANSL pixels per mm; IFOV rad/pixel. BORESIGHT_SAMPLE/LINE use the ISIS\n"
                "convention (centre of the first pixel is 1.0). x = TRANSX . (1, sample - BS,\n"
                "line - BL), y likewise; OD_K are the distortion coefficients of the\n"
                f"'{cam.distortion_model}' model (mm based).")
    return comments, [("Optics and detector.", geometry), ("Field of view (for getfov).", fov),
                      ("lunarmap keywords and CK metadata.", lunarmap)]
