"""The synthetic LUNARMAP-SIM mission: model (:func:`build_mission`) and kernel set (:func:`write_mission`).

A fictional lunar orbiter (NAIF id -990) on a near-circular polar orbit about
50 km above a spherical Moon, nadir pointing with a slow wobble and one
yaw-flipped interval, carrying a pushbroom camera (``SIM_NAC``, like LRO
NAC-L) and a framing camera (``SIM_FRAME``, like Clementine UVVIS). The model
is plain numpy, so tests can compare what SPICE reads back from the written
kernels with the truth at arbitrary times.

Timeline (seed-independent in shape; exact times depend on the seed and are
recorded in ``mission.json``):

* coverage: 2026-03-21T00:00:00 TDB plus 7 hours (about 3.7 orbits);
* orbit 1, ascending (northbound) over the sunlit side: ``sim_nac_equator``
  centred on the equator, ``sim_frame_a`` / ``sim_frame_b`` centred near
  30 N and overlapping by about 60 %, ``sim_nac_85n`` centred at 85 N;
* orbit 2: the bus is yaw-flipped for about 0.3 orbits around the ascending
  equator crossing, where ``sim_nac_flipped`` is centred.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import spiceypy
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import brentq

from ..errors import InvalidInputError
from ..orientation.rotation import align_quaternion_signs, matrix_to_quat
from ..spice.pool import SPICE_LOCK, spice_errors
from ..spice.writer import (CkSegment, SpkSegment, loaded_temporarily, write_ck, write_spk,
                            write_text_kernel)
from . import ids, textkernels
from .attitude import NadirAttitude
from .bodies import (MOON_RADIUS_KM, frame_rotation, j2000_to_iau_moon, moon_spin_rate,
                     moon_state_ssb, sun_state_ssb)
from .cameras import FRAME_CAMERA, NAC, CameraSpec
from .labels import isis_label
from .orbit import KeplerOrbit

__all__ = [
    "MISSION_START_TDB", "MISSION_DURATION", "ALTITUDE_KM", "SPK_STEP", "CK_STEP", "PLANET_STEP",
    "NAC_IMAGE_LINES", "FRAME_EXPOSURE_MS", "ImagePlan", "SimMission", "build_mission",
    "write_mission", "load_manifest", "tdb_to_et", "metakernel_text",
]

#: Start of the kernel coverage, calendar TDB.
MISSION_START_TDB = "2026-03-21T00:00:00"
#: Length of the coverage, s (about 3.7 orbits).
MISSION_DURATION = 7.0 * 3600.0
#: Mean altitude above the 1737.4 km sphere, km.
ALTITUDE_KM = 50.0
#: Spacing of the spacecraft SPK records, s.
SPK_STEP = 10.0
#: Spacing of the Sun and Moon SPK records, s.
PLANET_STEP = 3600.0
#: Margin of the Sun/Moon SPK coverage beyond the mission, s (light time, tests).
PLANET_MARGIN = 86400.0
#: Spacing of the CK records, s. 0.1 s would make a 16 MB CK; at 0.5 s the
#: whole set is about 3.4 MB and the linear CK interpolation error stays far
#: below a nanoradian for this slowly varying attitude.
CK_STEP = 0.5
#: Hermite degree of the SPK segments (window of 4 records).
SPK_DEGREE = 7
#: Lines of each pushbroom image.
NAC_IMAGE_LINES = 52224
#: Exposure time of the framing images, ms.
FRAME_EXPOSURE_MS = 5.0
#: Fraction of the frame footprint (along track) between sim_frame_a and sim_frame_b.
_FRAME_ADVANCE = 0.4
#: Argument of latitude at the start of the coverage, rad (southern hemisphere, northbound).
_START_ARG_LAT = np.deg2rad(-60.0)
#: Angle between the sunward direction and the orbit plane's sunlit half, rad (~45 deg incidence).
_SUN_OFFSET = np.deg2rad(45.0)
#: Half-width of the yaw-flipped interval, in orbits.
_FLIP_HALF_WIDTH = 0.15

_J2000 = _dt.datetime(2000, 1, 1, 12, 0, 0)


def tdb_to_et(calendar_tdb: str) -> float:
    """ET (TDB seconds past J2000) of an ISO calendar date read as TDB; exact, no SPICE."""
    t = _dt.datetime.fromisoformat(calendar_tdb)
    delta = t - _J2000
    return float(delta.days * 86400 + delta.seconds) + delta.microseconds * 1e-6


@dataclass(frozen=True)
class ImagePlan:
    """A predefined image of the synthetic mission (planned times; see the manifest for label times).

    Parameters
    ----------
    name : str
        Image name (label file ``<name>.lbl``).
    camera : CameraSpec
        The camera.
    lines : int
        Image lines (1 detector line read out repeatedly for a pushbroom).
    center_et : float
        Planned centre time, TDB seconds past J2000.
    line_time : float or None
        Line time of a pushbroom image, s (a whole number of nanoseconds).
    exposure : float or None
        Exposure time of a frame image, s.
    target_latitude_deg : float
        Planetocentric latitude the image is centred on, degrees.
    """

    name: str
    camera: CameraSpec
    lines: int
    center_et: float
    line_time: float | None
    exposure: float | None
    target_latitude_deg: float

    @property
    def samples(self) -> int:
        """Image samples (the detector width)."""
        return self.camera.samples

    @property
    def duration(self) -> float:
        """Acquisition time, s."""
        return self.lines * self.line_time if self.line_time is not None else float(self.exposure)

    @property
    def planned_start_et(self) -> float:
        """Planned start time (before rounding the label's UTC to milliseconds), ET."""
        return self.center_et - 0.5 * self.duration


@dataclass(frozen=True)
class SimMission:
    """The complete truth model of one synthetic mission (one seed).

    Parameters
    ----------
    seed : int
        Seed of the random perturbations.
    start_et, end_et : float
        Kernel coverage of the spacecraft SPK and CK, TDB seconds past J2000.
    sclk_zero_et : float
        ET at which the spacecraft clock reads zero.
    orbit : KeplerOrbit
        Spacecraft trajectory relative to the Moon.
    attitude : NadirAttitude
        Bus attitude.
    nac_angles_deg, frame_angles_deg : tuple of 3 float
        TK frame angles (about x, y, z) of the instruments relative to the bus, degrees.
    images : tuple of ImagePlan
        The predefined images.
    """

    seed: int
    start_et: float
    end_et: float
    sclk_zero_et: float
    orbit: KeplerOrbit
    attitude: NadirAttitude
    nac_angles_deg: tuple[float, float, float]
    frame_angles_deg: tuple[float, float, float]
    images: tuple[ImagePlan, ...]

    def state(self, et: ArrayLike) -> NDArray[np.float64]:
        """Spacecraft state relative to the Moon in J2000, km and km/s, shape ``et.shape + (6,)``."""
        return self.orbit.state(et)

    def bus_matrix(self, et: ArrayLike) -> NDArray[np.float64]:
        """J2000 -> bus rotation matrices."""
        return self.attitude.matrix(et)

    def mounting(self, naif_id: int) -> NDArray[np.float64]:
        """Bus -> instrument rotation matrix of an instrument (its TK frame)."""
        angles = {ids.NAC_ID: self.nac_angles_deg, ids.FRAME_CAMERA_ID: self.frame_angles_deg}.get(naif_id)
        if angles is None:
            raise InvalidInputError(f"no instrument {naif_id} in the synthetic mission")
        a = np.deg2rad(angles)
        # What SPICE builds from TK 'ANGLES' with AXES (1, 2, 3) (checked against pxform):
        # relative -> TK frame is [-a3]_3 [-a2]_2 [-a1]_1 in frame-rotation convention,
        # i.e. the TK frame's axes are the relative frame's turned by a1, a2, a3 in turn.
        return frame_rotation(-a[2], 3) @ frame_rotation(-a[1], 2) @ frame_rotation(-a[0], 1)

    def instrument_matrix(self, naif_id: int, et: ArrayLike) -> NDArray[np.float64]:
        """J2000 -> instrument rotation matrices."""
        return self.mounting(naif_id) @ self.bus_matrix(et)

    def sub_spacecraft(self, et: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Planetocentric latitude and east longitude of the sub-spacecraft point, degrees."""
        p = np.einsum("...ij,...j->...i", j2000_to_iau_moon(et), self.state(et)[..., :3])
        lat = np.degrees(np.arcsin(p[..., 2] / np.linalg.norm(p, axis=-1)))
        lon = np.degrees(np.arctan2(p[..., 1], p[..., 0]))
        return lat, lon

    def image(self, name: str) -> ImagePlan:
        """The image plan of that name."""
        for im in self.images:
            if im.name == name:
                return im
        raise InvalidInputError(f"no image {name!r} in the synthetic mission; have {ids.IMAGE_NAMES}")

    def ground_geometry(self, et: float) -> tuple[float, float]:
        """Altitude (km) and ground-track speed over the rotating Moon (km/s) at ``et``."""
        st = self.state(np.asarray(et, float))
        r, v = st[:3], st[3:]
        pole = j2000_to_iau_moon(et)[2]
        v_ground = v - moon_spin_rate() * np.cross(pole, r)
        rn = np.linalg.norm(r)
        rhat = r / rn
        v_tan = v_ground - np.dot(v_ground, rhat) * rhat
        return float(rn - MOON_RADIUS_KM), float(np.linalg.norm(v_tan) * MOON_RADIUS_KM / rn)

    def tick_aligned(self, et: float) -> float:
        """The clock tick (1/65536 s) nearest to ``et``, as ET.

        Image start times sit on ticks so that the label's
        ``SpacecraftClockStartCount`` is exact (ticks are binary fractions,
        so the sum is exact in double precision near 8e8 s).
        """
        ticks = round((et - self.sclk_zero_et) * textkernels.SCLK_MODULI[1])
        return self.sclk_zero_et + ticks / textkernels.SCLK_MODULI[1]

    def ck_grid(self) -> NDArray[np.float64]:
        """The CK record epochs, ET."""
        n = int(round((self.end_et - self.start_et) / CK_STEP))
        return self.start_et + CK_STEP * np.arange(n + 1)


def _latitude_time(orbit: KeplerOrbit, target_deg: float, revolution: int) -> float:
    """Time of the northbound crossing of a latitude in a given revolution (1 = first)."""
    u_target = np.deg2rad(target_deg) + 2.0 * np.pi * (revolution - 1)
    guess = orbit.epoch + (u_target - _START_ARG_LAT) / orbit.mean_motion

    def f(t: float) -> float:
        p = j2000_to_iau_moon(t) @ orbit.state(np.asarray(t))[:3]
        return float(np.degrees(np.arcsin(p[2] / np.linalg.norm(p))) - target_deg)

    # +-100 s is +-5 deg of argument of latitude: one crossing, even at 85 deg
    return float(brentq(f, guess - 100.0, guess + 100.0, xtol=1e-7, rtol=1e-15))


def build_mission(seed: int = 0) -> SimMission:
    """The truth model of the synthetic mission for a seed (no files, no SPICE).

    Parameters
    ----------
    seed : int
        Seed of the random perturbations (eccentricity, apsidal drift, node
        offset, wobble, instrument misalignments).

    Returns
    -------
    SimMission
    """
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InvalidInputError(f"seed must be a non-negative integer, got {seed!r}")
    rng = np.random.default_rng(int(seed))
    ecc = float(rng.uniform(0.001, 0.002))
    periapsis = float(rng.uniform(0.0, 2.0 * np.pi))
    periapsis_rate = float(np.deg2rad(rng.uniform(-3.0, 3.0)) / 86400.0)
    node_jitter = float(np.deg2rad(rng.uniform(-2.0, 2.0)))
    wobble_amp = tuple(float(np.deg2rad(a)) for a in rng.uniform(0.008, 0.012, 3))
    wobble_period = tuple(float(p) for p in rng.uniform(1500.0, 2400.0, 3))
    wobble_phase = tuple(float(p) for p in rng.uniform(0.0, 2.0 * np.pi, 3))
    signs = rng.choice([-1.0, 1.0], 6)
    mags = rng.uniform(0.01, 0.05, 6)
    nac_angles = tuple(float(round(s * m, 6)) for s, m in zip(signs[:3], mags[:3]))
    frame_angles = tuple(float(round(s * m, 6)) for s, m in zip(signs[3:], mags[3:]))

    start = tdb_to_et(MISSION_START_TDB)
    end = start + MISSION_DURATION

    # Put the northbound (sunlit) half of the polar orbit 45 degrees from the
    # subsolar meridian, so images have moderate solar incidence.
    probe = KeplerOrbit(start, MOON_RADIUS_KM + ALTITUDE_KM, 0.0, np.pi / 2, 0.0, 0.0, 0.0, 0.0)
    sun_dir = probe.moon_equator_to_j2000.T @ (sun_state_ssb(start)[:3] - moon_state_ssb(start)[:3])
    node = float(np.mod(np.arctan2(sun_dir[1], sun_dir[0]) + _SUN_OFFSET + node_jitter, 2.0 * np.pi))
    orbit = KeplerOrbit(
        epoch=start, semi_major_axis=MOON_RADIUS_KM + ALTITUDE_KM, eccentricity=ecc,
        inclination=np.pi / 2, node=node, periapsis=periapsis, periapsis_rate=periapsis_rate,
        mean_anomaly=KeplerOrbit.mean_anomaly_for(_START_ARG_LAT - periapsis, ecc),
    )

    # the flip interval starts and ends on CK record epochs, so each CK segment
    # begins and ends exactly at a boundary
    t_eq2 = _latitude_time(orbit, 0.0, 2)
    half = _FLIP_HALF_WIDTH * orbit.period
    flip_start = start + CK_STEP * round((t_eq2 - half - start) / CK_STEP)
    flip_end = start + CK_STEP * round((t_eq2 + half - start) / CK_STEP)
    attitude = NadirAttitude(orbit, wobble_amp, wobble_period, wobble_phase, flip_start, flip_end)

    mission = SimMission(seed=int(seed), start_et=start, end_et=end,
                         sclk_zero_et=tdb_to_et(textkernels.SCLK_ZERO_TDB), orbit=orbit,
                         attitude=attitude, nac_angles_deg=nac_angles, frame_angles_deg=frame_angles,
                         images=())
    images = []
    for name, lat, rev in (("sim_nac_equator", 0.0, 1), ("sim_nac_flipped", 0.0, 2), ("sim_nac_85n", 85.0, 1)):
        tc = _latitude_time(orbit, lat, rev)
        alt, speed = mission.ground_geometry(tc)
        # square ground pixels: one line per pixel's ground size; whole nanoseconds
        line_time = round(alt * NAC.ifov / speed, 9)
        images.append(ImagePlan(name, NAC, NAC_IMAGE_LINES, tc, line_time, None, lat))
    tc = _latitude_time(orbit, 30.0, 1)
    alt, speed = mission.ground_geometry(tc)
    step = round(_FRAME_ADVANCE * FRAME_CAMERA.samples * alt * FRAME_CAMERA.ifov / speed, 3)
    for name, t in (("sim_frame_a", tc - step / 2), ("sim_frame_b", tc + step / 2)):
        images.append(ImagePlan(name, FRAME_CAMERA, FRAME_CAMERA.lines, t, None,
                                FRAME_EXPOSURE_MS / 1000.0, 30.0))
    return dataclasses.replace(mission, images=tuple(images))


# ----------------------------------------------------------------------------- writing

def metakernel_text() -> str:
    """The meta-kernel of the written set (the text of ``kernels_meta/synthetic_mission.tm``)."""
    lines = [
        "KPL/MK",
        "",
        "Meta-kernel of the synthetic LUNARMAP-SIM mission written by",
        "lunarmap.synthetic.write_mission. It lives next to the kernels; the",
        "relative PATH_VALUES '.' means this file's folder to lunarmap's",
        "KernelSet.from_metakernel (for plain furnsh, run from this folder).",
        "",
        "\\begindata",
        "",
        "   PATH_VALUES     = ( '.' )",
        "   PATH_SYMBOLS    = ( 'KERNELS' )",
        "",
    ]
    for i, f in enumerate(ids.KERNEL_FILES):
        head = "   KERNELS_TO_LOAD = ( " if i == 0 else " " * 22
        tail = " )" if i == len(ids.KERNEL_FILES) - 1 else ""
        lines.append(f"{head}'$KERNELS/{f}'{tail}")
    lines += ["", "\\begintext", ""]
    return "\n".join(lines) + "\n"


def _template_path() -> Path:
    return Path(__file__).resolve().parents[2] / "kernels_meta" / ids.METAKERNEL_NAME


def _metakernel_source() -> str:
    """The template from the source tree if present (editable install), else the built-in text."""
    p = _template_path()
    return p.read_text(encoding="ascii") if p.is_file() else metakernel_text()


def _binary_comments(mission: SimMission, what: str) -> list[str]:
    return [f"{what} of the synthetic LUNARMAP-SIM mission (fictional; not real data).",
            f"Written by lunarmap.synthetic.write_mission, seed {mission.seed}."]


def _write_kernels(mission: SimMission, d: Path) -> None:
    """All kernels of the set into folder ``d``."""
    lsk, sclk, pck, fk, nac_ik, frame_ik = (d / f for f in ids.KERNEL_FILES[:6])
    planets, orbit_spk, ck = (d / f for f in ids.KERNEL_FILES[6:])
    write_text_kernel(lsk, "LSK", textkernels.lsk()[1], textkernels.lsk()[0])
    c, s = textkernels.sclk(mission.sclk_zero_et)
    write_text_kernel(sclk, "SCLK", s, c)
    c, s = textkernels.pck()
    write_text_kernel(pck, "PCK", s, c)
    c, s = textkernels.fk(mission.nac_angles_deg, mission.frame_angles_deg)
    write_text_kernel(fk, "FK", s, c)
    for cam, path in ((NAC, nac_ik), (FRAME_CAMERA, frame_ik)):
        c, s = textkernels.ik(cam)
        write_text_kernel(path, "IK", s, c)

    n_planet = int(round((mission.end_et - mission.start_et + 2 * PLANET_MARGIN) / PLANET_STEP))
    tp = mission.start_et - PLANET_MARGIN + PLANET_STEP * np.arange(n_planet + 1)
    sun, moon = sun_state_ssb(tp), moon_state_ssb(tp)
    write_spk(planets, [
        SpkSegment(ids.SUN_ID, ids.SSB_ID, "J2000", tp, sun[:, :3], sun[:, 3:], "SIM SUN", SPK_DEGREE),
        SpkSegment(ids.MOON_ID, ids.SSB_ID, "J2000", tp, moon[:, :3], moon[:, 3:], "SIM MOON", SPK_DEGREE),
    ], internal_name="LUNARMAP-SIM PLANETS", comments=_binary_comments(mission, "Sun and Moon SPK"))

    n_sc = int(round((mission.end_et - mission.start_et) / SPK_STEP))
    ts = mission.start_et + SPK_STEP * np.arange(n_sc + 1)
    st = mission.state(ts)
    write_spk(orbit_spk, [SpkSegment(ids.SPACECRAFT_ID, ids.MOON_ID, "J2000", ts, st[:, :3], st[:, 3:],
                                     "LUNARMAP-SIM ORBIT", SPK_DEGREE)],
              internal_name="LUNARMAP-SIM ORBIT", comments=_binary_comments(mission, "Spacecraft SPK"))

    att = mission.attitude
    grid = mission.ck_grid()
    segments = []
    pieces = ((mission.start_et, att.flip_start, False, "SIM BUS NOMINAL 1"),
              (att.flip_start, att.flip_end, True, "SIM BUS YAW FLIPPED"),
              (att.flip_end, mission.end_et, False, "SIM BUS NOMINAL 2"))
    for t0, t1, flipped, segid in pieces:
        t = grid[(grid >= t0 - 1e-6) & (grid <= t1 + 1e-6)]
        # both end records belong to this segment's attitude; where two
        # segments share an epoch the later one (the next interval) wins
        q = _aligned_quats(att.matrix(t, flipped=np.full(t.shape, flipped)))
        segments.append(CkSegment(ids.BUS_FRAME_ID, "J2000", t, q, att.angular_velocity(t), segid))
    write_ck(ck, segments, time_kernels=[lsk, sclk], sclk_id=ids.SCLK_ID,
             internal_name="LUNARMAP-SIM BUS", comments=_binary_comments(mission, "Bus attitude CK"))


def _aligned_quats(m: NDArray[np.float64]) -> NDArray[np.float64]:
    return align_quaternion_signs(matrix_to_quat(m))


def _image_records(mission: SimMission, d: Path) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    """Write the labels (times via SPICE, LSK and SCLK loaded temporarily).

    Returns the manifest's image entries, coverage and yaw-flip interval.
    """
    out: dict[str, dict[str, Any]] = {}
    lsk, sclk = d / ids.KERNEL_FILES[0], d / ids.KERNEL_FILES[1]
    with SPICE_LOCK, loaded_temporarily([lsk, sclk]), spice_errors("synthetic image times"):
        for im in mission.images:
            start_et = mission.tick_aligned(im.planned_start_et)
            sclk_start = spiceypy.sce2s(ids.SCLK_ID, start_et)
            if abs(spiceypy.scs2e(ids.SCLK_ID, sclk_start) - start_et) > 1e-7:
                raise RuntimeError(f"{im.name}: clock string {sclk_start} does not reproduce ET {start_et}")
            # microseconds: StartTime is within 0.5 us of the exact clock count
            start_utc = spiceypy.et2utc(start_et, "ISOC", 6)
            stop_et = start_et + im.duration
            stop_utc = spiceypy.et2utc(stop_et, "ISOC", 6)
            center = start_et + 0.5 * im.duration
            lat, lon = mission.sub_spacecraft(np.asarray(center))
            flipped = bool(mission.attitude.flipped(np.asarray(center)))
            rec: dict[str, Any] = {
                "label": f"{im.name}.lbl",
                "instrument": im.camera.name,
                "instrument_id": im.camera.naif_id,
                "frame": im.camera.frame_name,
                "camera_type": im.camera.camera_type,
                "samples": im.samples,
                "lines": im.lines,
                "start_time_utc": start_utc,
                # exact: the clock count's ET (StartTime is rounded to the microsecond)
                "start_et": start_et,
                "center_et": center,
                "stop_et": stop_et,
                "sclk_start": sclk_start,
                "target_latitude_deg": im.target_latitude_deg,
                "sub_spacecraft_latitude_deg": float(lat),
                "sub_spacecraft_longitude_deg": float(lon),
                "yaw_flipped": flipped,
                # sign of the velocity along bus +x (ISIS/ALE "spacecraft direction" for LRO NAC)
                "spacecraft_direction": -1 if flipped else 1,
            }
            if im.line_time is not None:
                line_ms = round(im.line_time * 1000.0, 6)
                rec["line_time_ms"] = line_ms
                rec["line_time_s"] = line_ms / 1000.0
                label = isis_label(samples=im.samples, lines=im.lines, spacecraft_name=ids.SPACECRAFT_NAME,
                                   instrument_id=im.camera.name, start_time=start_utc, stop_time=stop_utc,
                                   sclk_start=sclk_start, naif_frame_code=im.camera.naif_id,
                                   line_time_ms=line_ms)
            else:
                rec["exposure_ms"] = float(im.exposure) * 1000.0
                rec["exposure_s"] = float(im.exposure)
                label = isis_label(samples=im.samples, lines=im.lines, spacecraft_name=ids.SPACECRAFT_NAME,
                                   instrument_id=im.camera.name, start_time=start_utc, stop_time=stop_utc,
                                   sclk_start=sclk_start, naif_frame_code=im.camera.naif_id,
                                   exposure_ms=float(im.exposure) * 1000.0)
            (d / rec["label"]).write_text(label, encoding="ascii")
            out[im.name] = rec
        cover = {"start_et": mission.start_et, "end_et": mission.end_et,
                 "start_utc": spiceypy.et2utc(mission.start_et, "ISOC", 3),
                 "end_utc": spiceypy.et2utc(mission.end_et, "ISOC", 3)}
        flip = {"start_et": mission.attitude.flip_start, "end_et": mission.attitude.flip_end,
                "start_utc": spiceypy.et2utc(mission.attitude.flip_start, "ISOC", 3),
                "end_utc": spiceypy.et2utc(mission.attitude.flip_end, "ISOC", 3)}
    return out, cover, flip


def _manifest(mission: SimMission, images: dict[str, Any], cover: dict[str, Any],
              flip: dict[str, Any]) -> dict[str, Any]:
    o = mission.orbit
    cams = {}
    for cam, angles in ((NAC, mission.nac_angles_deg), (FRAME_CAMERA, mission.frame_angles_deg)):
        cams[cam.name] = {"id": cam.naif_id, "frame": cam.frame_name, "camera_type": cam.camera_type,
                          "distortion_model": cam.distortion_model, "samples": cam.samples,
                          "detector_lines": cam.lines, "focal_length_mm": cam.focal_length_mm,
                          "pixel_pitch_mm": cam.pixel_pitch_mm, "mounting_angles_deg": list(angles),
                          "ik": ids.KERNEL_FILES[4] if cam is NAC else ids.KERNEL_FILES[5]}
    return {
        "mission": ids.SPACECRAFT_NAME,
        "description": "fictional lunar orbiter written by lunarmap.synthetic (not real data)",
        "seed": mission.seed,
        "spacecraft": {"name": ids.SPACECRAFT_NAME, "id": ids.SPACECRAFT_ID, "sclk_id": ids.SCLK_ID},
        "target": {"name": "MOON", "id": ids.MOON_ID, "frame": ids.MOON_FRAME, "radius_km": MOON_RADIUS_KM},
        "frames": {
            ids.BUS_FRAME: {"id": ids.BUS_FRAME_ID, "class": "CK", "relative_to": ids.INERTIAL_FRAME},
            ids.NAC_FRAME: {"id": ids.NAC_ID, "class": "TK", "relative_to": ids.BUS_FRAME},
            ids.FRAME_CAMERA_FRAME: {"id": ids.FRAME_CAMERA_ID, "class": "TK", "relative_to": ids.BUS_FRAME},
        },
        "instruments": cams,
        "coverage": cover,
        "yaw_flip": flip,
        "orbit": {"epoch_et": o.epoch, "semi_major_axis_km": o.semi_major_axis,
                  "eccentricity": o.eccentricity, "inclination_deg": float(np.degrees(o.inclination)),
                  "node_deg": float(np.degrees(o.node)), "periapsis_deg": float(np.degrees(o.periapsis)),
                  "periapsis_rate_deg_per_day": float(np.degrees(o.periapsis_rate) * 86400.0),
                  "period_s": o.period, "frame": "Moon equator of the epoch (IAU pole), inertial"},
        "sampling": {"spk_step_s": SPK_STEP, "spk_degree": SPK_DEGREE, "ck_step_s": CK_STEP,
                     "planet_step_s": PLANET_STEP},
        "images": images,
        "kernels": list(ids.KERNEL_FILES),
        "metakernel": ids.METAKERNEL_NAME,
    }


def write_mission(folder: str | os.PathLike[str], *, seed: int = 0) -> Path:
    """Write the synthetic mission's kernel set, image labels and manifest into a folder.

    Everything is written into a hidden staging folder inside ``folder`` and
    moved into place only when complete (the meta-kernel last), so a failure
    leaves no partial set behind. Existing files of the same names are replaced.

    Parameters
    ----------
    folder : path-like
        Destination (created if missing).
    seed : int
        Seed of the random perturbations; the same seed gives byte-identical
        text kernels, labels and manifest and binary kernels with identical content.

    Returns
    -------
    pathlib.Path
        The meta-kernel ``synthetic_mission.tm``; load it with
        ``KernelSet.from_metakernel``.
    """
    mission = build_mission(seed)
    dest = Path(folder).expanduser()
    dest.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".lunarmap-sim-", dir=dest))
    try:
        _write_kernels(mission, staging)
        manifest = _manifest(mission, *_image_records(mission, staging))
        (staging / ids.MANIFEST_NAME).write_text(json.dumps(manifest, indent=2) + "\n", encoding="ascii")
        (staging / ids.METAKERNEL_NAME).write_text(_metakernel_source(), encoding="ascii")
        names = [*ids.KERNEL_FILES, *(f"{n}.lbl" for n in ids.IMAGE_NAMES), ids.MANIFEST_NAME,
                 ids.METAKERNEL_NAME]
        for name in names:
            os.replace(staging / name, dest / name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return dest / ids.METAKERNEL_NAME


def load_manifest(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read ``mission.json`` given its path, the meta-kernel's path or their folder."""
    p = Path(path)
    if p.is_dir():
        p = p / ids.MANIFEST_NAME
    elif p.suffix == ".tm":
        p = p.with_name(ids.MANIFEST_NAME)
    return json.loads(p.read_text(encoding="ascii"))
