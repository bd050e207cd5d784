"""The Moon and the Sun of the synthetic mission: constants, rotation, ephemerides.

* The Moon's orientation is the IAU/WGCCRE model (Archinal et al. 2011, as in
  NAIF's ``pck00009.tpc``/``pck00010.tpc``) evaluated here in numpy exactly as
  SPICE evaluates a text PCK, so the mission model and the written PCK agree.
* The heliocentric ephemerides are *not* the real ones: the Sun moves on a
  small circle about the solar-system barycentre and the Moon on a 1 AU
  circle about the Sun plus a monthly circle, both in the ecliptic. They only
  have to give a plausible Sun direction and make aberration-corrected
  ``spkez`` calls work.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "MOON_RADIUS_KM", "MOON_GM", "SUN_GM", "SUN_RADIUS_KM", "SECONDS_PER_DAY", "SECONDS_PER_CENTURY",
    "MOON_POLE_RA", "MOON_POLE_DEC", "MOON_PM", "MOON_NUT_PREC_RA", "MOON_NUT_PREC_DEC",
    "MOON_NUT_PREC_PM", "EARTH_MOON_NUT_PREC_ANGLES",
    "moon_euler_angles", "j2000_to_iau_moon", "moon_spin_rate", "sun_state_ssb", "moon_state_ssb",
    "frame_rotation",
]

#: Mean radius of the Moon (IAU), km; the PCK makes the Moon this sphere.
MOON_RADIUS_KM = 1737.4
#: GM of the Moon (DE430), km^3/s^2.
MOON_GM = 4902.800066
#: GM of the Sun, km^3/s^2.
SUN_GM = 132712440041.93938
#: Radius of the Sun, km.
SUN_RADIUS_KM = 696000.0
SECONDS_PER_DAY = 86400.0
SECONDS_PER_CENTURY = 86400.0 * 36525.0

# IAU rotation constants of the Moon (degrees, degrees per Julian century or day).
MOON_POLE_RA = (269.9949, 0.0031, 0.0)
MOON_POLE_DEC = (66.5392, 0.0130, 0.0)
MOON_PM = (38.3213, 13.17635815, -1.4e-12)
MOON_NUT_PREC_RA = (-3.8787, -0.1204, 0.0700, -0.0172, 0.0, 0.0072, 0.0, 0.0, 0.0, -0.0052,
                    0.0, 0.0, 0.0043)
MOON_NUT_PREC_DEC = (1.5419, 0.0239, -0.0278, 0.0068, 0.0, -0.0029, 0.0009, 0.0, 0.0, 0.0008,
                     0.0, 0.0, -0.0009)
MOON_NUT_PREC_PM = (3.5610, 0.1208, -0.0642, 0.0158, 0.0252, -0.0066, -0.0047, -0.0046, 0.0028,
                    0.0052, 0.0040, 0.0019, -0.0044)
#: (constant deg, rate deg/century) pairs E1..E13 of the Earth-Moon system.
EARTH_MOON_NUT_PREC_ANGLES = (
    (125.045, -1935.5364525000), (250.089, -3871.0729050000), (260.008, 475263.3328725000),
    (176.625, 487269.6299850000), (357.529, 35999.0509575000), (311.589, 964468.4993100000),
    (134.963, 477198.8693250000), (276.617, 12006.3007650000), (34.226, 63863.5132425000),
    (15.134, -5806.6093575000), (119.743, 131.8406400000), (239.961, 6003.1503825000),
    (25.053, 473327.7964200000),
)

_AU_KM = 149597870.7
_OBLIQUITY_DEG = 23.4392911
# Mean motions and J2000 phases of the fictional heliocentric geometry; the
# values mimic the real Earth-Moon system so the Sun direction is plausible.
_EMB_PERIOD_DAYS = 365.256363
_EMB_LONGITUDE_J2000_DEG = 100.46
_MOON_GEO_RADIUS_KM = 379700.0  # Moon about the Earth-Moon barycentre
_MOON_GEO_PERIOD_DAYS = 27.321661
_MOON_GEO_LONGITUDE_J2000_DEG = 218.316
_SUN_WOBBLE_KM = 742000.0  # the Sun's reflex motion, roughly Jupiter's
_SUN_WOBBLE_PERIOD_DAYS = 4332.59
_SUN_WOBBLE_LONGITUDE_J2000_DEG = 214.0


def frame_rotation(angle: ArrayLike, axis: int) -> NDArray[np.float64]:
    """SPICE ``rotate``: matrices turning the *frame* by ``angle`` (rad) about ``axis`` (1, 2, 3).

    Returns an array of shape ``angle.shape + (3, 3)``; ``v_new = R @ v_old``.
    """
    a = np.asarray(angle, dtype=float)
    c, s = np.cos(a), np.sin(a)
    m = np.zeros(a.shape + (3, 3))
    i, j = {1: (1, 2), 2: (2, 0), 3: (0, 1)}[axis]
    k = axis - 1
    m[..., k, k] = 1.0
    m[..., i, i] = c
    m[..., j, j] = c
    m[..., i, j] = s
    m[..., j, i] = -s
    return m


def moon_euler_angles(et: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Pole right ascension, declination and prime meridian of the Moon.

    Parameters
    ----------
    et : array_like
        Ephemeris time, TDB seconds past J2000.

    Returns
    -------
    ra, dec, w : ndarray
        Radians, in J2000 (ICRF) as SPICE's text-PCK evaluation gives them.
    """
    et = np.asarray(et, dtype=float)
    d = et / SECONDS_PER_DAY
    t = et / SECONDS_PER_CENTURY
    ang = np.deg2rad(_angles(t))
    ra = MOON_POLE_RA[0] + MOON_POLE_RA[1] * t + MOON_POLE_RA[2] * t * t \
        + np.sum(np.asarray(MOON_NUT_PREC_RA) * np.sin(ang), axis=-1)
    dec = MOON_POLE_DEC[0] + MOON_POLE_DEC[1] * t + MOON_POLE_DEC[2] * t * t \
        + np.sum(np.asarray(MOON_NUT_PREC_DEC) * np.cos(ang), axis=-1)
    w = MOON_PM[0] + MOON_PM[1] * d + MOON_PM[2] * d * d \
        + np.sum(np.asarray(MOON_NUT_PREC_PM) * np.sin(ang), axis=-1)
    return np.deg2rad(ra), np.deg2rad(dec), np.deg2rad(np.mod(w, 360.0))


