"""Vectorised intersection of look rays with an ellipsoid or a DTM.

Rays are ``origin + s * direction`` with ``s > 0`` (body-fixed metres); the
directions need not be unit vectors. A ray "misses" when it has no positive
intersection: :data:`on_miss` ``"raise"`` raises
:class:`~lunarmap.errors.NoIntersectionError` naming how many rays missed,
``"nan"`` returns NaN rows for them instead.

DTMs are ``xarray.DataArray`` of heights (metres above a reference sphere) on
a regular or irregular ``lat`` x ``lon`` grid in degrees (planetocentric,
east-positive), sampled bilinearly.
"""

from __future__ import annotations

from typing import Callable, Literal

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from ..errors import ConvergenceError, InvalidInputError, NoIntersectionError

__all__ = [
    "OnMiss",
    "intersect_ellipsoid",
    "intersect_sphere",
    "DtmSampler",
    "intersect_dtm",
    "surface_points_on_dtm",
]

OnMiss = Literal["raise", "nan"]
Array = NDArray[np.float64]


def _check_on_miss(on_miss: str) -> None:
    if on_miss not in ("raise", "nan"):
        raise InvalidInputError(f"on_miss must be 'raise' or 'nan', got {on_miss!r}")


def _rays(origins: ArrayLike, directions: ArrayLike) -> tuple[Array, Array]:
    o = np.asarray(origins, dtype=float)
    d = np.asarray(directions, dtype=float)
    if o.shape[-1:] != (3,) or d.shape[-1:] != (3,):
        raise InvalidInputError(f"ray origins and directions must have shape (..., 3), got {o.shape}, {d.shape}")
    o, d = np.broadcast_arrays(o, d)
    if not (np.all(np.isfinite(o)) and np.all(np.isfinite(d))):
        raise InvalidInputError("ray origins or directions hold NaN or infinite values")
    return o, d


def _nearest_positive_root(a: Array, b: Array, c: Array) -> Array:
    """Smallest positive root of ``a s^2 + 2 b s + c = 0`` (``a > 0``), NaN if none."""
    disc = b * b - a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        sq = np.sqrt(disc)
        # q form avoids the cancellation of -b +- sqrt(disc) for distant origins.
        q = -(b + np.copysign(sq, b))
        s1 = q / a
        s2 = c / q
    lo = np.fmin(s1, s2)
    hi = np.fmax(s1, s2)
    s = np.where(lo > 0.0, lo, np.where(hi > 0.0, hi, np.nan))
    return np.where(disc >= 0.0, s, np.nan)


def _finish(points: Array, on_miss: str, what: str) -> Array:
    missed = np.isnan(points[..., 0])
    if on_miss == "raise" and np.any(missed):
        n = int(np.count_nonzero(missed))
        raise NoIntersectionError(f"{n} of {missed.size} look ray(s) miss {what}")
    return points


def intersect_ellipsoid(origins: ArrayLike, directions: ArrayLike, axes: ArrayLike,
                        on_miss: OnMiss = "raise") -> Array:
    """Nearest positive intersection of rays with origin-centred ellipsoids.

    Parameters
    ----------
    origins, directions : array_like, shape (..., 3)
        Ray origins (metres) and directions (any length), body-fixed.
    axes : array_like, shape (3,) or (..., 3)
        Semi-axes ``(a, b, c)``, metres; per ray when it has the rays' shape
        (e.g. ``Shape.axes_at_height(h)`` for per-ray heights).
    on_miss : {"raise", "nan"}
        What to do for rays with no positive intersection.

    Returns
    -------
    ndarray, shape (..., 3)
        Intersection points, metres (NaN rows for misses with ``on_miss="nan"``).

    Raises
    ------
    NoIntersectionError
        Some ray misses and ``on_miss="raise"``; the message says how many.
    """
    _check_on_miss(on_miss)
    o, d = _rays(origins, directions)
    ax = np.asarray(axes, dtype=float)
    if not np.all(np.isfinite(ax)) or np.any(ax <= 0.0):
        raise InvalidInputError("ellipsoid semi-axes must be finite and positive "
                                "(a negative height larger than the radius?)")
    os_ = o / ax
    ds = d / ax
    a = np.einsum("...i,...i->...", ds, ds)
    b = np.einsum("...i,...i->...", os_, ds)
    c = np.einsum("...i,...i->...", os_, os_) - 1.0
    s = _nearest_positive_root(a, b, c)
    return _finish(o + s[..., None] * d, on_miss, "the ellipsoid")


