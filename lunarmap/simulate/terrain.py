"""Synthetic lunar terrain and albedo: crater fields over rolling terrain, band-limited texture.

Everything is generated on a local east/north grid in metres around a centre
(``lon0``, ``lat0``) and returned on a regular planetocentric ``lat`` x ``lon``
grid (degrees), so the results plug directly into
:class:`~lunarmap.camera.DtmSampler` and the cameras' ``image_to_ground(dtm=...)``.
No external data is needed; every generator is reproducible from its ``seed``.
"""

from __future__ import annotations

from typing import cast

import numpy as np
import xarray as xr
from numpy.typing import NDArray

from ..camera.shape import MOON_RADIUS
from ..errors import InvalidInputError

__all__ = ["local_grid", "rolling_terrain", "add_craters", "synthetic_dtm", "synthetic_albedo",
           "synthetic_scene"]

Array = NDArray[np.float64]


def local_grid(lon0: float, lat0: float, extent: float | tuple[float, float], spacing: float,
               radius: float = MOON_RADIUS) -> tuple[Array, Array, Array, Array]:
    """A regular lat/lon grid covering a square (or rectangle) of ground around a centre.

    Parameters
    ----------
    lon0, lat0 : float
        Centre, degrees (planetocentric, east-positive).
    extent : float or (float, float)
        Size east-west and north-south, metres.
    spacing : float
        Node spacing on the ground, metres.
    radius : float
        Reference sphere radius, metres.

    Returns
    -------
    lat, lon : ndarray
        Node coordinates, degrees (ascending).
    north, east : ndarray
        The same nodes as local distances from the centre, metres.
    """
    if np.isscalar(extent):         # np.isscalar does not narrow for mypy
        ew = ns = cast(float, extent)
    else:
        ew, ns = cast("tuple[float, float]", extent)
    if not (spacing > 0 and ew > 2 * spacing and ns > 2 * spacing):
        raise InvalidInputError(f"grid extent {extent} m must exceed twice the spacing {spacing} m (> 0)")
    if abs(lat0) > 89.0:
        raise InvalidInputError(f"local lat/lon grids are not supported within 1 degree of a pole (lat0={lat0})")
    n_e = int(np.ceil(ew / spacing)) + 1
    n_n = int(np.ceil(ns / spacing)) + 1
    east = np.asarray((np.arange(n_e) - (n_e - 1) / 2.0) * spacing, dtype=np.float64)
    north = np.asarray((np.arange(n_n) - (n_n - 1) / 2.0) * spacing, dtype=np.float64)
    lat = np.asarray(lat0 + np.degrees(north / radius), dtype=np.float64)
    lon = np.asarray(lon0 + np.degrees(east / (radius * np.cos(np.radians(lat0)))), dtype=np.float64)
    return lat, lon, north, east


def _power_law_noise(shape: tuple[int, int], spacing: float, beta: float, min_wavelength: float,
                     max_wavelength: float, rng: np.random.Generator) -> Array:
    """Zero-mean, unit-variance Gaussian field with power spectrum ``k^-beta`` in a wavelength band (m)."""
    white = rng.standard_normal(shape)
    ky = np.fft.fftfreq(shape[0], d=spacing)
    kx = np.fft.rfftfreq(shape[1], d=spacing)
    k = np.hypot(ky[:, None], kx[None, :])
    with np.errstate(divide="ignore"):
        amp = np.where(k > 0, k, np.inf) ** (-beta / 2.0)
    # Smooth band edges (Gaussian roll-off) avoid ringing at sharp cut-offs.
    amp *= np.exp(-0.5 * (k * min_wavelength) ** 2)
    amp *= 1.0 - np.exp(-0.5 * (k * max_wavelength) ** 2)
    field = np.fft.irfft2(np.fft.rfft2(white) * amp, s=shape)
    field -= field.mean()
    sd = field.std()
    return field / sd if sd > 0 else field


def rolling_terrain(north: Array, east: Array, relief: float, wavelength: float,
                    rng: np.random.Generator) -> Array:
    """Rolling terrain: a red-noise height field (metres) of standard deviation ``relief``.

    ``wavelength`` (metres) is the shortest wavelength kept; the spectrum falls as ``k^-3``.
    """
    spacing = float(abs(east[1] - east[0]))
    size = max(float(east[-1] - east[0]), float(north[-1] - north[0]))
    return relief * _power_law_noise((north.size, east.size), spacing, 3.0, wavelength, 2.0 * size, rng)


def add_craters(height: Array, north: Array, east: Array, n_craters: int, d_min: float, d_max: float,
                rng: np.random.Generator, depth_ratio: float = 0.2, rim_ratio: float = 0.04) -> Array:
    """Add simple bowl craters, diameters from a cumulative ``D^-2`` size-frequency law.

    The profile of a crater of radius ``R`` at distance ``r`` is a parabolic bowl
    ``d ((r/R)^2 - 1) + h_rim`` inside and an ejecta blanket ``h_rim (r/R)^-3``
    outside (the usual simple-crater morphometry, ``d = depth_ratio * 2R``,
    ``h_rim = rim_ratio * 2R``); both pieces meet at the rim. Heights in metres.
    """
    out = height.copy()
    u = rng.uniform(size=n_craters)
    # Inverse CDF of N(>D) ~ D^-2 truncated to [d_min, d_max].
    diam = (d_min ** -2 - u * (d_min ** -2 - d_max ** -2)) ** -0.5
    ce = rng.uniform(east[0], east[-1], n_craters)
    cn = rng.uniform(north[0], north[-1], n_craters)
    # One crater at a time over a window of 3 radii: a per-crater (not per-node) loop.
    for d, x0, y0 in zip(diam, ce, cn):
        r_c = d / 2.0
        reach = 3.0 * r_c
        j0, j1 = np.searchsorted(east, [x0 - reach, x0 + reach])
        i0, i1 = np.searchsorted(north, [y0 - reach, y0 + reach])
        if j1 <= j0 or i1 <= i0:
            continue
        rr = np.hypot(north[i0:i1, None] - y0, east[None, j0:j1] - x0) / r_c
        depth, rim = depth_ratio * d, rim_ratio * d
        prof = np.where(rr <= 1.0, depth * (rr ** 2 - 1.0) + rim, rim * np.maximum(rr, 1.0) ** -3)
        # Fade the blanket to zero at the window edge so craters have no seams.
        prof *= np.clip((3.0 - rr) / 1.0, 0.0, 1.0)
        out[i0:i1, j0:j1] += prof
    return out


