"""A reconstructed Ranger sequence written as a SPICE kernel set, so that it loads like any mission.

:func:`write_ranger_kernels` turns a flight-parameter table (orientation by the five rotations) and a
:class:`~lunarmap.missions.ranger.RangerCamera` into

===================  ======================================================================
file                 content
===================  ======================================================================
``ranger.tls``       leap seconds (lunarmap's LSK)
``ranger.tsc``       the spacecraft clock: seconds:ticks, 65536 ticks per second, parallel
                     to TDB from an integer ET before the first photo
``ranger.tpc``       the Moon: IAU rotation model (``IAU_MOON``, the body-fixed frame of the
                     reconstruction), a sphere of the table's radius (1736.6 km)
``ranger.tf``        names and ids, the camera's CK frame
``ranger_<cam>.ti``  the camera: focal length, focal plane <-> pixel transforms, boresight in
                     the ISIS pixel convention, ``LUNARMAP_CAMERA_TYPE = 'FRAME'``, no
                     distortion (the measurements are reseau-corrected), no light time
``ranger_planets.bsp`` Sun and Moon (lunarmap's synthetic ephemerides: a plausible Sun only)
``ranger.bsp``       SPK type 13: the camera stations relative to the Moon, J2000
``ranger.bc``        CK type 3: the camera attitude relative to J2000
``<photo>.lbl``      an ISIS-like label per photo (``StartTime``, ``SpacecraftClockStartCount``)
``ranger.tm``        the meta-kernel (relative paths)
===================  ======================================================================

The photos' positions and attitudes are records of the SPK and CK at their exposure times, which
are first moved to the clock's tick (at most 7.6 us; the orientation is that of the table whatever
the time label): the clock strings in the labels then reproduce them exactly, and
``lunarmap.load_camera(label, meta_kernel)`` (the generic IK-configured driver) gives back the
flight-parameter camera to rounding. Ids are fictional (``-981`` and ``-981xxx``, next to the
synthetic mission's ``-990``). Everything is staged in a hidden folder and moved into place when
complete; a failure leaves nothing behind.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np
from numpy.typing import NDArray

from ..errors import FlightParameterError, KernelError
from ..orientation.rotation import align_quaternion_signs, matrix_to_quat
from ..spice import queries as q
from ..spice.pool import SPICE_LOCK
from ..spice.writer import (
    Append,
    CkSegment,
    KernelDate,
    SpkSegment,
    loaded_temporarily,
    write_ck,
    write_spk,
    write_text_kernel,
)
from ..synthetic import textkernels
from ..synthetic.bodies import moon_state_ssb, sun_state_ssb
from ..synthetic.labels import isis_label
from .flight_parameters import FlightParameters
from .ranger import RangerCamera

__all__ = ["RangerKernelSet", "write_ranger_kernels", "load_ranger_cameras", "RANGER_ID", "SPACECRAFT_NAME"]

#: Fictional NAIF id of the reconstructed spacecraft (and of its clock).
RANGER_ID = -981
SPACECRAFT_NAME = "RANGER 9"
_TICKS = 65536
_FILES = {"lsk": "ranger.tls", "sclk": "ranger.tsc", "pck": "ranger.tpc", "fk": "ranger.tf",
          "planets": "ranger_planets.bsp", "spk": "ranger.bsp", "ck": "ranger.bc"}


@dataclass(frozen=True)
class RangerKernelSet:
    """What :func:`write_ranger_kernels` wrote.

    Attributes
    ----------
    metakernel : Path
        Load it with :class:`~lunarmap.spice.KernelSet` or give it to :func:`lunarmap.load_camera`.
    labels : dict photo -> Path
        One ISIS-like label per photo.
    et : dict photo -> float
        The exposure times of the records (tick-aligned), TDB seconds past J2000.
    camera_id : int
        NAIF id of the camera (its IK and CK frame).
    """

    metakernel: Path
    labels: dict[str, Path]
    et: dict[str, float]
    camera_id: int


def _sclk_sections(zero_et: float) -> tuple[str, list]:
    n = -RANGER_ID
    data = {
        "SCLK_KERNEL_ID": [KernelDate("1965-01-01/00:00:00")],
        f"SCLK_DATA_TYPE_{n}": [1],
        f"SCLK01_TIME_SYSTEM_{n}": [1],
        f"SCLK01_N_FIELDS_{n}": [2],
        f"SCLK01_MODULI_{n}": [4294967296, _TICKS],
        f"SCLK01_OFFSETS_{n}": [0, 0],
        f"SCLK01_OUTPUT_DELIM_{n}": [2],
        f"SCLK_PARTITION_START_{n}": [0.0],
        f"SCLK_PARTITION_END_{n}": [float(4294967296 * _TICKS - 1)],
        f"SCLK01_COEFFICIENTS_{n}": [0.0, float(zero_et), 1.0],
    }
    comments = (f"Clock of the reconstructed {SPACECRAFT_NAME} sequence (id {RANGER_ID}), written by\n"
                "lunarmap.missions.ranger_kernels: seconds:ticks with 65536 ticks per second, parallel to\n"
                f"TDB from zero at ET {zero_et:.1f}. Not a real Ranger clock.")
    return comments, [("", data)]


def _pck_sections(radius_km: float) -> tuple[str, list]:
    comments, sections = textkernels.pck()
    out = []
    for title, data in sections:
        data = dict(data)
        if "BODY301_RADII" in data:
            data["BODY301_RADII"] = [radius_km] * 3
        out.append((title, data))
    comments = (f"The Moon of the reconstruction: IAU rotation (IAU_MOON) and a sphere of {radius_km} km\n"
                "(the lunar radius of the Ranger reductions). " + comments.split("\n", 1)[-1])
    return comments, out


def _fk_sections(camera_id: int, frame: str) -> tuple[str, list]:
    names = {"NAIF_BODY_NAME": Append([SPACECRAFT_NAME, frame]), "NAIF_BODY_CODE": Append([RANGER_ID, camera_id])}
    ck = {f"FRAME_{frame}": camera_id, f"FRAME_{camera_id}_NAME": frame, f"FRAME_{camera_id}_CLASS": 3,
          f"FRAME_{camera_id}_CLASS_ID": camera_id, f"FRAME_{camera_id}_CENTER": RANGER_ID,
          f"CK_{camera_id}_SCLK": RANGER_ID, f"CK_{camera_id}_SPK": RANGER_ID}
    comments = (f"Frames of the reconstructed {SPACECRAFT_NAME} sequence (fictional ids). {frame} ({camera_id}) is\n"
                "the camera frame itself, a CK frame relative to J2000: boresight +z, x along image samples,\n"
                "y along image lines (the photo's x right and y up are x and -y here).")
    return comments, [("Names and ids.", names), ("Camera (CK frame).", ck)]


def _ik_sections(camera_id: int, frame: str, cam: RangerCamera) -> tuple[str, list]:
    p = f"INS{camera_id}_"
    n = cam.size
    half = 0.5 * cam.format
    corners = [[half, half, cam.focal_length], [-half, half, cam.focal_length],
               [-half, -half, cam.focal_length], [half, -half, cam.focal_length]]
    data = {
        p + "FOCAL_LENGTH": float(cam.focal_length), p + "PIXEL_PITCH": float(cam.pixel),
        p + "PIXEL_SAMPLES": n, p + "PIXEL_LINES": n,
        # ISIS pixel convention (first pixel centre at 1): CSM centre n/2 + 0.5
        p + "BORESIGHT_SAMPLE": n / 2.0 + 0.5, p + "BORESIGHT_LINE": n / 2.0 + 0.5,
        p + "TRANSX": [0.0, float(cam.pixel), 0.0], p + "TRANSY": [0.0, 0.0, float(cam.pixel)],
        p + "ITRANSS": [0.0, 1.0 / cam.pixel, 0.0], p + "ITRANSL": [0.0, 0.0, 1.0 / cam.pixel],
        p + "FOV_FRAME": frame, p + "FOV_SHAPE": "RECTANGLE", p + "BORESIGHT": [0.0, 0.0, 1.0],
        p + "FOV_CLASS_SPEC": "CORNERS", p + "FOV_BOUNDARY_CORNERS": [v for c in corners for v in c],
        p + "LUNARMAP_CAMERA_TYPE": "FRAME", p + "LUNARMAP_DISTORTION": "none", p + "LIGHTTIME_CORRECTION": "NONE",
    }
    comments = (f"{cam.name} of the reconstructed {SPACECRAFT_NAME} sequence, written by lunarmap.missions:\n"
                f"focal length {cam.focal_length} mm, square image of {cam.format} mm in {n} pixels of {cam.pixel}\n"
                "mm (the photo coordinates' units), principal point at the centre, no distortion: the\n"
                "measurements are reseau-corrected. BORESIGHT_SAMPLE/LINE in the ISIS convention.")
    return comments, [("Camera.", data)]


def _metakernel(files: list[str]) -> str:
    lines = ["KPL/MK", "", "Meta-kernel of a reconstructed Ranger sequence (lunarmap.missions.ranger_kernels).",
             "Relative PATH_VALUES '.' mean this file's folder to lunarmap's KernelSet.from_metakernel.",
             "", "\\begindata", "", "   PATH_VALUES     = ( '.' )", "   PATH_SYMBOLS    = ( 'KERNELS' )", ""]
    for i, f in enumerate(files):
        head = "   KERNELS_TO_LOAD = ( " if i == 0 else " " * 22
        lines.append(f"{head}'$KERNELS/{f}'{' )' if i == len(files) - 1 else ''}")
    return "\n".join(lines + ["", "\\begintext", ""]) + "\n"


def _finite_differences(t: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
    if t.size < 2:
        return np.zeros_like(v)
    return np.gradient(v, t, axis=0)


def write_ranger_kernels(table: FlightParameters, camera: RangerCamera, folder: str | os.PathLike[str], *,
                         camera_id: int = -981002, frame_name: str = "RANGER_9_B_CAMERA",
                         exposure_ms: float = 0.0) -> RangerKernelSet:
    """Write a flight-parameter sequence as a kernel set with labels (module docstring).

    Parameters
    ----------
    table : FlightParameters
        Must carry exposure times (``et``, or ``utc`` converted with the set's leap seconds).
    camera : RangerCamera
        Interior orientation of the photos.
    folder : path-like
        Destination (created if missing; files of the same names are replaced).
    camera_id : int
        NAIF id of the camera (``-981xxx``).
    frame_name : str
        Name of its frame (at most 32 characters).
    exposure_ms : float
        Exposure duration written in the labels (the position and attitude are those of the table at
        the exposure time, the label's ``StartTime``).

    Raises
    ------
    FlightParameterError
        The table has no exposure times, or two photos share a clock tick.
    KernelError, SpiceError
        A camera id outside ``-981xxx``, or an unreadable UTC time.
    """
    if table.et is None and table.utc is None:
        raise FlightParameterError(f"flight parameters {table.source}: writing kernels needs the exposure times "
                                   "(column et or utc)")
    if int(camera_id) >= 0 or -(abs(int(camera_id)) // 1000) != RANGER_ID:
        raise KernelError(f"camera_id {camera_id} must be in the -981xxx range of the reconstructed spacecraft")
    dest = Path(folder).expanduser()
    dest.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".lunarmap-ranger-", dir=dest))
    try:
        f = {k: staging / v for k, v in _FILES.items()}
        ik_name = f"ranger_{abs(camera_id)}.ti"
        c, s = textkernels.lsk()
        write_text_kernel(f["lsk"], "LSK", s, c)
        if table.et is not None:
            et_table = table.et
        else:                                             # UTC through the set's own leap seconds
            with SPICE_LOCK, loaded_temporarily([f["lsk"]]):
                et_table = np.array([q.str2et(u) for u in table.utc])  # type: ignore[union-attr]
        order = np.argsort(et_table, kind="stable")
        zero_et = float(np.floor(et_table.min()) - 1000.0)
        ticks = np.round((et_table - zero_et) * _TICKS)
        if np.unique(ticks).size != ticks.size:
            raise FlightParameterError(f"flight parameters {table.source}: two photos share one clock tick "
                                       f"(1/{_TICKS} s)")
        et = zero_et + ticks / _TICKS                     # exact in float64 (integer + dyadic fraction)
        c, s = _sclk_sections(zero_et)
        write_text_kernel(f["sclk"], "SCLK", s, c)
        c, s = _pck_sections(table.radius / 1000.0)
        write_text_kernel(f["pck"], "PCK", s, c)
        c, s = _fk_sections(camera_id, frame_name)
        write_text_kernel(f["fk"], "FK", s, c)
        c, s = _ik_sections(camera_id, frame_name, camera)
        write_text_kernel(staging / ik_name, "IK", s, c)

        t_ord = et[order]
        margin = 3600.0
        tp = np.linspace(t_ord[0] - margin, t_ord[-1] + margin, 9)
        sun, moon = sun_state_ssb(tp), moon_state_ssb(tp)
        write_spk(f["planets"], [SpkSegment(10, 0, "J2000", tp, sun[:, :3], sun[:, 3:], "SUN (SYNTHETIC)", 7),
                                 SpkSegment(301, 0, "J2000", tp, moon[:, :3], moon[:, 3:], "MOON (SYNTHETIC)", 7)],
                  internal_name="RANGER PLANETS", comments=["Synthetic Sun and Moon ephemerides of lunarmap."])
        pos = table.positions[order] / 1000.0                 # km, body-fixed (IAU_MOON)
        rot = table.sensor_rotations()[order]                 # sensor -> body-fixed
        with SPICE_LOCK, loaded_temporarily([f["lsk"], f["pck"]]):
            xf = q.state_rotations("J2000", "IAU_MOON", t_ord)  # J2000 -> body-fixed states
            utc = [q.et2utc(float(t), "ISOC", 6) for t in t_ord]
        vel_bf = _finite_differences(t_ord, pos)
        inv = np.linalg.inv(xf)
        state = np.einsum("nij,nj->ni", inv, np.concatenate([pos, vel_bf], axis=1))
        cmat = np.transpose(rot, (0, 2, 1)) @ xf[:, :3, :3]   # J2000 -> camera
        quats = align_quaternion_signs(matrix_to_quat(cmat))
        if t_ord.size == 1:                                  # a segment needs two records: hold still for 1 s
            t_rec = np.array([t_ord[0], t_ord[0] + 1.0])
            state = np.repeat(state, 2, axis=0)
            state[:, 3:] = 0.0
            quats = np.repeat(quats, 2, axis=0)
        else:
            t_rec = t_ord
        av = np.zeros((t_rec.size, 3))                       # the camera's attitude is held between photos
        write_spk(f["spk"], [SpkSegment(RANGER_ID, 301, "J2000", t_rec, state[:, :3], state[:, 3:],
                                        "RANGER STATIONS", 3 if t_rec.size >= 2 else 1)],
                  internal_name="RANGER STATIONS", comments=["Camera stations of a flight-parameter table.",
                                                              f"Source: {table.source or 'in memory'}"])
        write_ck(f["ck"], [CkSegment(camera_id, "J2000", t_rec, quats, av, "RANGER CAMERA")],
                 time_kernels=[f["lsk"], f["sclk"]], sclk_id=RANGER_ID, internal_name="RANGER CAMERA",
                 comments=["Camera attitude of a flight-parameter table (five rotations, seeds/000)."])
        labels: dict[str, Path] = {}
        ets: dict[str, float] = {}
        for k, i in enumerate(order):
            photo = table.photo[i]
            sec, tick = divmod(int(ticks[i]), _TICKS)
            clock = f"1/{sec:010d}:{tick:05d}"
            text = isis_label(samples=camera.size, lines=camera.size, spacecraft_name=SPACECRAFT_NAME,
                              instrument_id=frame_name, start_time=utc[k], stop_time=utc[k], sclk_start=clock,
                              naif_frame_code=camera_id, exposure_ms=float(exposure_ms))
            (staging / f"{photo}.lbl").write_text(text, encoding="ascii")
            labels[photo] = dest / f"{photo}.lbl"
            ets[photo] = float(et[i])
        with SPICE_LOCK, loaded_temporarily([f["lsk"], f["sclk"]]):
            for photo, t in ets.items():
                sec, tick = divmod(int(round((t - zero_et) * _TICKS)), _TICKS)
                back = q.scs2e(RANGER_ID, f"1/{sec:010d}:{tick:05d}")
                if back != t:
                    raise KernelError(f"photo {photo}: clock string does not reproduce ET {t!r} ({back!r})")
        files = [_FILES["lsk"], _FILES["sclk"], _FILES["pck"], _FILES["fk"], ik_name, _FILES["planets"],
                 _FILES["spk"], _FILES["ck"]]
        (staging / "ranger.tm").write_text(_metakernel(files), encoding="ascii")
        for name in [*files, *[p.name for p in labels.values()], "ranger.tm"]:   # the meta-kernel last
            os.replace(staging / name, dest / name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return RangerKernelSet(dest / "ranger.tm", labels, ets, int(camera_id))


def load_ranger_cameras(kernels: RangerKernelSet) -> Mapping[str, object]:
    """The cameras of a written set, through the labels and the meta-kernel as any mission's (generic driver)."""
    from ..camera.factory import load_camera

    return {photo: load_camera(label, kernels.metakernel) for photo, label in kernels.labels.items()}
