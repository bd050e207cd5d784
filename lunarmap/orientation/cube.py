"""Image support data from an ISIS cube's ``spiceinit`` tables, without kernels, and adjusted tables back.

``spiceinit`` stores in the cube what ISIS's own camera then uses instead of the kernels:

* ``InstrumentPointing``: quaternions ``(w, x, y, z)`` J2000 -> the table's first
  ``TimeDependentFrames`` entry, angular velocities (rad/s), ``ET``; a
  ``ConstantRotation`` on to the sensor frame when the label gives one;
* ``InstrumentPosition``: the sensor relative to the target's centre, J2000, km and
  km/s (``CacheType = HermiteSpline`` after ISIS thinned it);
* ``BodyRotation``: J2000 -> body-fixed, at a few epochs with angular velocities;
* ``SunPosition``; and the ``NaifKeywords`` object: the kernel-pool values of the
  instrument (IK/IAK keywords) and, as ``CLOCK_ET_<sc>_<count>_COMPUTED``, the ET of each
  spacecraft clock count ISIS converted (the double's 8 bytes as hexadecimal, little-endian).

:func:`image_support_from_cube` lays these out as an ALE ISD and reads it with the
SPICE-free ISD reader (:mod:`lunarmap.orientation.isd_reader`), so positions are
interpolated with the Hermite spline of positions and velocities (ISIS's
``HermiteSpline`` cache) and pointing by spherical linear interpolation between records
(ISIS's cache interpolation and SPICE's CK type 3). The instrument-specific part (times,
interior orientation) follows the kernel drivers: LRO NAC-L/NAC-R from ``lronac2isis``
cubes (:mod:`lunarmap.orientation.drivers.lro`), with the start time from the cached clock
conversion and the spacecraft's flight direction from the tables (x of the velocity in
the NAC frame, as ALE's ISIS-table driver does; negated for NAC-R).

:func:`orientation_tables` turns an adjusted ISD (:func:`lunarmap.orientation.update.updated_image_support`)
into new ``InstrumentPointing`` / ``InstrumentPosition`` tables, and
:func:`write_cube_orientation` writes them into a copy of the cube (what ISIS's
``jigsaw update=yes`` does to the cube itself).
"""

from __future__ import annotations

import os
import struct
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import CubeFormatError, LabelError, MissingSpiceTablesError, UnknownInstrumentError
from ..io.cube import IsisCube, Table, copy_cube_with_tables
from ..labels import Label
from ..labels.pvl import label_int
from .exterior import ExteriorOrientation
from .isd import ImageSupport, line_scan_epochs
from .isd_reader import EPOCH_MERGE_TOLERANCE, KNOWN_BODY_FRAMES, _resample_pointing, _resample_states
from .rotation import quat_to_matrix

__all__ = ["SPICE_TABLES", "image_support_from_cube", "naif_keywords", "orientation_tables",
           "write_cube_orientation"]

#: The tables ``spiceinit`` attaches and a camera without kernels needs.
SPICE_TABLES = ("InstrumentPointing", "InstrumentPosition", "BodyRotation", "SunPosition")
_NAC = {"NACL": -85600, "NACR": -85610}
_LRO = -85


def _plain(v: Any) -> Any:
    if isinstance(v, list):
        return [_plain(x) for x in v]
    if isinstance(v, float):
        return float(v)
    if isinstance(v, str) and v.upper() in ("TRUE", "FALSE"):
        return v.upper() == "TRUE"
    return v


def naif_keywords(cube: IsisCube) -> dict[str, Any]:
    """The cube's ``NaifKeywords`` object as a plain dict (lists for sequences).

    Raises
    ------
    MissingSpiceTablesError
        The cube has no ``NaifKeywords`` object (not ``spiceinit``-ed, or by an old ISIS).
    """
    obj = cube.label.get("NaifKeywords")
    if not isinstance(obj, Label):
        raise MissingSpiceTablesError(f"ISIS cube {cube.path} has no NaifKeywords object: run spiceinit "
                                      "(ISIS >= 3.6 stores the kernel-pool values in the cube)")
    return {str(k): _plain(v) for k, v in obj.items() if not isinstance(v, Label)}


