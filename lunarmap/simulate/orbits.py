"""Synthetic cameras and orbits for tests and benchmarks (pure numpy, no SPICE).

The orbit is circular and polar around a spherical Moon, in the body-fixed
frame (the body's rotation is ignored: the EO is just samples, and every
oracle here is geometric). Positions, velocities and attitudes are analytic,
so the interpolated EO is exact to far below the test tolerances.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..camera.interior import InteriorOrientation
from ..camera.pushframe import FrameletTiming, PushFrameCamera
from ..camera.shape import MOON_RADIUS
from ..orientation.exterior import ExteriorOrientation
from ..orientation.rotation import matrix_to_quat

__all__ = [
    "GM_MOON",
    "polar_orbit_eo",
    "orbit_state",
    "nadir_rotation",
    "nac_like_interior",
    "frame_interior",
    "wac_like_interior",
    "wac_like_camera",
    "NAC_LINES",
    "NAC_SAMPLES",
    "NAC_LINE_TIME",
]

#: Lunar gravitational parameter, m^3 s^-2.
GM_MOON = 4.9028e12
#: Size and line period of the NAC-like synthetic line-scan image.
NAC_LINES = 52224
NAC_SAMPLES = 5064
NAC_LINE_TIME = 0.00034


def orbit_state(t: NDArray[np.float64], lat_center: float = 0.0, lon: float = 0.0, altitude: float = 50e3,
                radius: float = MOON_RADIUS) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Positions (m) and velocities (m/s) on a circular polar orbit, northbound at ``t = 0``.

    Parameters
    ----------
    t : ndarray
        Seconds after the epoch, at which the sub-spacecraft point is
        (``lat_center``, ``lon``), degrees.
    altitude, radius : float
        Orbit altitude and body radius, metres.
    """
    t = np.asarray(t, dtype=float)
    r = radius + altitude
    w = np.sqrt(GM_MOON / r**3)
    th = np.radians(lat_center) + w * t
    lam = np.radians(lon)
    c, s = np.cos(th), np.sin(th)
    pos = r * np.stack([c * np.cos(lam), c * np.sin(lam), s], axis=-1)
    vel = r * w * np.stack([-s * np.cos(lam), -s * np.sin(lam), c], axis=-1)
    return pos, vel


def nadir_rotation(pos: NDArray[np.float64], vel: NDArray[np.float64], flip: bool = False,
                   roll_deg: float = 0.0) -> NDArray[np.float64]:
    """Sensor-to-body matrices of a nadir-pointing sensor.

    Sensor +z (boresight) points to nadir, +x along the velocity (the
    line-scan's across-line, i.e. along-track, axis), +y completes the frame.
    ``flip`` yaws the sensor by 180 degrees (reverses the scan direction);
    ``roll_deg`` rotates the sensor about its x axis (180 looks at the sky).
    """
    z = -pos / np.linalg.norm(pos, axis=-1, keepdims=True)
    x = vel - np.sum(vel * z, axis=-1, keepdims=True) * z
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    if flip:
        x = -x
    y = np.cross(z, x)
    m = np.stack([x, y, z], axis=-1)  # columns are the sensor axes in body coordinates
    if roll_deg:
        a = np.radians(roll_deg)
        roll = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])
        m = m @ roll
    return m


def polar_orbit_eo(lat_center: float = 0.0, lon: float = 30.0, altitude: float = 50e3,
                   radius: float = MOON_RADIUS, half_span: float = 12.0, step: float = 0.05,
                   flip: bool = False, roll_deg: float = 0.0, epoch: float = 3.0e8) -> ExteriorOrientation:
    """Sampled EO of a nadir-pointing sensor on a circular polar orbit.

    Parameters
    ----------
    lat_center, lon : float
        Sub-spacecraft point at ``t = 0`` (s after ``epoch``), degrees.
    altitude, radius : float
        Metres.
    half_span, step : float
        Samples every ``step`` seconds over ``[-half_span, half_span]``.
    flip, roll_deg
        See :func:`nadir_rotation`.
    epoch : float
        Ephemeris time of ``t = 0``, s past J2000.
    """
    n = int(round(2 * half_span / step)) + 1
    t = np.linspace(-half_span, half_span, n)
    pos, vel = orbit_state(t, lat_center, lon, altitude, radius)
    q = matrix_to_quat(nadir_rotation(pos, vel, flip, roll_deg))
    sun_t = np.array([t[0], t[-1]])
    sun = np.array([[1.5e11, 0.0, 0.0], [1.5e11, 1.0e6, 0.0]])
    return ExteriorOrientation(epoch=epoch, times=t, positions=pos, velocities=vel, quaternions=q,
                               sun_times=sun_t, sun_positions=sun,
                               attrs={"source": "lunarmap.simulate.orbits.polar_orbit_eo"})


