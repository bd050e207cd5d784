"""A reference DTM with a known error model, for adjustments to terrain (issue 30).

The DTM is the true terrain on a lon/lat grid plus

* a smooth systematic offset field ``bias + amplitude sin(2 pi e / L + p1) cos(2 pi n / L + p2)``
  (``e, n``: ground metres east / north of the grid's centre; ``L`` the wavelength, longer than a
  block, like the long-wavelength errors of a DTM tied to altimetry), and
* white noise of ``noise_sigma`` per grid node.

Interpolated bilinearly at a random place, white node noise has the standard deviation
``noise_sigma * 2/3`` (``E[((1-u)^2 + u^2)((1-v)^2 + v^2)] = (2/3)^2``); :attr:`SimulatedDtm.sigma_m`
is that figure, the sigma to give the DTM's observations when the offset field is zero. It is
written as a GeoTIFF (float32, nodata NaN) in the IAU 2015 Moon geographic CRS, so that
:class:`lunarmap.adjust.ReferenceDtm` reads it like any other.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..camera.geodesy import MOON_GEOGRAPHIC_CRS
from ..camera.shape import MOON_RADIUS
from ..errors import InvalidInputError, MissingDependencyError

__all__ = ["SimulatedDtm", "reference_dtm"]


@dataclass
class SimulatedDtm:
    """A written reference DTM and its error model.

    Attributes
    ----------
    path : str
        The GeoTIFF.
    lon, lat : (ns,), (nl,)
        Node (pixel centre) longitudes and latitudes, degrees (latitudes descending, north-up).
    heights : (nl, ns)
        The written heights, metres above the sphere (NaN where holes were cut).
    bias, amplitude, wavelength, noise_sigma : float
        The error model (metres).
    sigma_m : float
        Standard deviation of the interpolated noise, ``2/3 noise_sigma`` (metres).
    """

    path: str
    lon: NDArray[np.float64]
    lat: NDArray[np.float64]
    heights: NDArray[np.float64]
    bias: float
    amplitude: float
    wavelength: float
    noise_sigma: float
    sigma_m: float
    _phase: tuple[float, float] = (0.0, 0.0)
    _centre: tuple[float, float] = (0.0, 0.0)

    def offset(self, lon: ArrayLike, lat: ArrayLike) -> NDArray[np.float64]:
        """The systematic offset field (DTM minus truth without the noise) at ``lon, lat`` degrees, metres."""
        e = np.radians(np.asarray(lon, float) - self._centre[0]) * MOON_RADIUS * np.cos(np.radians(self._centre[1]))
        n = np.radians(np.asarray(lat, float) - self._centre[1]) * MOON_RADIUS
        k = 2.0 * np.pi / self.wavelength
        return self.bias + self.amplitude * np.sin(k * e + self._phase[0]) * np.cos(k * n + self._phase[1])


def reference_dtm(path: str | os.PathLike[str], height: Callable[[NDArray, NDArray], NDArray],
                  lon_range: tuple[float, float], lat_range: tuple[float, float], spacing_m: float, *,
                  bias: float = 0.0, amplitude: float = 0.0, wavelength: float = 200e3, noise_sigma: float = 1.0,
                  holes: int = 0, hole_radius_px: int = 3, seed: int = 0, crs: str | None = MOON_GEOGRAPHIC_CRS
                  ) -> SimulatedDtm:
    """Write a reference DTM of the true terrain ``height(lon, lat)`` with the error model above.

    Parameters
    ----------
    path : path-like
        Output GeoTIFF.
    height : callable
        True heights above the Moon sphere (metres) at ``lon, lat`` degrees (arrays).
    lon_range, lat_range : (float, float)
        Extent of the grid, degrees.
    spacing_m : float
        Node spacing on the ground (at the grid's centre latitude), metres.
    bias, amplitude, wavelength : float
        The offset field, metres.
    noise_sigma : float
        White noise per node, metres.
    holes : int
        Number of square NaN holes (``2 hole_radius_px + 1`` nodes wide) at random places (bad input).
    seed : int
    crs : str or None
        The CRS written; None writes a GeoTIFF without one (bad input).

    Raises
    ------
    InvalidInputError
        Bad extent or spacing.
    MissingDependencyError
        rasterio not installed.
    """
    try:
        import rasterio
        from rasterio.transform import from_origin
    except ImportError:
        raise MissingDependencyError("writing a GeoTIFF DTM needs rasterio: pip install lunarmap[raster]") from None
    lon0, lon1 = (float(v) for v in lon_range)
    lat0, lat1 = (float(v) for v in lat_range)
    if not (lon1 > lon0 and lat1 > lat0 and spacing_m > 0):
        raise InvalidInputError(f"reference_dtm: bad extent {lon_range} x {lat_range} or spacing {spacing_m}")
    rng = np.random.default_rng(seed)
    clat = 0.5 * (lat0 + lat1)
    dlat = np.degrees(spacing_m / MOON_RADIUS)
    dlon = dlat / max(np.cos(np.radians(clat)), 1e-3)
    ns = int(np.ceil((lon1 - lon0) / dlon)) + 1
    nl = int(np.ceil((lat1 - lat0) / dlat)) + 1
    lon = lon0 + dlon * np.arange(ns)
    lat = lat0 + dlat * (nl - 1) - dlat * np.arange(nl)          # north-up: first row northernmost
    LON, LAT = np.meshgrid(lon, lat)
    sim = SimulatedDtm(os.fspath(path), lon, lat, np.zeros((nl, ns)), float(bias), float(amplitude), float(wavelength),
                       float(noise_sigma), 2.0 / 3.0 * float(noise_sigma),
                       (float(rng.uniform(0, 2 * np.pi)), float(rng.uniform(0, 2 * np.pi))),
                       (0.5 * (lon0 + lon1), clat))
    z = np.asarray(height(LON, LAT), float) + sim.offset(LON, LAT) + rng.normal(0.0, noise_sigma, LON.shape)
    for _ in range(int(holes)):
        i, j = int(rng.integers(0, nl)), int(rng.integers(0, ns))
        z[max(i - hole_radius_px, 0):i + hole_radius_px + 1, max(j - hole_radius_px, 0):j + hole_radius_px + 1] = np.nan
    sim.heights = z
    # pixel-is-area: the corner of the first pixel half a spacing west and north of its centre
    transform = from_origin(lon0 - 0.5 * dlon, lat[0] + 0.5 * dlat, dlon, dlat)
    with rasterio.open(os.fspath(path), "w", driver="GTiff", height=nl, width=ns, count=1, dtype="float32",
                       crs=crs, transform=transform, nodata=np.nan) as ds:
        ds.write(z.astype(np.float32), 1)
    return sim