def _clock_et(naif: dict[str, Any], spacecraft: int, count: str, path: str) -> float:
    key = f"CLOCK_ET_{spacecraft}_{count}_COMPUTED"
    if key not in naif:
        raise MissingSpiceTablesError(f"ISIS cube {path}: NaifKeywords lacks {key} (the ET of clock count {count} "
                                      "that spiceinit caches); without it the image time needs the SCLK kernel")
    value = naif[key]
    text = str(value)
    if isinstance(value, int):  # a hex string of digits only, read as a number by the PVL parser
        text = text.zfill(16)
    try:
        return float(struct.unpack("<d", bytes.fromhex(text))[0])
    except ValueError as err:
        raise MissingSpiceTablesError(f"ISIS cube {path}: {key} = {value!r} is not 16 hexadecimal digits") from err


def _table(cube: IsisCube, name: str, fields: tuple[str, ...]) -> tuple[dict[str, NDArray], Label]:
    cols, meta = cube.table(name)
    missing = [f for f in fields if f not in cols]
    if missing:
        raise CubeFormatError(f"ISIS cube {cube.path}: table {name} lacks field(s) {missing} (has {sorted(cols)}); "
                              "polynomial (jigsaw) tables are not read, spiceinit's caches are")
    for f in fields:
        if np.asarray(cols[f]).ndim != 1 or not np.all(np.isfinite(cols[f])):
            raise CubeFormatError(f"ISIS cube {cube.path}: table {name} field {f} holds values that are not finite "
                                  "numbers")
    et = np.asarray(cols["ET"], float)
    if et.size == 0:
        raise CubeFormatError(f"ISIS cube {cube.path}: table {name} has no records")
    if et.size > 1 and not np.all(np.diff(et) > 0):
        k = int(np.nonzero(np.diff(et) <= 0)[0][0])
        raise CubeFormatError(f"ISIS cube {cube.path}: table {name}: epochs (ET) do not increase at record {k + 1} "
                              f"({et[k]!r} then {et[k + 1]!r})")
    return cols, meta


def _int_list(meta: Label, key: str) -> list[int]:
    v = meta.get(key)
    if v is None:
        return []
    try:
        return [label_int(x, f"{key}") for x in (v if isinstance(v, list) else [v])]
    except LabelError as err:
        raise CubeFormatError(f"table keyword {err}") from None


def _floats(meta: Label, key: str, path: str) -> list[float]:
    v = meta[key]
    try:
        out = [float(x) for x in (v if isinstance(v, list) else [v])]
    except (TypeError, ValueError):
        raise CubeFormatError(f"ISIS cube {path}: table keyword {key} {v!r:.60} is not a list of numbers") from None
    if not all(np.isfinite(out)):
        raise CubeFormatError(f"ISIS cube {path}: table keyword {key} holds values that are not finite")
    return out


def _rotation_block(cube: IsisCube, name: str) -> dict[str, Any]:
    cols, meta = _table(cube, name, ("J2000Q0", "J2000Q1", "J2000Q2", "J2000Q3", "ET"))
    blk: dict[str, Any] = {
        "time_dependent_frames": _int_list(meta, "TimeDependentFrames") or [1],
        "ephemeris_times": np.asarray(cols["ET"], float).tolist(),
        "quaternions": np.column_stack([cols[f"J2000Q{i}"] for i in range(4)]).tolist(),
        "reference_frame": 1,
    }
    if all(f"AV{i}" in cols for i in (1, 2, 3)):
        blk["angular_velocities"] = np.column_stack([cols[f"AV{i}"] for i in (1, 2, 3)]).tolist()
    if "ConstantRotation" in meta:
        blk["constant_rotation"] = _floats(meta, "ConstantRotation", cube.path)
        if len(blk["constant_rotation"]) != 9:
            raise CubeFormatError(f"ISIS cube {cube.path}: table {name}: ConstantRotation has "
                                  f"{len(blk['constant_rotation'])} values, not 9")
        blk["constant_frames"] = _int_list(meta, "ConstantFrames") or blk["time_dependent_frames"][:1]
    return blk