def intersect_sphere(origins: ArrayLike, directions: ArrayLike, radius: ArrayLike,
                     on_miss: OnMiss = "raise") -> Array:
    """Nearest positive intersection of rays with origin-centred spheres.

    Parameters
    ----------
    origins, directions : array_like, shape (..., 3)
        Ray origins (metres) and directions, body-fixed.
    radius : array_like, shape () or (...)
        Sphere radius, metres (per ray when it has the rays' shape).
    on_miss : {"raise", "nan"}
        What to do for rays with no positive intersection.

    Returns
    -------
    ndarray, shape (..., 3)
        Intersection points, metres.
    """
    _check_on_miss(on_miss)
    o, d = _rays(origins, directions)
    r = np.asarray(radius, dtype=float)
    if not np.all(np.isfinite(r)) or np.any(r <= 0.0):
        raise InvalidInputError("sphere radius must be finite and positive")
    a = np.einsum("...i,...i->...", d, d)
    b = np.einsum("...i,...i->...", o, d)
    c = np.einsum("...i,...i->...", o, o) - r * r
    s = _nearest_positive_root(a, b, c)
    return _finish(o + s[..., None] * d, on_miss, "the sphere")


class DtmSampler:
    """Bilinear height lookup in a lat/lon DTM.

    Parameters
    ----------
    dtm : xarray.DataArray
        Heights, metres above the reference sphere, with dimensions ``lat``
        and ``lon`` (degrees, planetocentric, east-positive; either order,
        ascending or descending; longitudes in [-180, 180] or [0, 360]).

    Notes
    -----
    Queries outside the grid (or next to NaN nodes) give NaN; longitudes of
    queries are wrapped into the DTM's longitude convention first.
    """

    def __init__(self, dtm: xr.DataArray) -> None:
        if not isinstance(dtm, xr.DataArray):
            raise InvalidInputError(f"dtm must be an xarray.DataArray, got {type(dtm).__name__}")
        if set(dtm.dims) != {"lat", "lon"}:
            raise InvalidInputError(f"dtm must have dims ('lat', 'lon'), got {dtm.dims}")
        da = dtm.transpose("lat", "lon")
        lat = np.asarray(da["lat"].values, dtype=float)
        lon = np.asarray(da["lon"].values, dtype=float)
        z = np.asarray(da.values, dtype=float)
        if lat.size < 2 or lon.size < 2:
            raise InvalidInputError("dtm needs at least 2 x 2 nodes")
        if lat[0] > lat[-1]:
            lat, z = lat[::-1], z[::-1, :]
        if lon[0] > lon[-1]:
            lon, z = lon[::-1], z[:, ::-1]
        if np.any(np.diff(lat) <= 0) or np.any(np.diff(lon) <= 0):
            raise InvalidInputError("dtm lat/lon coordinates must be strictly monotonic")
        if not np.any(np.isfinite(z)):
            raise InvalidInputError("dtm holds no finite height")
        self.lat = lat
        self.lon = lon
        self.z = np.ascontiguousarray(z)
        self._lon360 = bool(lon[-1] > 180.0)
        self.min_height = float(np.nanmin(z))
        self.max_height = float(np.nanmax(z))

    def __call__(self, lon: ArrayLike, lat: ArrayLike) -> Array:
        """Heights (metres) at ``lon``, ``lat`` (degrees); NaN outside the grid."""
        lon = np.asarray(lon, dtype=float)
        lat = np.asarray(lat, dtype=float)
        lon = np.mod(lon, 360.0) if self._lon360 else np.mod(lon + 180.0, 360.0) - 180.0
        i = np.clip(np.searchsorted(self.lat, lat, side="right") - 1, 0, self.lat.size - 2)
        j = np.clip(np.searchsorted(self.lon, lon, side="right") - 1, 0, self.lon.size - 2)
        u = (lat - self.lat[i]) / (self.lat[i + 1] - self.lat[i])
        v = (lon - self.lon[j]) / (self.lon[j + 1] - self.lon[j])
        z = self.z
        h = ((1.0 - u) * ((1.0 - v) * z[i, j] + v * z[i, j + 1])
             + u * ((1.0 - v) * z[i + 1, j] + v * z[i + 1, j + 1]))
        outside = (u < 0.0) | (u > 1.0) | (v < 0.0) | (v > 1.0) | np.isnan(lat) | np.isnan(lon)
        return np.where(outside, np.nan, h)


