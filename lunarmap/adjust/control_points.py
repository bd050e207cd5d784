"""Control points given as planetocentric latitude, longitude and height with sigmas.

A control point ``(lon, lat, h)`` on the reference sphere of radius ``R`` is the body-fixed point

    X = (R + h) (cos(lat) cos(lon), cos(lat) sin(lon), sin(lat))

and its sigmas propagate to a 3 x 3 covariance by ``C_X = J diag(s^2) J^T`` with the
closed-form Jacobian (columns in metres per radian, per radian, per metre)::

    dX/dlon = (R + h) cos(lat) e,   dX/dlat = (R + h) n,   dX/dh = u

(``e, n, u`` the local east, north, up unit vectors).  Horizontal sigmas may be given in
degrees, radians or ground metres (east, north); the height sigma is in metres.
The propagation is exact for the linearised model; the neglected curvature terms are of order
``sigma^2 / R`` (below a micrometre for sigmas of tens of metres on the Moon).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..camera.geodesy import lonlat_height_to_xyz
from ..camera.shape import MOON_RADIUS
from ..errors import AdjustmentInputError
from .problem import PointPriors

__all__ = ["enu_basis", "lonlat_covariance_to_xyz", "lonlat_priors"]

_UNITS = ("deg", "rad", "m")


def enu_basis(lon: ArrayLike, lat: ArrayLike) -> NDArray[np.float64]:
    """Local east, north, up unit vectors as rows, ``(..., 3, 3)``, at ``lon, lat`` in degrees."""
    lam, phi = np.radians(np.asarray(lon, float)), np.radians(np.asarray(lat, float))
    cl, sl, co, so = np.cos(phi), np.sin(phi), np.cos(lam), np.sin(lam)
    east = np.stack([-so, co, np.zeros_like(lam)], -1)
    north = np.stack([-sl * co, -sl * so, cl], -1)
    up = np.stack([cl * co, cl * so, sl], -1)
    return np.stack([east, north, up], axis=-2)


def lonlat_covariance_to_xyz(lon: ArrayLike, lat: ArrayLike, height: ArrayLike, cov_llh: ArrayLike,
                             unit: str = "deg", radius: float = MOON_RADIUS) -> NDArray[np.float64]:
    """Propagate covariances of ``(lon, lat, height)`` to body-fixed ``(x, y, z)``, ``(k, 3, 3)`` m^2.

    Parameters
    ----------
    lon, lat : (k,) degrees
    height : (k,) metres above the sphere of ``radius`` metres
    cov_llh : (k, 3, 3)
        Covariance of ``(lon, lat, height)`` in ``unit^2`` for the horizontal part (``"deg"``,
        ``"rad"``, or ``"m"`` = east/north ground metres) and m^2 for height.
    """
    if unit not in _UNITS:
        raise AdjustmentInputError(f"unit must be one of {_UNITS}, got {unit!r}")
    lon, lat, height = (np.atleast_1d(np.asarray(a, float)) for a in (lon, lat, height))
    cov = np.asarray(cov_llh, float).reshape(-1, 3, 3)
    E = enu_basis(lon, lat)                                   # (k, 3, 3) rows e, n, u
    scale = np.ones((lon.size, 3))
    if unit != "m":
        per_rad = (radius + height)[:, None] * np.column_stack([np.cos(np.radians(lat)), np.ones_like(lat)])
        scale[:, :2] = per_rad * (np.pi / 180.0 if unit == "deg" else 1.0)
    J = np.swapaxes(E, 1, 2) * scale[:, None, :]              # columns d X / d(lon, lat, h)
    return np.einsum("kij,kjl,kml->kim", J, cov, J)


def lonlat_priors(idx: ArrayLike, lon: ArrayLike, lat: ArrayLike, height: ArrayLike, sigma_lon: ArrayLike,
                  sigma_lat: ArrayLike, sigma_height: ArrayLike, unit: str = "deg", radius: float = MOON_RADIUS,
                  representation: str = "covariance") -> PointPriors:
    """Control-point priors (body-fixed metres) from latitude/longitude/height with sigmas.

    Parameters
    ----------
    idx : (k,) int
        Point indices in the block.
    lon, lat : (k,) degrees (east longitude, planetocentric latitude)
    height : (k,) metres above the sphere of ``radius`` metres
    sigma_lon, sigma_lat : (k,) or scalar
        In ``unit``: ``"deg"``, ``"rad"``, or ``"m"`` (ground metres east and north).
    sigma_height : (k,) or scalar, metres
    representation : {"covariance", "isotropic-bound"}
        ``"covariance"``: the exact 3 x 3 covariance (``PointPriors.cov``).  ``"isotropic-bound"``:
        per-axis sigma equal to the square root of the largest eigenvalue, for all three axes; a
        conservative bound (its weight never exceeds the true one in any direction) for solvers
        that only take per-axis sigmas.

    Raises
    ------
    AdjustmentInputError
        Bad unit/representation, non-finite or negative sigma, shape mismatch.
    """
    if representation not in ("covariance", "isotropic-bound"):
        raise AdjustmentInputError(f"representation must be 'covariance' or 'isotropic-bound', got {representation!r}")
    idx = np.atleast_1d(np.asarray(idx, np.int64))
    k = idx.size
    try:
        lon, lat, height, s_lon, s_lat, s_h = (np.broadcast_to(np.asarray(a, float), (k,)) for a in
                                               (lon, lat, height, sigma_lon, sigma_lat, sigma_height))
    except ValueError as exc:
        raise AdjustmentInputError(f"control points: coordinates and sigmas must have {k} values") from exc
    s = np.column_stack([s_lon, s_lat, s_h])
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(np.column_stack([lon, lat, height])))):
        raise AdjustmentInputError("control points: non-finite coordinates or sigmas")
    if np.any(s < 0):
        raise AdjustmentInputError("control point sigmas must be >= 0")
    if np.any((s == 0).any(axis=1) & ~(s == 0).all(axis=1)):
        raise AdjustmentInputError("control point sigmas: zero for some but not all of lon/lat/height "
                                   "(all zero holds the point fixed)")
    cov = lonlat_covariance_to_xyz(lon, lat, height, s[:, :, None] ** 2 * np.eye(3), unit, radius)
    xyz = lonlat_height_to_xyz(lon, lat, height, radius)
    if representation == "covariance":
        return PointPriors(idx, xyz, cov=cov)
    bound = np.sqrt(np.linalg.eigvalsh(cov)[:, -1])
    return PointPriors(idx, xyz, np.repeat(bound[:, None], 3, axis=1))