def _as_dataarray(values: Array, lat: Array, lon: Array, name: str, units: str, **attrs: object) -> xr.DataArray:
    return xr.DataArray(values, dims=("lat", "lon"), coords={"lat": lat, "lon": lon}, name=name,
                        attrs={"units": units, **attrs})


def synthetic_dtm(lon0: float, lat0: float, extent: float | tuple[float, float], spacing: float, relief: float = 5.0,
                  wavelength: float | None = None, crater_density: float = 0.01, d_min: float | None = None,
                  d_max: float | None = None, seed: int = 0, radius: float = MOON_RADIUS) -> xr.DataArray:
    """A synthetic DTM: craters over rolling terrain.

    Parameters
    ----------
    lon0, lat0 : float
        Centre, degrees.
    extent : float or (float, float)
        Side of the square, or sides east-west and north-south of the rectangle, metres.
    spacing : float
        Node spacing, metres.
    relief : float
        Standard deviation of the rolling terrain, metres.
    wavelength : float, optional
        Shortest wavelength of the rolling terrain, metres (default ``20 * spacing``).
    crater_density : float
        Craters (``D >= d_min``) per square of side ``d_min``: the scene gets
        ``density * area / d_min^2`` craters (scale-free).
    d_min, d_max : float, optional
        Crater diameter range, metres (defaults ``8 * spacing`` and a quarter of the shorter side).
    seed : int
        Random seed.

    Returns
    -------
    xarray.DataArray
        Heights above ``radius`` (metres) on (``lat``, ``lon``) in degrees.
    """
    rng = np.random.default_rng(seed)
    lat, lon, north, east = local_grid(lon0, lat0, extent, spacing, radius)
    h = rolling_terrain(north, east, relief, wavelength or 20.0 * spacing, rng)
    d_lo: float = d_min or 8.0 * spacing
    if np.isscalar(extent):         # np.isscalar does not narrow for mypy
        side = cast(float, extent)
        d_hi: float = d_max or side / 4.0
        n_craters = int(round(crater_density * (side / d_lo) ** 2))
    else:
        ew, ns = (float(v) for v in cast("tuple[float, float]", extent))
        d_hi = d_max or min(ew, ns) / 4.0
        n_craters = int(round(crater_density * ew * ns / d_lo ** 2))
    if n_craters and d_hi > d_lo:
        h = add_craters(h, north, east, n_craters, d_lo, d_hi, rng)
    return _as_dataarray(h, lat, lon, "height", "m", spacing_m=spacing, radius_m=radius,
                         description="lunarmap.simulate synthetic DTM (craters over rolling terrain)")


def synthetic_albedo(lon0: float, lat0: float, extent: float, spacing: float, feature_size: float,
                     contrast: float = 0.25, mean: float = 0.5, seed: int = 1,
                     radius: float = MOON_RADIUS) -> xr.DataArray:
    """Band-limited albedo texture (dimensionless, in (0, 1)).

    The texture has a ``k^-1`` spectrum between ``feature_size`` (the shortest
    wavelength, metres; choose >= 2 image pixels on the ground so the rendered
    images are not aliased) and the extent, plus isolated bright and dark
    spots (fresh craters, boulders) of a few ``feature_size``.
    """
    if feature_size < 2.0 * spacing:
        raise InvalidInputError(f"feature_size {feature_size} m must be at least twice the spacing {spacing} m")
    rng = np.random.default_rng(seed)
    lat, lon, north, east = local_grid(lon0, lat0, extent, spacing, radius)
    shape = (north.size, east.size)
    tex = _power_law_noise(shape, spacing, 1.0, feature_size / np.pi, extent, rng)
    alb = mean + contrast * mean * np.tanh(tex / 1.5) * 1.5
    alb = np.clip(alb, 0.02, 0.98)
    return _as_dataarray(alb, lat, lon, "albedo", "1", spacing_m=spacing, feature_size_m=feature_size,
                         description="lunarmap.simulate synthetic albedo")


def synthetic_scene(lon0: float, lat0: float, extent: float, gsd: float, seed: int = 0,
                    relief: float | None = None) -> tuple[xr.DataArray, xr.DataArray]:
    """A DTM and a matching albedo map for images of ground sample distance ``gsd`` (metres).

    The DTM has a spacing of ``2 gsd`` and the albedo ``gsd / 3`` with
    features down to ``2 gsd``, the combination the tests and benchmarks use.
    ``relief`` (metres) defaults to ``10 gsd``.
    """
    dtm = synthetic_dtm(lon0, lat0, extent, 2.0 * gsd, relief=10.0 * gsd if relief is None else relief,
                        seed=seed)
    alb = synthetic_albedo(lon0, lat0, extent, gsd / 3.0, feature_size=2.0 * gsd, seed=seed + 1)
    return dtm, alb