def _lonlat(points: Array) -> tuple[Array, Array]:
    lon = np.degrees(np.arctan2(points[..., 1], points[..., 0]))
    lat = np.degrees(np.arctan2(points[..., 2], np.hypot(points[..., 0], points[..., 1])))
    return lon, lat


def surface_points_on_dtm(point_at: Callable[[NDArray[np.intp], Array], Array], n: int,
                          dtm: xr.DataArray | DtmSampler, radius: float, tol: float = 1e-3,
                          max_iter: int = 100) -> Array:
    """Points of ``n`` one-parameter loci (rays, SAR range circles) where they meet a DTM; NaN where none.

    ``point_at(idx, r)`` gives the points ``(len(idx), 3)`` where loci ``idx`` cross the sphere of radius
    ``r`` (metres; NaN rows where they do not). The height ``h`` of the crossing solves
    ``dtm(point_at(radius + h)) = h`` with the safeguarded secant iteration of :func:`intersect_dtm`.

    Raises
    ------
    ConvergenceError
        The iteration did not converge within ``max_iter`` for some locus.
    """
    sampler = dtm if isinstance(dtm, DtmSampler) else DtmSampler(dtm)

    def f_at(idx: NDArray[np.intp], h: Array) -> tuple[Array, Array]:
        p = point_at(idx, radius + h)
        lon, lat = _lonlat(p)
        f = sampler(lon, lat) - h
        # A locus that misses the sphere R+h stays above height h everywhere,
        # which is the same side of the terrain as f < 0.
        f = np.where(np.isnan(p[:, 0]), -1.0, f)
        return f, p

    out = np.full((n, 3), np.nan)
    lo = np.full(n, sampler.min_height - 1.0)
    hi = np.full(n, sampler.max_height + 1.0)
    idx_all = np.arange(n)
    # Loci missing the lowest sphere miss the terrain altogether.
    failed = np.isnan(point_at(idx_all, radius + lo)[:, 0])
    # First guess: the DTM height under the crossing of the mid-range sphere.
    f_mid, _ = f_at(idx_all, 0.5 * (lo + hi))
    h = np.clip(0.5 * (lo + hi) + f_mid, lo, hi)
    h = np.where(np.isnan(h), 0.5 * (lo + hi), h)
    h_prev = np.full(n, np.nan)
    f_prev = np.full(n, np.nan)
    active = np.flatnonzero(~failed)
    for _ in range(max_iter):
        if active.size == 0:
            break
        ha = h[active]
        f, p = f_at(active, ha)
        bad = np.isnan(f)  # left the DTM extent or hit a hole
        if np.any(bad):
            failed[active[bad]] = True
        pos = f > 0.0
        lo[active] = np.where(pos & ~bad, ha, lo[active])
        hi[active] = np.where(~pos & ~bad, ha, hi[active])
        hp, fp = h_prev[active], f_prev[active]
        with np.errstate(divide="ignore", invalid="ignore"):
            secant = ha - f * (ha - hp) / (f - fp)
        new = np.where(np.isfinite(secant), secant, ha + f)
        mid = 0.5 * (lo[active] + hi[active])
        # Bisect when the step leaves the bracket or |f| did not halve (stalling).
        stall = np.isfinite(fp) & (np.abs(f) > 0.5 * np.abs(fp))
        outside = ~((new > lo[active]) & (new < hi[active]))
        new = np.where(outside | stall, mid, new)
        new = np.where(f == 0.0, ha, new)
        done = (np.abs(new - ha) < tol) | (f == 0.0) | (hi[active] - lo[active] < tol)
        done &= ~bad
        conv = active[done]
        out[conv] = point_at(conv, radius + new[done])
        h_prev[active] = ha
        f_prev[active] = f
        h[active] = new
        active = active[~done & ~bad]
    if active.size:
        raise ConvergenceError(f"DTM intersection did not converge to {tol} m in {max_iter} iterations "
                               f"for {active.size} of {n} ray(s)")
    out[failed] = np.nan
    return out