def _state_block(cube: IsisCube, name: str) -> dict[str, Any]:
    f = ("J2000X", "J2000Y", "J2000Z", "J2000XV", "J2000YV", "J2000ZV", "ET")
    cols, _ = _table(cube, name, f)
    return {"ephemeris_times": np.asarray(cols["ET"], float).tolist(),
            "positions": np.column_stack([cols[k] for k in f[:3]]).tolist(),
            "velocities": np.column_stack([cols[k] for k in f[3:6]]).tolist(), "reference_frame": 1}


def _image_grid(cube: IsisCube, image_size: tuple[int, int] | None) -> tuple[int, int, float, float]:
    """``(lines, samples, first line, first sample)`` of the cube in the original image (pixels, CSM)."""
    if image_size is not None:
        lines, samples = (int(v) for v in image_size)
        if lines < 1 or samples < 1:
            raise CubeFormatError(f"image_size {image_size} must be positive")
        return lines, samples, 0.0, 0.0
    _, lines, samples = cube.shape
    alpha = cube.group("AlphaCube")
    if alpha is None:
        return lines, samples, 0.0, 0.0
    try:
        s_scale = (float(alpha["AlphaEndingSample"]) - float(alpha["AlphaStartingSample"])) / float(alpha["BetaSamples"])
        l_scale = (float(alpha["AlphaEndingLine"]) - float(alpha["AlphaStartingLine"])) / float(alpha["BetaLines"])
        first_line, first_sample = float(alpha["AlphaStartingLine"]) - 0.5, float(alpha["AlphaStartingSample"]) - 0.5
    except (KeyError, TypeError, ValueError, ZeroDivisionError) as err:
        raise CubeFormatError(f"ISIS cube {cube.path}: malformed AlphaCube group ({err})") from None
    if abs(s_scale - 1.0) > 1e-9 or abs(l_scale - 1.0) > 1e-9:
        raise CubeFormatError(
            f"ISIS cube {cube.path}: its AlphaCube group describes a scaled image (x{l_scale:g} lines, "
            f"x{s_scale:g} samples); only crops are modelled. Pass image_size=(lines, samples) of the image "
            "the tables describe to ignore the AlphaCube group")
    return lines, samples, first_line, first_sample


