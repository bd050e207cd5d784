"""LOLA-like laser-altimetry tracks over a known terrain, with a known error model (issue 30).

Tracks run north-south (LRO's polar orbit) at evenly spaced longitudes over a lon/lat box. Every track
fires at ``along_track_m`` intervals (LOLA: 28 Hz at ~1.6 km/s, ~57 m) a five-spot pattern: a centre spot
and four spots ``spot_radius_m`` (25 m) from it on a cross turned ``spot_angle_deg`` (26 degrees) from the
track, so that the five profiles are ~10 m apart across track. Each shot's radius is

    r = R + h(lon, lat) + o_T + d_T (t - t_T) + e,        e ~ N(0, sigma^2)

with ``h`` the true terrain, ``o_T ~ N(0, offset_sigma^2)`` and ``d_T ~ N(0, drift_sigma^2)`` the track's
orbit error (``t_T`` its mean shot time), and optionally gross errors of ``+-gross_m`` on a fraction of
the shots. The truth is returned with the shots (:class:`SimulatedAltimetry`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from numpy.typing import NDArray

from ..camera.shape import MOON_RADIUS
from ..errors import InvalidInputError
from ..io.altimetry import AltimetryShots

__all__ = ["SimulatedAltimetry", "altimetry_tracks", "LOLA_ALONG_TRACK_M"]

#: LOLA's along-track shot spacing, metres (28 Hz at ~1.6 km/s ground speed)
LOLA_ALONG_TRACK_M = 57.0


@dataclass
class SimulatedAltimetry:
    """Simulated shots and their truth.

    Attributes
    ----------
    shots : AltimetryShots
    track_names : (n_tr,) str
        Sorted like ``np.unique(shots.track)``.
    offsets, drifts : (n_tr,)
        True per-track offsets (m) and drifts (m/s), in ``track_names`` order.
    terrain_radius : (n,)
        True terrain radius at every shot, metres.
    gross : (n,) bool
        Shots carrying a gross error.
    sigma : float
        The radial noise, metres.
    """

    shots: AltimetryShots
    track_names: NDArray
    offsets: NDArray[np.float64]
    drifts: NDArray[np.float64]
    terrain_radius: NDArray[np.float64]
    gross: NDArray[np.bool_]
    sigma: float


def altimetry_tracks(height: Callable[[NDArray, NDArray], NDArray], lon_range: tuple[float, float],
                     lat_range: tuple[float, float], n_tracks: int, *, along_track_m: float = LOLA_ALONG_TRACK_M,
                     spots: int = 5, spot_radius_m: float = 25.0, spot_angle_deg: float = 26.0, sigma: float = 0.5,
                     offset_sigma: float = 30.0, drift_sigma: float = 0.0, speed: float = 1600.0,
                     gross_fraction: float = 0.0, gross_m: float = 50.0, heading_deg: float = 0.0,
                     seed: int = 0) -> SimulatedAltimetry:
    """Simulate LOLA-like tracks (module docstring) over the terrain ``height(lon, lat)`` (metres above the
    Moon sphere at planetocentric degrees).

    Parameters
    ----------
    lon_range, lat_range : (float, float)
        Box the tracks cover, degrees (tracks at evenly spaced longitudes inside it, from its south edge to
        its north edge).
    n_tracks : int
        Tracks (>= 1).
    along_track_m : float
        Shot spacing along track, metres.
    spots : {1, 5}
        Spots per shot (1: the centre spot only).
    sigma : float
        Radial noise per spot, metres.
    offset_sigma, drift_sigma : float
        Per-track offset (m) and drift (m/s) sigmas.
    speed : float
        Ground speed, m/s (times of the shots).
    gross_fraction, gross_m : float
        Fraction of spots with a gross error, and its size (random sign), metres.
    heading_deg : float
        Tracks alternate between ``+heading_deg`` and ``-heading_deg`` from north (0: all north-south;
        a few degrees: LRO's ascending and descending passes away from the equator, whose crossings tie the
        tracks' offsets together). Each track is cut to the box.
    seed : int

    Raises
    ------
    InvalidInputError
        Bad box, counts or sigmas.
    """
    lon0, lon1 = (float(v) for v in lon_range)
    lat0, lat1 = (float(v) for v in lat_range)
    if not (lon1 > lon0 and lat1 > lat0 and n_tracks >= 1 and along_track_m > 0 and speed > 0):
        raise InvalidInputError(f"altimetry_tracks: bad box {lon_range} x {lat_range}, {n_tracks} tracks or spacing")
    if spots not in (1, 5) or sigma < 0 or offset_sigma < 0 or drift_sigma < 0 or not 0 <= gross_fraction < 1:
        raise InvalidInputError("altimetry_tracks: spots must be 1 or 5, sigmas >= 0, gross_fraction in [0, 1)")
    rng = np.random.default_rng(seed)
    R = MOON_RADIUS
    clat_deg = 0.5 * (lat0 + lat1)
    clat = np.radians(clat_deg)
    # local metres east / north of the box's centre
    half_e = 0.5 * np.radians(lon1 - lon0) * R * np.cos(clat)
    half_n = 0.5 * np.radians(lat1 - lat0) * R
    s_along = np.arange(-np.hypot(half_e, half_n), np.hypot(half_e, half_n), along_track_m)
    # tracks evenly spaced, each shifted by up to a tenth of the spacing (orbits do not fall on a grid)
    de = 2.0 * half_e / n_tracks
    e_t = -half_e + de * (np.arange(n_tracks) + 0.5) + rng.uniform(-0.1, 0.1, n_tracks) * de
    spot_ang = np.radians(spot_angle_deg) + np.arange(4) * np.pi / 2
    along = np.concatenate([[0.0], spot_radius_m * np.cos(spot_ang)])[:spots]
    across = np.concatenate([[0.0], spot_radius_m * np.sin(spot_ang)])[:spots]
    names = np.array([f"T{k:03d}" for k in range(n_tracks)])
    off = rng.normal(0.0, offset_sigma, n_tracks)
    dri = rng.normal(0.0, drift_sigma, n_tracks)
    tr, tt, lo, la = [], [], [], []
    for k in range(n_tracks):
        a = np.radians(heading_deg) * (1.0 if k % 2 == 0 else -1.0)
        u = np.array([np.sin(a), np.cos(a)])                       # along track (east, north)
        w = np.array([np.cos(a), -np.sin(a)])                      # across track
        sa = (s_along[:, None] + along[None, :]).ravel()
        sc = np.broadcast_to(across[None, :], (s_along.size, spots)).ravel()
        east = e_t[k] + sa * u[0] + sc * w[0]
        north = sa * u[1] + sc * w[1]
        t = np.repeat(s_along, spots) / speed + 1.0e4 * k          # seconds; tracks an orbit apart
        # whole shots (all their spots) whose centre spot is in the box
        ce, cn = e_t[k] + s_along * u[0], s_along * u[1]
        inside = np.repeat((np.abs(ce) <= half_e) & (np.abs(cn) <= half_n), spots)
        tr.append(np.full(int(inside.sum()), names[k]))
        tt.append(t[inside])
        lo.append(0.5 * (lon0 + lon1) + np.degrees(east[inside] / (R * np.cos(clat))))
        la.append(clat_deg + np.degrees(north[inside] / R))
    track, time, lon, lat = (np.concatenate(a) for a in (tr, tt, lo, la))
    kt = np.searchsorted(names, track)
    tmean = np.array([time[kt == k].mean() for k in range(n_tracks)])
    terrain = R + np.asarray(height(lon, lat), float)
    gross = rng.random(lon.size) < gross_fraction
    radius = (terrain + off[kt] + dri[kt] * (time - tmean[kt]) + rng.normal(0.0, sigma, lon.size)
              + np.where(gross, gross_m * rng.choice([-1.0, 1.0], lon.size), 0.0))
    shots = AltimetryShots(track, time, lon, lat, radius, None, "simulated")
    return SimulatedAltimetry(shots, names, off, dri, terrain, gross, float(sigma))