def intersect_dtm(origins: ArrayLike, directions: ArrayLike, dtm: xr.DataArray | DtmSampler,
                  radius: float, tol: float = 1e-3, max_iter: int = 100,
                  on_miss: OnMiss = "raise") -> Array:
    """Intersection of rays with a DTM on a reference sphere.

    The height ``h`` of the intersection solves ``f(h) = dtm(P(h)) - h = 0``
    where ``P(h)`` is the ray's nearest intersection with the sphere of radius
    ``radius + h``. Starting from a fixed-point step (``h <- dtm(P(h))``, the
    classic iteration), the solution is refined by secant steps, each kept
    inside a bracket ``[lo, hi]`` with ``f(lo) > 0 > f(hi)`` (initially the DTM's
    height range widened by 1 m) and replaced by bisection when it leaves the
    bracket or stalls, so steep terrain, where plain fixed-point iteration
    oscillates or diverges, still converges.

    Parameters
    ----------
    origins, directions : array_like, shape (n, 3)
        Ray origins (metres) and directions, body-fixed.
    dtm : xarray.DataArray or DtmSampler
        Heights (metres above ``radius``) on a ``lat`` x ``lon`` grid, degrees.
    radius : float
        Reference sphere radius of the DTM, metres.
    tol : float
        Convergence threshold on the height change, metres (default 1 mm).
    max_iter : int
        Iteration limit.
    on_miss : {"raise", "nan"}
        What to do for rays that miss the DTM (or leave its extent).

    Returns
    -------
    ndarray, shape (n, 3)
        Intersection points, metres.

    Raises
    ------
    NoIntersectionError
        Some ray misses the DTM and ``on_miss="raise"``.
    ConvergenceError
        The iteration did not converge within ``max_iter`` for some ray.

    Notes
    -----
    Where a ray crosses the terrain several times (grazing rays over
    ridges), the root found is the one the iteration converges to from the
    first-guess height, normally the first crossing but not guaranteed.
    """
    _check_on_miss(on_miss)
    o, d = _rays(origins, directions)
    shape = o.shape[:-1]
    o = o.reshape(-1, 3)
    d = d.reshape(-1, 3)

    def point_at(idx: NDArray[np.intp], r: Array) -> Array:
        return intersect_sphere(o[idx], d[idx], r, on_miss="nan")

    out = surface_points_on_dtm(point_at, o.shape[0], dtm, radius, tol=tol, max_iter=max_iter)
    return _finish(out.reshape(shape + (3,)), on_miss, "the DTM (outside its extent or on a hole)")