def _lro_nac(cube: IsisCube, inst: Label, naif: dict[str, Any], pos: dict[str, Any], pointing: dict[str, Any],
             image_size: tuple[int, int] | None) -> dict[str, Any]:
    nac = str(inst.get("InstrumentId", ""))
    ikid = _NAC[nac]

    def ik(key: str, default: Any = None) -> Any:
        name = f"INS{ikid}_{key}"
        if name not in naif:
            if default is None:
                raise MissingSpiceTablesError(f"ISIS cube {cube.path}: NaifKeywords lacks {name}")
            return default
        return naif[name]

    exposure = inst.get("LineExposureDuration")
    if exposure is None:
        raise LabelError(f"ISIS cube {cube.path} lacks Instrument/LineExposureDuration")
    if str(getattr(exposure, "unit", "ms")).lower() not in ("ms", "msec", "millisecond", "milliseconds"):
        raise LabelError(f"ISIS cube {cube.path}: LineExposureDuration is in {exposure.unit!r}, expected ms")
    dt = float(exposure) * 1e-3 * (1.0 + float(ik("MULTIPLI_LINE_ERROR", 0.0))) + float(ik("ADDITIVE_LINE_ERROR", 0.0))
    count = inst.get("SpacecraftClockPrerollCount")
    if count is None:
        raise LabelError(f"ISIS cube {cube.path} lacks Instrument/SpacecraftClockPrerollCount")
    start = _clock_et(naif, _LRO, str(count), cube.path) + float(ik("CONSTANT_TIME_OFFSET", 0.0)) \
        + float(ik("ADDITIONAL_PREROLL", 0.0)) * dt
    lines, samples, first_line, first_sample = _image_grid(cube, image_size)
    start += first_line * dt
    summing = int(inst.get("SpatialSumming", 1))

    # flight direction (LRO yaws by 180 degrees twice a year): x of the velocity in the NAC frame
    t = np.asarray(pos["ephemeris_times"])
    vel = np.array([np.interp(start, t, np.asarray(pos["velocities"])[:, i]) for i in range(3)])
    tp = np.asarray(pointing["ephemeris_times"])
    q = np.asarray(pointing["quaternions"])[int(np.argmin(np.abs(tp - start)))]
    direction = float((quat_to_matrix(q) @ vel)[0]) * (-1.0 if nac == "NACR" else 1.0)
    f2l = [float(v) for v in ik("ITRANSL")]
    if direction < 0:
        f2l = [-v for v in f2l]
    center = start + lines * dt / 2.0
    return {
        "name_model": "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL",
        "name_platform": str(inst.get("SpacecraftName", "LUNAR RECONNAISSANCE ORBITER")),
        "name_sensor": str(inst.get("InstrumentName", nac)),
        "image_lines": lines, "image_samples": samples,
        "starting_ephemeris_time": start, "center_ephemeris_time": center,
        "line_scan_rate": [[0.5, start - center, dt]],
        "focal_length_model": {"focal_length": float(ik("FOCAL_LENGTH"))},
        "focal2pixel_lines": f2l, "focal2pixel_samples": [float(v) for v in ik("ITRANSS")],
        "detector_center": {"line": float(ik("BORESIGHT_LINE")), "sample": float(ik("BORESIGHT_SAMPLE")) - 0.5},
        "starting_detector_line": 0.0,
        "starting_detector_sample": float(inst.get("SampleFirstPixel", 0)) + first_sample * summing,
        "detector_line_summing": summing, "detector_sample_summing": summing,
        "optical_distortion": {"lrolrocnac": {"coefficients": [float(ik("OD_K"))]}},
        "isis_camera_version": 2,
        "_driver": "lro_nac", "_ids": {"spacecraft_id": _LRO, "target_id": int(naif.get("BODY_CODE", 301))},
    }


def image_support_from_cube(path: str | os.PathLike[str], image_size: tuple[int, int] | None = None) -> ImageSupport:
    """The image support data of a ``spiceinit``-ed ISIS cube, from its tables: no kernels, no SPICE.

    Parameters
    ----------
    path : path-like
        The cube.
    image_size : (int, int), optional
        ``(lines, samples)`` of the image the tables describe, for stand-in cubes whose core is
        not that image (ALE's 1 x 1 test cubes); the ``Dimensions`` and ``AlphaCube`` of the
        label are then not used. By default the camera describes the cube's own pixels: a
        cropped cube (``AlphaCube`` group) gets its crop's start line and first sample.

    Returns
    -------
    ImageSupport
        As a driver would sample it from the kernels; ``provenance["cube"]`` names the cube.

    Raises
    ------
    MissingSpiceTablesError
        A spiceinit table, the ``NaifKeywords`` object or a keyword of it is missing.
    UnknownInstrumentError
        The cube's instrument has no cube driver (LRO NAC only so far).
    CubeFormatError
        A truncated cube, polynomial tables, a scaled (``reduce``-d) cube.
    """
    cube = IsisCube(path)
    missing = [t for t in SPICE_TABLES if t not in cube.table_names]
    if missing:
        raise MissingSpiceTablesError(f"ISIS cube {cube.path} has no spiceinit table(s) {', '.join(missing)} "
                                      f"(tables: {cube.table_names or 'none'}); run spiceinit on it")
    naif = naif_keywords(cube)
    inst = cube.group("Instrument")
    if inst is None:
        raise LabelError(f"ISIS cube {cube.path} has no Instrument group")
    pointing = _rotation_block(cube, "InstrumentPointing")
    position = _state_block(cube, "InstrumentPosition")
    body = _rotation_block(cube, "BodyRotation")
    if "angular_velocities" not in body:
        raise CubeFormatError(f"ISIS cube {cube.path}: table BodyRotation has no angular velocities (AV1..AV3)")
    sun = _state_block(cube, "SunPosition")
    if str(inst.get("InstrumentHostId", "")) == "LRO" and str(inst.get("InstrumentId", "")) in _NAC:
        d = _lro_nac(cube, inst, naif, position, pointing, image_size)
    else:
        raise UnknownInstrumentError(
            f"no camera-from-cube driver for instrument {inst.get('InstrumentId')!r} of "
            f"{inst.get('SpacecraftName')!r} (cube {cube.path}); supported: LRO NAC-L/NAC-R (lronac2isis cubes). "
            "Use the kernels (lunarmap.load_camera) instead")
    body_code = (body.get("constant_frames") or body["time_dependent_frames"])[0]
    frame_name = naif.get(f"FRAME_{body_code}_NAME") or KNOWN_BODY_FRAMES.get(int(body_code), f"FRAME_{body_code}")
    code = int(naif.get("BODY_CODE", 301))
    radii = naif.get(f"BODY{code}_RADII")
    if not isinstance(radii, list) or len(radii) != 3:
        raise MissingSpiceTablesError(f"ISIS cube {cube.path}: NaifKeywords lacks BODY{code}_RADII")
    driver, ids = d.pop("_driver"), d.pop("_ids")
    _densify(d, position, pointing)
    d.update({
        "radii": {"semimajor": float(radii[0]), "semiminor": float(radii[2]), "unit": "km"},
        "instrument_position": position, "sun_position": sun, "instrument_pointing": pointing,
        "body_rotation": body, "naif_keywords": {k: v for k, v in naif.items()},
        "lunarmap": {"body_frame": str(frame_name), "driver": f"{driver} (ISIS spiceinit tables)",
                     "label": cube.path, "cube": cube.path, "position_correction": "table", **ids},
    })
    return ImageSupport.from_ale_dict(d, source=cube.path)


