"""Synthetic stereo geometry: cameras on neighbouring polar orbits looking at one ground point.

Two images with convergence angle ``c`` are taken from orbits placed
symmetrically east and west of the target, each rolled across track so that
the image centre sees the target: the pair has equal emission angles ``c/2``
on opposite sides of nadir, the set-up of the LROC study's simulation
(seeds/001, section 3.4). Pure numpy (no SPICE), built on
:mod:`lunarmap.simulate.orbits`.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from ..camera import FrameCamera, LineScanCamera, Shape
from ..camera.interior import InteriorOrientation
from ..camera.shape import MOON_RADIUS
from ..errors import InvalidInputError
from .orbits import NAC_LINE_TIME, frame_interior, nac_like_interior, polar_orbit_eo

__all__ = ["look_angle_for_emission", "pointed_camera", "stereo_pair"]


def look_angle_for_emission(emission_deg: float, altitude: float, radius: float = MOON_RADIUS) -> float:
    """Off-nadir look angle (degrees) at the spacecraft giving an emission angle (degrees) at the ground.

    Sine rule in the triangle body centre / spacecraft / ground point:
    ``sin(look) = R / (R + H) * sin(emission)``.
    """
    return float(np.degrees(np.arcsin(radius / (radius + altitude) * np.sin(np.radians(emission_deg)))))


def pointed_camera(kind: Literal["linescan", "frame"], lon0: float, lat0: float, emission_deg: float,
                   altitude: float = 50e3, interior: InteriorOrientation | None = None,
                   n_lines: int = 512, n_samples: int = 512, line_time: float = NAC_LINE_TIME,
                   shape: Shape | None = None) -> FrameCamera | LineScanCamera:
    """A camera whose image centre sees (``lon0``, ``lat0``) at height 0 with a given signed emission angle.

    Parameters
    ----------
    kind : {"linescan", "frame"}
        NAC-like line scanner (``n_lines`` x ``n_samples``, 0.5 m pixels at
        50 km) or Clementine UVVIS-like frame camera (384 x 288).
    lon0, lat0 : float
        Target, degrees.
    emission_deg : float
        Signed emission angle at the target, degrees (positive rolls one way,
        negative the other).
    altitude : float
        Orbit altitude, metres.
    interior : InteriorOrientation, optional
        Overrides the default interior orientation.
    line_time : float
        Line period of the line scanner, seconds.
    """
    if kind not in ("linescan", "frame"):
        raise InvalidInputError(f"camera kind must be 'linescan' or 'frame', got {kind!r}")
    if not abs(emission_deg) < 80.0:
        raise InvalidInputError(f"emission angle {emission_deg} deg is too oblique (|e| < 80 deg)")
    shape = shape or Shape.moon()
    radius = float(shape.reference_radius)
    roll = np.sign(emission_deg) * look_angle_for_emission(abs(emission_deg), altitude, radius)
    if kind == "linescan":
        io = interior or nac_like_interior(n_lines=n_lines, n_samples=n_samples, k1=None)
        half_t = 0.5 * io.n_lines * line_time
    else:
        io = interior or frame_interior(odk=None)
        half_t = 0.0
    lon_orbit, lat_orbit = lon0, lat0
    for _ in range(4):  # the body is a sphere: shifting the orbit shifts the footprint rigidly
        eo = polar_orbit_eo(lat_center=lat_orbit, lon=lon_orbit, altitude=altitude, radius=radius,
                            half_span=max(2.0, 2.0 * half_t + 1.0), step=0.05, roll_deg=float(roll))
        if kind == "linescan":
            cam: FrameCamera | LineScanCamera = LineScanCamera(io, eo, shape, line_times=(-half_t, line_time))
        else:
            cam = FrameCamera(io, eo, shape, time=0.0)
        g = cam.image_to_ground(io.n_lines / 2.0, io.n_samples / 2.0, height=0.0)
        lon_c = np.degrees(np.arctan2(g[1], g[0]))
        lat_c = np.degrees(np.arctan2(g[2], np.hypot(g[0], g[1])))
        if abs(lon_c - lon0) < 1e-9 and abs(lat_c - lat0) < 1e-9:
            break
        lon_orbit += lon0 - lon_c
        lat_orbit += lat0 - lat_c
    return cam


def stereo_pair(kind: Literal["linescan", "frame"], convergence_deg: float, lon0: float = 30.0,
                lat0: float = 0.0, **kwargs: object) -> tuple[FrameCamera | LineScanCamera,
                                                           FrameCamera | LineScanCamera]:
    """Two cameras seeing (``lon0``, ``lat0``) with a symmetric convergence angle (degrees).

    Extra keyword arguments go to :func:`pointed_camera`. At 0 degrees both
    cameras are identical.
    """
    if not 0.0 <= convergence_deg < 120.0:
        raise InvalidInputError(f"convergence angle must be in [0, 120) degrees, got {convergence_deg}")
    half = 0.5 * convergence_deg
    return (pointed_camera(kind, lon0, lat0, +half, **kwargs),  # type: ignore[arg-type]
            pointed_camera(kind, lon0, lat0, -half, **kwargs))  # type: ignore[arg-type]
