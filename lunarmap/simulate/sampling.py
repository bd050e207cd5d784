"""Bilinear sampling of rasters on a lat/lon grid or on a map-projected grid (pyproj).

An orthoimage (or albedo map) is an ``xarray.DataArray`` either with dims
(``lat``, ``lon``) in degrees, or with dims (``y``, ``x``) in map metres and
its CRS in ``attrs["crs"]`` (anything :class:`pyproj.CRS` accepts: WKT, PROJ
string, ``"IAU_2015:30110"``...). Lon/lat queries are converted to map
coordinates through PROJ from the IAU 2015 Moon geographic CRS.
"""

from __future__ import annotations

import threading

import numpy as np
import pyproj
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from ..camera.geodesy import MOON_GEOGRAPHIC_CRS
from ..camera.intersect import DtmSampler
from ..errors import InvalidInputError

__all__ = ["RasterSampler"]

Array = NDArray[np.float64]


_TRANSFORMER_LOCK = threading.Lock()


class RasterSampler:
    """Bilinear lookup ``sampler(lon, lat)`` of a lat/lon or projected raster; NaN outside.

    Parameters
    ----------
    raster : xarray.DataArray
        Dims (``lat``, ``lon``) in degrees, or (``y``, ``x``) in metres with
        ``attrs["crs"]`` naming the map projection.

    Notes
    -----
    The object pickles (the PROJ transformer is rebuilt on demand), so it can
    travel into dask tasks.
    """

    def __init__(self, raster: xr.DataArray) -> None:
        if not isinstance(raster, xr.DataArray):
            raise InvalidInputError(f"raster must be an xarray.DataArray, got {type(raster).__name__}")
        dims = set(raster.dims)
        self._latlon: DtmSampler | None = None
        self._crs: str | None = None
        self._transformer: pyproj.Transformer | None = None
        if dims == {"lat", "lon"}:
            self._latlon = DtmSampler(raster)
            return
        if dims != {"y", "x"}:
            raise InvalidInputError(f"raster must have dims (lat, lon) or (y, x), got {raster.dims}")
        crs = raster.attrs.get("crs")
        if crs is None:
            raise InvalidInputError("a projected raster (dims y, x) needs its CRS in attrs['crs']")
        try:
            self._crs = pyproj.CRS(crs).to_wkt()
        except pyproj.exceptions.CRSError as exc:
            raise InvalidInputError(f"raster attrs['crs'] is not a valid CRS: {exc}") from exc
        da = raster.transpose("y", "x")
        y = np.asarray(da["y"].values, dtype=float)
        x = np.asarray(da["x"].values, dtype=float)
        z = np.asarray(da.values, dtype=float)
        if y.size < 2 or x.size < 2:
            raise InvalidInputError("raster needs at least 2 x 2 nodes")
        if y[0] > y[-1]:
            y, z = y[::-1], z[::-1]
        if x[0] > x[-1]:
            x, z = x[::-1], z[:, ::-1]
        if np.any(np.diff(y) <= 0) or np.any(np.diff(x) <= 0):
            raise InvalidInputError("raster x/y coordinates must be strictly monotonic")
        self.y, self.x, self.z = y, x, np.ascontiguousarray(z)

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_transformer"] = None
        return state

    def _to_map(self, lon: Array, lat: Array) -> tuple[Array, Array]:
        transformer = self._transformer
        if transformer is None:
            with _TRANSFORMER_LOCK:   # built once; pyproj transformers are thread-safe (pyproj >= 3.1)
                if self._transformer is None:
                    self._transformer = pyproj.Transformer.from_crs(pyproj.CRS(MOON_GEOGRAPHIC_CRS),
                                                                    pyproj.CRS(self._crs), always_xy=True)
                transformer = self._transformer
        x, y = transformer.transform(lon, lat)
        return np.asarray(x, dtype=float), np.asarray(y, dtype=float)

    def __call__(self, lon: ArrayLike, lat: ArrayLike) -> Array:
        """Values at ``lon``, ``lat`` (degrees); NaN outside the raster or next to NaN nodes."""
        lon = np.asarray(lon, dtype=float)
        lat = np.asarray(lat, dtype=float)
        if self._latlon is not None:
            return self._latlon(lon, lat)
        x, y = self._to_map(lon, lat)
        i = np.clip(np.searchsorted(self.y, y, side="right") - 1, 0, self.y.size - 2)
        j = np.clip(np.searchsorted(self.x, x, side="right") - 1, 0, self.x.size - 2)
        u = (y - self.y[i]) / (self.y[i + 1] - self.y[i])
        v = (x - self.x[j]) / (self.x[j + 1] - self.x[j])
        z = self.z
        val = ((1.0 - u) * ((1.0 - v) * z[i, j] + v * z[i, j + 1])
               + u * ((1.0 - v) * z[i + 1, j] + v * z[i + 1, j + 1]))
        outside = (u < 0.0) | (u > 1.0) | (v < 0.0) | (v > 1.0) | ~np.isfinite(x) | ~np.isfinite(y)
        return np.where(outside, np.nan, val)
