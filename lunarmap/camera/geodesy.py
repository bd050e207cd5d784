"""Body-fixed Cartesian <-> planetocentric longitude, latitude, height.

Longitudes are east-positive degrees in ``(-180, 180]``, latitudes
planetocentric degrees, heights metres above a reference *sphere*. On a sphere
planetocentric and planetographic latitudes coincide, so these are also the
geodetic coordinates of the IAU 2015 Moon CRS (``IAU_2015:30100``).

Two implementations are provided: a closed form for any reference radius
(used internally: it is a few numpy operations) and the PROJ pipeline of the
IAU 2015 Moon sphere (:func:`pyproj_xyz_to_lonlat_height` and back), which
serves as an independent check and as the CRS to write products in.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pyproj
from numpy.typing import ArrayLike, NDArray

from ..errors import InvalidInputError
from .shape import MOON_RADIUS

__all__ = [
    "MOON_GEOGRAPHIC_CRS",
    "moon_geographic_crs",
    "moon_geocentric_crs",
    "xyz_to_lonlat_height",
    "lonlat_height_to_xyz",
    "pyproj_xyz_to_lonlat_height",
    "pyproj_lonlat_height_to_xyz",
    "enu_basis",
]

#: Authority code of the IAU 2015 Moon sphere (1737.4 km), planetocentric geographic 2-D CRS.
MOON_GEOGRAPHIC_CRS = "IAU_2015:30100"


def _finite(name: str, a: NDArray[np.float64]) -> None:
    if not np.all(np.isfinite(a)):
        raise InvalidInputError(f"{name} holds NaN or infinite values")


@lru_cache(maxsize=None)
def moon_geographic_crs() -> pyproj.CRS:
    """The IAU 2015 Moon sphere geographic CRS with ellipsoidal height (3-D)."""
    return pyproj.CRS(MOON_GEOGRAPHIC_CRS).to_3d()


@lru_cache(maxsize=None)
def moon_geocentric_crs() -> pyproj.CRS:
    """Body-fixed Cartesian CRS on the IAU 2015 Moon sphere datum, metres.

    The IAU_2015 registry has no geocentric Moon CRS, so one is built on the
    datum of ``IAU_2015:30100``.
    """
    datum = pyproj.CRS(MOON_GEOGRAPHIC_CRS).datum
    return pyproj.crs.GeocentricCRS(name="Moon (2015) - Sphere / Ocentric / Geocentric", datum=datum)


@lru_cache(maxsize=None)
def _transformer(forward: bool) -> pyproj.Transformer:
    src, dst = moon_geocentric_crs(), moon_geographic_crs()
    if not forward:
        src, dst = dst, src
    return pyproj.Transformer.from_crs(src, dst, always_xy=True)


def xyz_to_lonlat_height(xyz: ArrayLike, radius: float = MOON_RADIUS
                         ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Planetocentric coordinates of body-fixed points (closed form).

    Parameters
    ----------
    xyz : array_like, shape (..., 3)
        Body-fixed positions, metres.
    radius : float
        Reference sphere radius, metres.

    Returns
    -------
    lon, lat : ndarray, shape (...)
        East longitude in (-180, 180] and planetocentric latitude, degrees.
    height : ndarray, shape (...)
        Height above the reference sphere, metres.
    """
    xyz = np.asarray(xyz, dtype=float)
    if xyz.shape[-1:] != (3,):
        raise InvalidInputError(f"xyz must have shape (..., 3), got {xyz.shape}")
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    rho = np.hypot(x, y)
    lon = np.degrees(np.arctan2(y, x))
    lat = np.degrees(np.arctan2(z, rho))
    height = np.sqrt(rho * rho + z * z) - radius
    return lon, lat, height


def lonlat_height_to_xyz(lon: ArrayLike, lat: ArrayLike, height: ArrayLike = 0.0,
                         radius: float = MOON_RADIUS) -> NDArray[np.float64]:
    """Body-fixed positions of planetocentric coordinates (closed form).

    Parameters
    ----------
    lon, lat : array_like
        East longitude and planetocentric latitude, degrees.
    height : array_like
        Height above the reference sphere, metres.
    radius : float
        Reference sphere radius, metres.

    Returns
    -------
    ndarray, shape (..., 3)
        Body-fixed positions, metres.
    """
    lon, lat, height = np.broadcast_arrays(np.asarray(lon, dtype=float), np.asarray(lat, dtype=float),
                                           np.asarray(height, dtype=float))
    lam = np.radians(lon)
    phi = np.radians(lat)
    r = radius + height
    cphi = np.cos(phi)
    return np.stack([r * cphi * np.cos(lam), r * cphi * np.sin(lam), r * np.sin(phi)], axis=-1)


def pyproj_xyz_to_lonlat_height(xyz: ArrayLike
                                ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """:func:`xyz_to_lonlat_height` on the 1737.4 km IAU 2015 sphere, through PROJ."""
    xyz = np.asarray(xyz, dtype=float)
    if xyz.shape[-1:] != (3,):
        raise InvalidInputError(f"xyz must have shape (..., 3), got {xyz.shape}")
    _finite("xyz", xyz)
    lon, lat, h = _transformer(True).transform(xyz[..., 0], xyz[..., 1], xyz[..., 2])
    return np.asarray(lon, dtype=float), np.asarray(lat, dtype=float), np.asarray(h, dtype=float)


def pyproj_lonlat_height_to_xyz(lon: ArrayLike, lat: ArrayLike, height: ArrayLike = 0.0
                                ) -> NDArray[np.float64]:
    """:func:`lonlat_height_to_xyz` on the 1737.4 km IAU 2015 sphere, through PROJ."""
    lon, lat, height = np.broadcast_arrays(np.asarray(lon, dtype=float), np.asarray(lat, dtype=float),
                                           np.asarray(height, dtype=float))
    x, y, z = _transformer(False).transform(lon, lat, height)
    return np.stack([np.asarray(x, dtype=float), np.asarray(y, dtype=float), np.asarray(z, dtype=float)],
                    axis=-1)


def enu_basis(lon: ArrayLike, lat: ArrayLike) -> NDArray[np.float64]:
    """Local east, north, up unit vectors (body-fixed) at planetocentric coordinates.

    Parameters
    ----------
    lon, lat : array_like
        East longitude and planetocentric latitude, degrees.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Rows are east, north and up, so ``enu_basis(lon, lat) @ v`` gives the
        east/north/up components of a body-fixed vector ``v``.
    """
    lon, lat = np.broadcast_arrays(np.asarray(lon, dtype=float), np.asarray(lat, dtype=float))
    lam = np.radians(lon)
    phi = np.radians(lat)
    sl, cl = np.sin(lam), np.cos(lam)
    sp, cp = np.sin(phi), np.cos(phi)
    east = np.stack([-sl, cl, np.zeros_like(sl)], axis=-1)
    north = np.stack([-sp * cl, -sp * sl, cp], axis=-1)
    up = np.stack([cp * cl, cp * sl, sp], axis=-1)
    return np.stack([east, north, up], axis=-2)
