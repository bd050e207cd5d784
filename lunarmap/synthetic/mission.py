"""The synthetic LUNARMAP-SIM mission: the truth model behind its kernels (:func:`build_mission`).

A fictional lunar orbiter (NAIF id -990) on a near-circular polar orbit about
50 km above a spherical Moon, nadir pointing with a slow wobble and one
yaw-flipped interval, carrying a pushbroom camera (``SIM_NAC``, like LRO
NAC-L) and a framing camera (``SIM_FRAME``, like Clementine UVVIS). The model
is plain numpy, so tests can compare what SPICE reads back from the kernels
written by :func:`lunarmap.synthetic.write_mission` with the truth at
arbitrary times.

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
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import brentq

from ..errors import InvalidInputError
from . import ids, textkernels
from .attitude import NadirAttitude
from .bodies import MOON_RADIUS_KM, frame_rotation, j2000_to_iau_moon, moon_spin_rate, moon_state_ssb, sun_state_ssb
from .cameras import FRAME_CAMERA, NAC, CameraSpec
from .orbit import KeplerOrbit

__all__ = [
    "MISSION_START_TDB", "MISSION_DURATION", "ALTITUDE_KM", "SPK_STEP", "SPK_DEGREE", "CK_STEP",
    "PLANET_STEP", "PLANET_MARGIN", "NAC_IMAGE_LINES", "FRAME_EXPOSURE_MS", "ImageTiming", "ImagePlan", "SimMission",
    "build_mission", "tdb_to_et",
]

#: roll, pitch, yaw-like triples (angles, wobble amplitudes/periods/phases)
_Vec3 = tuple[float, float, float]

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


class ImageTiming:
    """Timing of a planned image, from its ``camera``, ``lines``, ``center_et``, ``line_time``, ``exposure``."""

    camera: Any
    lines: int
    center_et: float
    line_time: float | None
    exposure: float | None

    @property
    def samples(self) -> int:
        """Image samples (the detector width)."""
        return self.camera.samples

    @property
    def duration(self) -> float:
        """Acquisition time, s."""
        if self.line_time is not None:
            return self.lines * self.line_time
        assert self.exposure is not None        # frame images have an exposure
        return float(self.exposure)

    @property
    def planned_start_et(self) -> float:
        """Planned start time (before rounding the label's UTC to milliseconds), ET."""
        return self.center_et - 0.5 * self.duration


@dataclass(frozen=True)
class ImagePlan(ImageTiming):
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
        return np.asarray(self.start_et + CK_STEP * np.arange(n + 1), dtype=np.float64)


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
    wobble_amp = cast(_Vec3, tuple(float(np.deg2rad(a)) for a in rng.uniform(0.008, 0.012, 3)))
    wobble_period = cast(_Vec3, tuple(float(p) for p in rng.uniform(1500.0, 2400.0, 3)))
    wobble_phase = cast(_Vec3, tuple(float(p) for p in rng.uniform(0.0, 2.0 * np.pi, 3)))
    signs = rng.choice([-1.0, 1.0], 6)
    mags = rng.uniform(0.01, 0.05, 6)
    nac_angles = cast(_Vec3, tuple(float(round(s * m, 6)) for s, m in zip(signs[:3], mags[:3])))
    frame_angles = cast(_Vec3, tuple(float(round(s * m, 6)) for s, m in zip(signs[3:], mags[3:])))

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