def _densify(d: dict[str, Any], position: dict[str, Any], pointing: dict[str, Any]) -> None:
    """Resample positions and pointing at the tables' epochs plus ALE's image grid (every 10th line).

    Between the table records ISIS interpolates pointing linearly (slerp) and positions with
    their Hermite spline; the exterior orientation interpolates its samples with cubic splines.
    Sampling the tables' own interpolants densely over the image makes the camera follow
    ISIS's interpolation, not a cubic spline through records tens of milliseconds apart.
    """
    lines = int(d["image_lines"])
    start = float(d["starting_ephemeris_time"])
    grid = line_scan_epochs(start, start + lines * float(d["line_scan_rate"][0][2]), lines)
    tp, tx = np.asarray(pointing["ephemeris_times"]), np.asarray(position["ephemeris_times"])
    epochs = np.union1d(tp, tx)
    k = np.searchsorted(epochs, grid).clip(1, epochs.size - 1)
    near = np.minimum(np.abs(epochs[k] - grid), np.abs(epochs[k - 1] - grid)) < EPOCH_MERGE_TOLERANCE
    epochs = np.union1d(epochs, grid[~near])
    q = np.asarray(pointing["quaternions"])
    av = np.asarray(pointing["angular_velocities"]) if "angular_velocities" in pointing else None
    if av is None:
        # a table without AV1..AV3 (a CK without rates): the resampling interpolates the quaternions
        # without them; they are only written out again (issue 28: this path imported a function that does
        # not exist, a raw ImportError found by fuzzing)
        av = np.zeros((tp.size, 3))
    q_new, w_new = _resample_pointing(tp, q, av, epochs)
    p_new, v_new = _resample_states(tx, np.asarray(position["positions"]), np.asarray(position["velocities"]), epochs)
    pointing.update(ephemeris_times=epochs.tolist(), quaternions=q_new.tolist(), angular_velocities=w_new.tolist())
    position.update(ephemeris_times=epochs.tolist(), positions=p_new.tolist(), velocities=v_new.tolist())


# -- adjusted tables back ------------------------------------------------------------------