def nac_like_interior(n_lines: int = NAC_LINES, n_samples: int = NAC_SAMPLES, k1: float | None = 1.81e-5,
                      detector_center_line: float = 0.5) -> InteriorOrientation:
    """An LRO NAC-like line-scan interior orientation.

    f = 699.62 mm, 7 micrometre pixels, detector lines along focal-plane x and
    samples along y (as in LRO NAC ISDs), ``lrolrocnac`` distortion ``k1``
    (``None`` for no distortion). With ``detector_center_line = 0.5`` and
    ``starting_detector_line = 0`` the detector line sits half a pixel off
    the principal point, as in the NAC ISD.
    """
    pitch = 0.007
    model = "none" if k1 is None else "lrolrocnac"
    coeffs = {} if k1 is None else {"coefficients": [k1]}
    return InteriorOrientation(
        focal_length=699.62, focal2pixel_lines=(0.0, 1.0 / pitch, 0.0),
        focal2pixel_samples=(0.0, 0.0, 1.0 / pitch), detector_center_line=detector_center_line,
        detector_center_sample=n_samples / 2.0, n_lines=n_lines, n_samples=n_samples,
        distortion_model=model, distortion_coefficients=coeffs, pixel_pitch=pitch, name="NAC-like")


def frame_interior(odk: tuple[float, float, float] | None = (0.0, -2.42e-5, 0.0)) -> InteriorOrientation:
    """A Clementine UVVIS-like 384 x 288 framing interior orientation.

    f = 89.87 mm, 23 micrometre pixels, ``radial`` distortion ``OD_K = odk``
    (``None`` for none). Samples run along focal-plane x and lines along y,
    the opposite of :func:`nac_like_interior`, so both affine layouts are
    exercised.
    """
    pitch = 0.023
    model = "none" if odk is None else "radial"
    coeffs = {} if odk is None else {"coefficients": list(odk)}
    return InteriorOrientation(
        focal_length=89.87, focal2pixel_lines=(0.0, 0.0, 1.0 / pitch),
        focal2pixel_samples=(0.0, 1.0 / pitch, 0.0), detector_center_line=144.0,
        detector_center_sample=192.0, n_lines=288, n_samples=384,
        distortion_model=model, distortion_coefficients=coeffs, pixel_pitch=pitch, name="UVVIS-like")


def wac_like_interior(framelets: int = 60) -> InteriorOrientation:
    """An LRO WAC UV filter-1-like push-frame interior (IK INS-85641, COLOR readout window), CSM pixels.

    f = 4.669 mm, 9 micrometre pixels summed 4x into 128 samples, 16-line framelets (4 image lines
    each, ``framelets`` of them), the UV's radial distortion (2.6 % at the field edge).
    """
    return InteriorOrientation(
        focal_length=4.6690884, focal2pixel_lines=(0.0, -111.1111110443480, -0.0038517843825),
        focal2pixel_samples=(0.0, -0.0038517843825, 111.1111110443480), detector_center_line=294.9784,
        detector_center_sample=513.0482, n_lines=4 * framelets, n_samples=128, starting_detector_line=244.0,
        starting_detector_sample=264.0, line_summing=4, sample_summing=4, distortion_model="radial",
        distortion_coefficients={"coefficients": [-0.0258245827515546, -4.66139483592234e-05,
                                                  -0.000144650735580122]},
        pixel_pitch=0.009, name="WAC-UV-like")


def wac_like_camera(lon: float = 30.0, lat: float = 0.0, t0: float = 0.0, framelets: int = 60,
                    delay: float = 0.9, altitude: float = 50e3) -> PushFrameCamera:
    """A nadir WAC-UV-like push-frame camera flying north on a polar orbit (:func:`polar_orbit_eo`).

    The image is centred at ``t0`` (s after the EO epoch), with ``framelets`` framelets every ``delay``
    seconds. A framelet covers 1.54 km at 50 km up, the ground track 1.61 km/s: 0.9 s makes neighbouring
    framelets overlap by ~0.1 km, as a WAC image's do; 1.0 s leaves gaps, as the WAC's even and odd
    framelet images (what ISIS and ALE adjust) do. The detector lines run south, so the framelets are
    flipped into the image.
    """
    eo = polar_orbit_eo(lat_center=lat, lon=lon, altitude=altitude, half_span=abs(t0) + framelets * delay,
                        step=0.5)
    timing = FrameletTiming(t_first=t0 - 0.5 * (framelets - 1) * delay, interframe_delay=delay,
                            framelet_height=16, exposure_duration=0.04, framelets_flipped=True)
    return PushFrameCamera(wac_like_interior(framelets), eo, None, timing)
