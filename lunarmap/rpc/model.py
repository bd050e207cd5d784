"""The cubic rational function model (RFM) of an image and its analytic partials.

Model (LROC multi-image study, ``seeds/001``, Eqs. 11-12; NITF RPC00B)::

    r = P1(X, Y, Z) / P2(X, Y, Z)        c = P3(X, Y, Z) / P4(X, Y, Z)

with ``X = (lon - LON_OFF) / LON_SCALE``, ``Y = (lat - LAT_OFF) / LAT_SCALE``,
``Z = (h - HEIGHT_OFF) / HEIGHT_SCALE`` and ``line = r * LINE_SCALE +
LINE_OFF``, ``sample = c * SAMP_SCALE + SAMP_OFF``; each ``Pi`` is a cubic
with the 20 terms of :mod:`lunarmap.rpc.terms`.

Conventions
-----------
* Image coordinates are lunarmap's (USGS CSM): continuous ``(line,
  sample)``, centre of the first pixel at ``(0.5, 0.5)``. GDAL's RPC files
  put ``(0, 0)`` at the centre of the first pixel; :mod:`lunarmap.rpc.io`
  converts (``LINE_OFF_file = LINE_OFF - 0.5``).
* Ground coordinates are planetocentric latitude and east-positive longitude
  in degrees and height in metres above the reference sphere of radius
  ``radius`` (the camera shape's ``reference_radius``; 1737.4 km for the
  Moon). Longitudes are reduced to ``LON_OFF +- 180`` before normalising,
  so images across the 180 degree meridian work.
* Array arguments follow :mod:`lunarmap.camera.geodesy`: ``(lon, lat,
  height)``, and so do the columns of the partial derivatives.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from ..camera.geodesy import lonlat_height_to_xyz, xyz_to_lonlat_height
from ..camera.shape import MOON_RADIUS
from ..errors import GeometryError, RpcConvergenceError, RpcFormatError, RpcInputError
from .terms import N_TERMS, TERM_NAMES, rpc_term_gradients, rpc_terms

__all__ = ["RationalFunctionModel", "POLYNOMIALS", "COORDINATES"]

Array = NDArray[np.float64]

#: Order of the four polynomials in :attr:`RationalFunctionModel.coefficients`.
POLYNOMIALS = ("line_num", "line_den", "samp_num", "samp_den")
#: Order of the offsets and scales in :attr:`RationalFunctionModel.offsets`.
COORDINATES = ("line", "sample", "lat", "lon", "height")

_NEWTON_MAX = 30
# image_to_ground stops when the normalised ground step is below this
# (1e-13 of a scale of a few km is < 1 nm).
_NEWTON_TOL = 1e-13


def _finite(name: str, *arrays: Array) -> None:
    for a in arrays:
        if not np.all(np.isfinite(a)):
            n = int(np.count_nonzero(~np.isfinite(a)))
            raise RpcInputError(f"{name}: {n} value(s) are NaN or infinite")


@dataclass(frozen=True)
class RationalFunctionModel:
    """A cubic RFM (RPC00B) mapping planetocentric ground coordinates to image coordinates.

    Parameters
    ----------
    coefficients : array_like, shape (4, 20)
        Rows ``line_num, line_den, samp_num, samp_den`` (:data:`POLYNOMIALS`),
        columns in RPC00B term order (:data:`~lunarmap.rpc.terms.TERM_NAMES`).
    offsets, scales : array_like, shape (5,)
        For ``line, sample`` (pixels, CSM convention), ``lat, lon``
        (degrees) and ``height`` (metres), in :data:`COORDINATES` order.
    radius : float
        Reference sphere radius of the heights, metres.
    n_lines, n_samples : int
        Image size, pixels (0 when unknown).
    attrs : dict
        Provenance and fit statistics (numbers and strings only).
    """

    coefficients: Array
    offsets: Array
    scales: Array
    radius: float = MOON_RADIUS
    n_lines: int = 0
    n_samples: int = 0
    attrs: dict[str, Any] = field(default_factory=dict)

    #: its rays (:meth:`rays`) do not start at a sensor position: no behind-camera or range bound applies
    rays_from_position = False

    def __post_init__(self) -> None:
        c = np.array(self.coefficients, dtype=float)
        o = np.array(self.offsets, dtype=float)
        s = np.array(self.scales, dtype=float)
        if c.shape != (4, N_TERMS):
            raise RpcFormatError(f"RPC coefficients must have shape (4, 20), got {c.shape}")
        if o.shape != (5,) or s.shape != (5,):
            raise RpcFormatError(f"RPC offsets and scales need 5 values each, got {o.shape} and {s.shape}")
        for name, a in (("coefficients", c), ("offsets", o), ("scales", s)):
            if not np.all(np.isfinite(a)):
                raise RpcFormatError(f"RPC {name} hold NaN or infinite values")
        if np.any(s == 0.0):
            bad = [COORDINATES[i] for i in np.flatnonzero(s == 0.0)]
            raise RpcFormatError(f"RPC scale of {', '.join(bad)} is zero")
        if not (np.isfinite(self.radius) and self.radius > 0.0):
            raise RpcFormatError(f"RPC reference radius must be finite and positive, got {self.radius}")
        for a in (c, o, s):
            a.setflags(write=False)
        object.__setattr__(self, "coefficients", c)
        object.__setattr__(self, "offsets", o)
        object.__setattr__(self, "scales", s)
        object.__setattr__(self, "radius", float(self.radius))
        object.__setattr__(self, "n_lines", int(self.n_lines))
        object.__setattr__(self, "n_samples", int(self.n_samples))
        object.__setattr__(self, "attrs", dict(self.attrs))

    def __repr__(self) -> str:
        o = self.offsets
        return (f"RationalFunctionModel({self.n_lines} x {self.n_samples} px, centre lat {o[2]:.4f}, "
                f"lon {o[3]:.4f} deg, height {o[4]:.0f} m)")

    # -- normalisation -------------------------------------------------------
    def normalize_ground(self, lon: ArrayLike, lat: ArrayLike, height: ArrayLike) -> tuple[Array, Array, Array]:
        """Normalised ``(X, Y, Z)`` of ground coordinates (degrees, degrees, metres)."""
        lon, lat, height = np.broadcast_arrays(np.asarray(lon, dtype=float), np.asarray(lat, dtype=float),
                                               np.asarray(height, dtype=float))
        _finite("ground coordinates", lon, lat, height)
        o, s = self.offsets, self.scales
        dlon = np.remainder(lon - o[3] + 180.0, 360.0) - 180.0  # nearest turn to LON_OFF
        return dlon / s[3], (lat - o[2]) / s[2], (height - o[4]) / s[4]

    def _image_from_normalized(self, x: Array, y: Array, z: Array) -> tuple[Array, Array]:
        t = rpc_terms(x, y, z)
        p = t @ self.coefficients.T  # (..., 4): N1, D1, N3, D3
        o, s = self.offsets, self.scales
        return p[..., 0] / p[..., 1] * s[0] + o[0], p[..., 2] / p[..., 3] * s[1] + o[1]

    # -- the SensorModel protocol (lunarmap.camera.sensor) ----------------------
    @property
    def reference_radius(self) -> float:
        """Radius of the height reference sphere, metres."""
        return self.radius

    def ground_to_image(self, xyz: ArrayLike, on_miss: str = "nan",
                        within_image: bool = True) -> tuple[Array, Array]:
        """Image coordinates of body-fixed ground points.

        Parameters
        ----------
        xyz : array_like, shape (..., 3)
            Body-fixed points, metres.
        on_miss : {"nan", "raise"}
            Points outside the image (with ``within_image`` and a known image size): NaN
            coordinates or :class:`~lunarmap.errors.GeometryError`.
        within_image : bool
            Treat coordinates outside ``[0, n_lines] x [0, n_samples]`` as not seen.

        Returns
        -------
        line, sample : ndarray, shape (...)
            Pixels, CSM convention.
        """
        if on_miss not in ("raise", "nan"):
            raise RpcInputError(f"on_miss must be 'raise' or 'nan', got {on_miss!r}")
        xyz = self._check_xyz(xyz)
        lon, lat, h = xyz_to_lonlat_height(xyz, self.radius)
        line, sample = self.lonlat_to_image(lon, lat, h)
        if within_image and self.n_lines > 0 and self.n_samples > 0:
            tol = 1e-6
            inside = (line >= -tol) & (line <= self.n_lines + tol) & (sample >= -tol) & (sample <= self.n_samples + tol)
            if on_miss == "raise" and not np.all(inside):
                raise GeometryError(f"{int(np.count_nonzero(~inside))} of {inside.size} ground point(s) fall "
                                    f"outside the {self.n_lines} x {self.n_samples} image of this RFM")
            line = np.where(inside, line, np.nan)
            sample = np.where(inside, sample, np.nan)
        return line, sample

    def lonlat_to_image(self, lon: ArrayLike, lat: ArrayLike, height: ArrayLike = 0.0) -> tuple[Array, Array]:
        """Image coordinates of planetocentric ground coordinates (Eq. 11 of ``seeds/001``).

        Parameters
        ----------
        lon, lat : array_like
            East longitude and planetocentric latitude, degrees.
        height : array_like
            Height above the reference sphere, metres.

        Returns
        -------
        line, sample : ndarray
            Image coordinates, pixels, CSM convention (not limited to the image).

        Raises
        ------
        RpcInputError
            NaN or infinite coordinates.
        """
        return self._image_from_normalized(*self.normalize_ground(lon, lat, height))

    def _check_xyz(self, xyz: ArrayLike) -> Array:
        xyz = np.asarray(xyz, dtype=float)
        if xyz.shape[-1:] != (3,):
            raise RpcInputError(f"ground points must have shape (..., 3), got {xyz.shape}")
        _finite("ground points", xyz)
        return xyz

    # -- partial derivatives -------------------------------------------------
    def jacobian(self, lon: ArrayLike, lat: ArrayLike, height: ArrayLike = 0.0) -> tuple[Array, Array, Array]:
        """Image coordinates and their analytic partials with respect to ``(lon, lat, height)``.

        Differentiates Eq. 11 of ``seeds/001`` by the quotient rule:
        ``d(N/D) = (dN D - N dD) / D^2``, times ``LINE_SCALE / LON_SCALE``
        etc. for the normalisations.

        Parameters
        ----------
        lon, lat : array_like
            East longitude and planetocentric latitude, degrees.
        height : array_like
            Height above the reference sphere, metres.

        Returns
        -------
        line, sample : ndarray, shape (...)
            Image coordinates, pixels (CSM convention).
        jac : ndarray, shape (..., 2, 3)
            Rows ``(line, sample)``; columns d/d(lon) and d/d(lat) in
            pixels per degree and d/d(height) in pixels per metre.
        """
        x, y, z = self.normalize_ground(lon, lat, height)
        return self._jacobian_normalized(x, y, z)

    def _jacobian_normalized(self, x: Array, y: Array, z: Array) -> tuple[Array, Array, Array]:
        t = rpc_terms(x, y, z)
        g = rpc_term_gradients(x, y, z)          # (..., 3, 20)
        c = self.coefficients
        p = t @ c.T                               # (..., 4)
        dp = g @ c.T                              # (..., 3, 4): d P_k / d coordinate
        o, s = self.offsets, self.scales
        jac = np.empty(x.shape + (2, 3))
        for row, (num, den) in enumerate(((0, 1), (2, 3))):
            n, d = p[..., num], p[..., den]
            jac[..., row, :] = (dp[..., :, num] * d[..., None] - n[..., None] * dp[..., :, den]) \
                / (d * d)[..., None] * s[row]
        # normalised (lon, lat, h) -> physical: columns divided by their scales
        jac /= np.array([s[3], s[2], s[4]])
        line = p[..., 0] / p[..., 1] * s[0] + o[0]
        sample = p[..., 2] / p[..., 3] * s[1] + o[1]
        return line, sample, jac

    def ground_partials(self, xyz: ArrayLike) -> tuple[Array, Array, Array]:
        """Image coordinates and their partials with respect to body-fixed ``(x, y, z)``.

        Chain rule through the planetocentric coordinates:
        ``d(lon)/d(x, y) = (-y, x) / rho^2`` and
        ``d(lat)/d(x, y, z) = (-z x / rho, -z y / rho, rho) / r^2`` (radians),
        ``d(h)/d(xyz) = xyz / r``.

        Parameters
        ----------
        xyz : array_like, shape (..., 3)
            Body-fixed points, metres.

        Returns
        -------
        line, sample : ndarray, shape (...)
            Image coordinates, pixels.
        jac : ndarray, shape (..., 2, 3)
            d(line, sample)/d(x, y, z), pixels per metre.
        """
        xyz = self._check_xyz(xyz)
        lon, lat, h = xyz_to_lonlat_height(xyz, self.radius)
        line, sample, j_llh = self.jacobian(lon, lat, h)
        X, Y, Z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
        rho2 = X * X + Y * Y
        rho = np.sqrt(rho2)
        r2 = rho2 + Z * Z
        r = np.sqrt(r2)
        deg = 180.0 / np.pi
        d = np.zeros(xyz.shape[:-1] + (3, 3))  # rows lon (deg), lat (deg), h (m); columns x, y, z
        d[..., 0, 0] = -Y / rho2 * deg
        d[..., 0, 1] = X / rho2 * deg
        d[..., 1, 0] = -Z * X / (rho * r2) * deg
        d[..., 1, 1] = -Z * Y / (rho * r2) * deg
        d[..., 1, 2] = rho / r2 * deg
        d[..., 2, :] = xyz / r[..., None]
        return line, sample, j_llh @ d

    # -- image to ground -----------------------------------------------------
    def image_to_lonlat(self, line: ArrayLike, sample: ArrayLike, height: ArrayLike = 0.0,
                        on_fail: str = "raise") -> tuple[Array, Array]:
        """Ground coordinates seen at image coordinates, at given heights (Newton iterations).

        Solves Eq. 11 of ``seeds/001`` for ``(lon, lat)`` at fixed height with
        Newton steps on the analytic 2 x 2 Jacobian, all points at once,
        starting from the centre of the normalised domain.

        Parameters
        ----------
        line, sample : array_like
            Image coordinates, pixels (CSM convention).
        height : array_like
            Height above the reference sphere, metres.
        on_fail : {"raise", "nan"}
            Points that do not converge: raise :class:`RpcConvergenceError`
            or return NaN.

        Returns
        -------
        lon, lat : ndarray
            East longitude and planetocentric latitude, degrees.
        """
        if on_fail not in ("raise", "nan"):
            raise RpcInputError(f"on_fail must be 'raise' or 'nan', got {on_fail!r}")
        line, sample, height = np.broadcast_arrays(np.asarray(line, dtype=float),
                                                   np.asarray(sample, dtype=float),
                                                   np.asarray(height, dtype=float))
        _finite("image coordinates and heights", line, sample, height)
        shape = line.shape
        o, s = self.offsets, self.scales
        rn = ((line - o[0]) / s[0]).ravel()
        cn = ((sample - o[1]) / s[1]).ravel()
        z = ((height - o[4]) / s[4]).ravel()
        x = np.zeros_like(rn)
        y = np.zeros_like(rn)
        act = np.arange(rn.size)
        for _ in range(_NEWTON_MAX):
            if act.size == 0:
                break
            li, sa, jac = self._jacobian_normalized(x[act], y[act], z[act])
            # residual and Jacobian in normalised image units per normalised ground unit
            er = (li - o[0]) / s[0] - rn[act]
            ec = (sa - o[1]) / s[1] - cn[act]
            a = jac[:, 0, 0] * s[3] / s[0]
            b = jac[:, 0, 1] * s[2] / s[0]
            c = jac[:, 1, 0] * s[3] / s[1]
            d = jac[:, 1, 1] * s[2] / s[1]
            det = a * d - b * c
            with np.errstate(divide="ignore", invalid="ignore"):
                dx = (d * er - b * ec) / det
                dy = (-c * er + a * ec) / det
            # damp steps that would leave the domain by far (bad start, far extrapolation)
            step = np.maximum(np.abs(dx), np.abs(dy))
            damp = np.where(step > 1.0, 1.0 / np.where(step > 0, step, 1.0), 1.0)
            x[act] -= damp * dx
            y[act] -= damp * dy
            bad = ~np.isfinite(x[act]) | ~np.isfinite(y[act])
            x[act[bad]] = np.nan
            y[act[bad]] = np.nan
            act = act[~bad & (step >= _NEWTON_TOL)]
        fail = np.zeros(rn.size, dtype=bool)
        fail[act] = True
        fail |= ~np.isfinite(x)
        if fail.any():
            if on_fail == "raise":
                raise RpcConvergenceError(f"RFM image_to_ground did not converge for {int(fail.sum())} of "
                                          f"{fail.size} point(s)")
            x[fail] = np.nan
            y[fail] = np.nan
        lon = x * s[3] + o[3]
        lon = np.remainder(lon + 180.0, 360.0) - 180.0
        lat = y * s[2] + o[2]
        return lon.reshape(shape), lat.reshape(shape)

    def image_to_ground(self, line: ArrayLike, sample: ArrayLike, height: ArrayLike = 0.0, dtm: Any = None,
                        on_miss: str = "raise", tol: float = 1e-3) -> Array:
        """Body-fixed ground points seen at image coordinates, at given heights or on a DTM.

        Parameters
        ----------
        line, sample : array_like
            Image coordinates, pixels (CSM convention).
        height : array_like
            Height above the reference sphere, metres (ignored with ``dtm``).
        dtm : xarray.DataArray or DtmSampler, optional
            Heights (metres above ``radius``) on ``lat`` x ``lon`` (degrees): the point is found
            by iterating height -> ``(lon, lat)`` -> DTM height.
        on_miss : {"raise", "nan"}
            Points that do not converge (or leave the DTM): raise, or NaN rows.
        tol : float
            DTM iteration threshold on height, metres.

        Returns
        -------
        ndarray, shape (..., 3)
            Body-fixed points, metres.
        """
        if on_miss not in ("raise", "nan"):
            raise RpcInputError(f"on_miss must be 'raise' or 'nan', got {on_miss!r}")
        line, sample = np.broadcast_arrays(np.asarray(line, dtype=float), np.asarray(sample, dtype=float))
        if dtm is None:
            h = np.broadcast_to(np.asarray(height, dtype=float), line.shape)
            lon, lat = self.image_to_lonlat(line, sample, h, on_fail=on_miss)
            return lonlat_height_to_xyz(lon, lat, h, self.radius)
        return self._image_to_dtm(line, sample, dtm, on_miss, tol)

    def _image_to_dtm(self, line: Array, sample: Array, dtm: Any, on_miss: str, tol: float) -> Array:
        from ..camera.intersect import DtmSampler

        sampler = dtm if isinstance(dtm, DtmSampler) else DtmSampler(dtm)
        h = np.full(line.shape, float(self.offsets[4]))
        lon = lat = np.full(line.shape, np.nan)
        done = np.zeros(line.shape, dtype=bool)
        for _ in range(50):
            lon, lat = self.image_to_lonlat(line, sample, h, on_fail="nan")
            with np.errstate(invalid="ignore"):
                h_new = sampler(lon, lat)
            step = h_new - h
            h = np.where(np.isfinite(h_new), h_new, h)
            done = np.isfinite(step) & (np.abs(step) < tol)
            if np.all(done | ~np.isfinite(step)):
                break
        bad = ~done
        if bad.any() and on_miss == "raise":
            raise RpcConvergenceError(f"RFM image_to_ground on the DTM failed for {int(bad.sum())} of {bad.size} "
                                      "point(s) (outside the DTM or no convergence)")
        xyz = lonlat_height_to_xyz(lon, lat, h, self.radius)
        return np.where(bad[..., None], np.nan, xyz)

    def rays(self, line: ArrayLike, sample: ArrayLike) -> tuple[Array, Array]:
        """Points at the top of the RFM's height range and unit directions down to its bottom (body-fixed).

        An RFM has no sensor position: its "ray" through a pixel is the line joining the ground
        points of that pixel at the highest and lowest heights it was fitted for.
        """
        lo, hi = self.height_range
        top = self.image_to_ground(line, sample, hi)
        d = self.image_to_ground(line, sample, lo) - top
        return top, d / np.linalg.norm(d, axis=-1, keepdims=True)

    def look_vector(self, line: ArrayLike, sample: ArrayLike) -> Array:
        """Unit vectors (body-fixed) from the top to the bottom of the height range, see :meth:`rays`."""
        return self.rays(line, sample)[1]

    def corrections(self, degree: int | None = None, origin: str = "center") -> Any:
        """Six affine image-space corrections (``seeds/001`` Eq. 13).

        ``origin``: ``"center"`` (the RFM's line/sample offsets: better conditioned) or ``"image"``
        (``(0, 0)``, Eq. 13 literally). ``degree`` is ignored (no time dependence).
        """
        from ..camera.corrections import AffineCorrections

        if origin not in ("center", "image"):
            raise RpcInputError(f"origin must be 'center' or 'image', got {origin!r}")
        o = (float(self.offsets[0]), float(self.offsets[1])) if origin == "center" else (0.0, 0.0)
        return AffineCorrections(self, o)

    # -- storage ---------------------------------------------------------------
    @property
    def height_range(self) -> tuple[float, float]:
        """Heights spanned by the normalisation, ``HEIGHT_OFF +- HEIGHT_SCALE``, metres."""
        return self.offsets[4] - abs(self.scales[4]), self.offsets[4] + abs(self.scales[4])

    def with_attrs(self, **attrs: Any) -> "RationalFunctionModel":
        """A copy with extra attributes."""
        merged = dict(self.attrs)
        merged.update(attrs)
        return RationalFunctionModel(self.coefficients, self.offsets, self.scales, self.radius,
                                     self.n_lines, self.n_samples, merged)

    def to_dataset(self) -> xr.Dataset:
        """The model as an :class:`xarray.Dataset`.

        Variables ``coefficients (polynomial, term)``, ``offset (coordinate)``
        and ``scale (coordinate)``; the reference radius, image size,
        conventions, fit statistics and provenance are attributes.
        """
        attrs: dict[str, Any] = {
            "rpc_model": "RPC00B cubic rational function (seeds/001 Eqs. 11-12)",
            "pixel_convention": "CSM: continuous (line, sample), centre of the first pixel at (0.5, 0.5)",
            "ground_convention": "planetocentric latitude, east-positive longitude (degrees), "
                                 "height above the reference sphere (metres)",
            "reference_radius_m": self.radius,
            "n_lines": self.n_lines,
            "n_samples": self.n_samples,
        }
        for k, v in self.attrs.items():
            attrs[k] = _netcdf_attr(v)
        units = {"line": "pixel", "sample": "pixel", "lat": "degree", "lon": "degree", "height": "metre"}
        return xr.Dataset(
            {
                "coefficients": (("polynomial", "term"), np.array(self.coefficients)),
                "offset": (("coordinate",), np.array(self.offsets),
                           {"units": ", ".join(f"{k}: {units[k]}" for k in COORDINATES)}),
                "scale": (("coordinate",), np.array(self.scales),
                          {"units": ", ".join(f"{k}: {units[k]}" for k in COORDINATES)}),
            },
            coords={"polynomial": list(POLYNOMIALS), "term": list(TERM_NAMES), "coordinate": list(COORDINATES)},
            attrs=attrs,
        )

    @classmethod
    def from_dataset(cls, ds: xr.Dataset) -> "RationalFunctionModel":
        """The model stored by :meth:`to_dataset`.

        Raises
        ------
        RpcFormatError
            Missing variables or attributes, or values of the wrong shape.
        """
        try:
            coeffs = ds["coefficients"].transpose("polynomial", "term").sel(
                polynomial=list(POLYNOMIALS), term=list(TERM_NAMES)).values
            offsets = ds["offset"].sel(coordinate=list(COORDINATES)).values
            scales = ds["scale"].sel(coordinate=list(COORDINATES)).values
            radius = float(ds.attrs["reference_radius_m"])
            n_lines = int(ds.attrs.get("n_lines", 0))
            n_samples = int(ds.attrs.get("n_samples", 0))
        except (KeyError, ValueError, TypeError, IndexError, OverflowError) as exc:
            raise RpcFormatError(f"dataset is not an RPC model written by lunarmap: {exc}") from exc
        skip = {"rpc_model", "pixel_convention", "ground_convention", "reference_radius_m", "n_lines",
                "n_samples"}
        attrs = {k: v for k, v in ds.attrs.items() if k not in skip}
        return cls(coeffs, offsets, scales, radius, n_lines, n_samples, attrs)


def _netcdf_attr(v: Any) -> Any:
    """A value netCDF can store as an attribute (numbers, strings, 1-d numeric arrays)."""
    if isinstance(v, (bool, np.bool_)):
        return int(v)
    if isinstance(v, (int, float, str, np.integer, np.floating)):
        return v
    if isinstance(v, (list, tuple, np.ndarray)):
        a = np.asarray(v)
        if a.dtype.kind in "biuf" and a.ndim == 1:
            return a.astype(float if a.dtype.kind == "f" else np.int64)
    return str(v)