def _angles(t: NDArray[np.float64]) -> NDArray[np.float64]:
    """Nutation/precession angles E1..E13 in degrees, shape ``t.shape + (13,)``."""
    c = np.asarray(EARTH_MOON_NUT_PREC_ANGLES)
    return c[:, 0] + c[:, 1] * t[..., None]


def j2000_to_iau_moon(et: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrices from J2000 to IAU_MOON (``pxform('J2000', 'IAU_MOON', et)``).

    Parameters
    ----------
    et : array_like
        Ephemeris time, TDB seconds past J2000.

    Returns
    -------
    ndarray, shape ``et.shape + (3, 3)``
    """
    ra, dec, w = moon_euler_angles(et)
    return frame_rotation(w, 3) @ frame_rotation(np.pi / 2 - dec, 1) @ frame_rotation(np.pi / 2 + ra, 3)


def moon_spin_rate() -> float:
    """Mean rotation rate of the Moon about its pole, rad/s (the linear ``PM`` term)."""
    return float(np.deg2rad(MOON_PM[1]) / SECONDS_PER_DAY)


def _ecliptic_to_j2000(v: NDArray[np.float64]) -> NDArray[np.float64]:
    eps = np.deg2rad(_OBLIQUITY_DEG)
    c, s = np.cos(eps), np.sin(eps)
    out = np.empty_like(v)
    out[..., 0] = v[..., 0]
    out[..., 1] = c * v[..., 1] - s * v[..., 2]
    out[..., 2] = s * v[..., 1] + c * v[..., 2]
    return out


def _circle(et: NDArray[np.float64], radius_km: float, period_days: float,
            longitude_j2000_deg: float) -> NDArray[np.float64]:
    """State (km, km/s) on a circle in the ecliptic, shape ``et.shape + (6,)``."""
    n = 2.0 * np.pi / (period_days * SECONDS_PER_DAY)
    lam = np.deg2rad(longitude_j2000_deg) + n * et
    c, s = np.cos(lam), np.sin(lam)
    zero = np.zeros_like(lam)
    pos = radius_km * np.stack([c, s, zero], axis=-1)
    vel = radius_km * n * np.stack([-s, c, zero], axis=-1)
    return np.concatenate([_ecliptic_to_j2000(pos), _ecliptic_to_j2000(vel)], axis=-1)


def sun_state_ssb(et: ArrayLike) -> NDArray[np.float64]:
    """Fictional state of the Sun relative to the solar-system barycentre, J2000.

    Returns
    -------
    ndarray, shape ``et.shape + (6,)``
        Position (km) and velocity (km/s).
    """
    et = np.asarray(et, dtype=float)
    return _circle(et, _SUN_WOBBLE_KM, _SUN_WOBBLE_PERIOD_DAYS, _SUN_WOBBLE_LONGITUDE_J2000_DEG)


def moon_state_ssb(et: ArrayLike) -> NDArray[np.float64]:
    """Fictional state of the Moon relative to the solar-system barycentre, J2000.

    Sun + Earth-Moon barycentre on a 1 AU circle + the Moon on a monthly
    circle about it.

    Returns
    -------
    ndarray, shape ``et.shape + (6,)``
        Position (km) and velocity (km/s).
    """
    et = np.asarray(et, dtype=float)
    return (sun_state_ssb(et)
            + _circle(et, _AU_KM, _EMB_PERIOD_DAYS, _EMB_LONGITUDE_J2000_DEG)
            + _circle(et, _MOON_GEO_RADIUS_KM, _MOON_GEO_PERIOD_DAYS, _MOON_GEO_LONGITUDE_J2000_DEG))