def orientation_tables(isd: ImageSupport, original: str | os.PathLike[str] | None = None) -> list[Table]:
    """``InstrumentPointing`` and ``InstrumentPosition`` tables of an ISD (e.g. an adjusted one).

    Records are at the ISD's epochs (positions and pointing share them); the frames,
    constant rotation and descriptive keywords are the original cube's when ``original`` is given.
    """
    p = isd.pointing
    if p.times.shape != isd.times.shape or np.any(p.times != isd.times):
        raise CubeFormatError("orientation_tables: the ISD's pointing and position epochs differ")
    keep_p: list[tuple[str, Any]] = []
    keep_s: list[tuple[str, Any]] = []
    if original is not None:
        cube = IsisCube(original)
        for name, keep in (("InstrumentPointing", keep_p), ("InstrumentPosition", keep_s)):
            for t in cube.label.all("Table"):
                if str(t.get("Name")) == name:
                    keep.extend((k, v) for k, v in t.items() if k in ("Kernels", "FrameTypeCode")
                                and not isinstance(v, Label))
    t0, t1, n = float(isd.times[0]), float(isd.times[-1]), int(isd.times.size)
    pointing_kw: list[tuple[str, Any]] = [("TimeDependentFrames", list(p.time_dependent_frames))]
    if p.constant_frames[0] != p.time_dependent_frames[0] or not np.array_equal(p.constant_rotation, np.eye(3)):
        pointing_kw += [("ConstantFrames", list(p.constant_frames)),
                        ("ConstantRotation", [float(x) for x in p.constant_rotation.ravel()])]
    pointing_kw += [("CkTableStartTime", t0), ("CkTableEndTime", t1), ("CkTableOriginalSize", n),
                    *keep_p, ("Description", "Adjusted by lunarmap")]
    q, w = p.quaternions, p.angular_velocities
    pointing = Table("InstrumentPointing",
                     {"J2000Q0": q[:, 0], "J2000Q1": q[:, 1], "J2000Q2": q[:, 2], "J2000Q3": q[:, 3],
                      "AV1": w[:, 0], "AV2": w[:, 1], "AV3": w[:, 2], "ET": isd.times}, keywords=pointing_kw)
    pos, vel = isd.positions, isd.velocities
    position = Table("InstrumentPosition",
                     {"J2000X": pos[:, 0], "J2000Y": pos[:, 1], "J2000Z": pos[:, 2],
                      "J2000XV": vel[:, 0], "J2000YV": vel[:, 1], "J2000ZV": vel[:, 2], "ET": isd.times},
                     keywords=[("CacheType", "HermiteSpline"), ("SpkTableStartTime", t0), ("SpkTableEndTime", t1),
                               ("SpkTableOriginalSize", float(n)), *keep_s,
                               ("Description", "Adjusted by lunarmap")])
    return [pointing, position]


def write_cube_orientation(cube: str | os.PathLike[str], target: str | os.PathLike[str],
                           eo: ExteriorOrientation, image_size: tuple[int, int] | None = None) -> Path:
    """Write an adjusted exterior orientation into a copy of a ``spiceinit``-ed cube.

    The copy's ``InstrumentPointing`` and ``InstrumentPosition`` tables hold ``eo`` at the
    original tables' epochs (J2000, km, quaternions J2000 -> the original first time-dependent
    frame), through the cube's own body rotation; the original cube is not modified, and
    :func:`image_support_from_cube` on the copy reproduces ``eo``.

    Parameters
    ----------
    cube : path-like
        The original cube.
    target : path-like
        The copy to write (atomically; it must not be the original).
    eo : ExteriorOrientation
        Adjusted orientation (body-fixed, metres), e.g. ``result.adjusted_sensors()[name].eo``
        of a camera built with :func:`lunarmap.camera.cube.camera_from_cube`; it must cover the
        tables' epochs.
    image_size : (int, int), optional
        As for :func:`image_support_from_cube`.

    Raises
    ------
    OrientationCoverageError
        ``eo`` does not cover the tables' epochs, or is in another body frame.
    """
    from .update import updated_image_support

    isd = image_support_from_cube(cube, image_size=image_size)
    adjusted = updated_image_support(isd, eo)
    return copy_cube_with_tables(cube, target, orientation_tables(adjusted, original=cube))
