"""Synthetic-aperture radar (LRO Mini-RF) in zero-Doppler slant-range geometry (usgscsm's SAR model).

Geometry (``UsgsAstroSarSensorModel``)
-------------------------------------
Image line ``L`` is the zero-Doppler time ``t = t_start + (L - 0.5) dt``: the ground point lies in
the plane through the sensor ``P(t)`` perpendicular to its body-fixed velocity ``V(t)``. Sample ``S``
is the ground range ``g = (S - 0.5) w``, and the slant range ``|G - P(t)| = c0 + c1 g + c2 g² + c3 g³``
with the range-conversion coefficients interpolated to ``t``. The ground point is where the circle of
that radius about ``P`` in the zero-Doppler plane meets the surface, on the look side (right or left
of the ground track, ``u = v̂ × t̂`` with ``t̂`` the radial direction perpendicular to ``V``).

The range-conversion sets are interpolated in time as usgscsm does (``getRangeCoefficients``):
Lagrange interpolation of up to 8th order on nodes assumed equally spaced from the first set's time
with spacing ``(t_last - t_first) / m`` for ``m`` sets (usgscsm's rule, not the sets' own times; for
Mini-RF's sets, ~15 s apart, the two readings differ by up to about a pixel, see the README).

Sensor positions and velocities come from the exterior orientation (cubic Hermite of the ISD's
states; usgscsm uses 8th-order Lagrange on a resampled grid: the two agree to micrometres on
smooth orbits).

Image to ground is closed form on a sphere (the circle meets a sphere of radius ``R + h``), iterated
on an ellipsoid, and solved with :func:`~lunarmap.camera.intersect.surface_points_on_dtm` on a DTM.
Ground to image solves the zero-Doppler condition ``(P(t) - G) . V(t) = 0`` by a bracketed secant
iteration (all points at once), then the slant-range cubic by Newton iteration from usgscsm's guess
(mid-swath). All partial derivatives are analytic (implicit-function rule through the Doppler
condition and the range cubic).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicSpline

from ..errors import ConvergenceError, InvalidInputError
from ..orientation.exterior import ExteriorOrientation
from ..orientation.isd import ImageSupport
from .frame import _check_ground_on_miss, _finite_pixels, _finite_xyz, finish_ground_to_image, occluded_by_body
from .intersect import DtmSampler, OnMiss, _finish, surface_points_on_dtm
from .shape import Shape

__all__ = ["SarSensor", "RangeConversion", "SarCorrections"]

Array = NDArray[np.float64]

_COARSE = 64            # times tabulated to bracket zero-Doppler times
_TIME_TOL = 1e-10       # s, zero-Doppler time convergence
_RANGE_TOL = 1e-9       # m, ground-range convergence
_MAX_ITER = 60


def _lagrange_weights(s: Array, start: NDArray[np.intp], order: int) -> tuple[Array, Array]:
    """Lagrange basis values and derivatives (per unit of ``s``) at ``s`` on integer nodes ``start + i``."""
    nodes = start[:, None] + np.arange(order)[None, :]
    diff = s[:, None] - nodes                                  # (n, order)
    w = np.ones((s.size, order))
    dw = np.zeros((s.size, order))
    for i in range(order):
        denom = 1.0
        for m in range(order):
            if m != i:
                denom *= float(i - m)
        prod = np.ones(s.size)
        dprod = np.zeros(s.size)
        for m in range(order):
            if m == i:
                continue
            dprod = dprod * diff[:, m] + prod
            prod = prod * diff[:, m]
        w[:, i] = prod / denom
        dw[:, i] = dprod / denom
    return w, dw


class RangeConversion:
    """Range-conversion coefficients in time, interpolated as usgscsm's ``getRangeCoefficients``.

    Parameters
    ----------
    times : array_like (m,)
        Times of the sets, s (any origin; the same as the times given to :meth:`at`).
    coefficients : array_like (m, 4)
        Ground range (m) -> slant range (m) cubic coefficients ``c0 .. c3`` of each set.
    """

    def __init__(self, times: ArrayLike, coefficients: ArrayLike) -> None:
        self.times = np.atleast_1d(np.asarray(times, dtype=float))
        self.coefficients = np.asarray(coefficients, dtype=float).reshape(-1, 4)
        m = self.times.size
        if m == 0 or self.coefficients.shape[0] != m:
            raise InvalidInputError(f"range conversion needs one set of 4 coefficients per time, got "
                                    f"{self.coefficients.shape[0]} sets for {m} times")
        # usgscsm's spacing: (last - first) / m, not / (m - 1)
        self.step = (self.times[-1] - self.times[0]) / m if m > 1 else 0.0

    def at(self, t: ArrayLike) -> tuple[Array, Array]:
        """Coefficients ``(n, 4)`` at times ``t`` and their time derivatives ``(n, 4)`` (per s)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        m = self.times.size
        if m == 1:
            return np.broadcast_to(self.coefficients[0], (t.size, 4)).copy(), np.zeros((t.size, 4))
        s = (t - self.times[0]) / self.step
        index = np.clip(np.floor(s), 0, m - 2).astype(np.intp)
        order = np.where((index >= 3) & (index < m - 4), 8,
                         np.where((index >= 2) & (index < m - 3), 6, np.where((index >= 1) & (index < m - 2), 4, 2)))
        c = np.empty((t.size, 4))
        dc = np.empty((t.size, 4))
        for o in np.unique(order):
            sel = np.flatnonzero(order == o)
            start = index[sel] - o // 2 + 1
            w, dw = _lagrange_weights(s[sel], start, int(o))
            rows = self.coefficients[start[:, None] + np.arange(o)[None, :]]    # (k, o, 4)
            c[sel] = np.einsum("ko,koc->kc", w, rows)
            dc[sel] = np.einsum("ko,koc->kc", dw, rows) / self.step
        return c, dc


def _poly(c: Array, g: Array) -> Array:
    return c[:, 0] + g * (c[:, 1] + g * (c[:, 2] + g * c[:, 3]))


def _dpoly(c: Array, g: Array) -> Array:
    return c[:, 1] + g * (2.0 * c[:, 2] + 3.0 * g * c[:, 3])


class SarSensor:
    """A side-looking SAR image in zero-Doppler geometry; implements :class:`~lunarmap.camera.SensorModel`.

    Parameters
    ----------
    eo : ExteriorOrientation
        Sensor trajectory (positions and velocities; the attitude is not used).
    shape : Shape
        Body shape.
    n_lines, n_samples : int
        Image size.
    t_start : float
        Zero-Doppler time of the top edge of line 0 (``L = 0.5`` is ``t_start``... see the module
        docstring: ``t = t_start + (L - 0.5) dt``), s after ``eo.epoch``.
    line_period : float
        Seconds per image line.
    pixel_width : float
        Ground range per sample, m.
    range_conversion : RangeConversion
        Coefficient sets, times relative to ``eo.epoch``.
    look_direction : {"left", "right"}
        Side of the track the radar looks at.
    t_end : float, optional
        End of the image, s after ``eo.epoch`` (zero-Doppler times are searched within the image span
        widened by 25 % at each end, as usgscsm does); default the last line.
    wavelength : float
        Radar wavelength, m (kept for the ISD; the geometry does not depend on it).
    name : str
        For messages.
    """

    def __init__(self, eo: ExteriorOrientation, shape: Shape, n_lines: int, n_samples: int, t_start: float,
                 line_period: float, pixel_width: float, range_conversion: RangeConversion, look_direction: str,
                 t_end: float | None = None, wavelength: float = float("nan"), name: str = "") -> None:
        if not isinstance(eo, ExteriorOrientation):
            raise InvalidInputError(f"eo must be an ExteriorOrientation, got {type(eo).__name__}")
        if eo.times.size < 2:
            raise InvalidInputError("a SAR sensor needs at least 2 trajectory samples (velocities define the geometry)")
        if not (line_period > 0.0 and pixel_width > 0.0):
            raise InvalidInputError(f"line period and pixel width must be positive, got {line_period!r}, "
                                    f"{pixel_width!r}")
        look = str(look_direction).lower()
        if look not in ("left", "right"):
            raise InvalidInputError(f"look direction must be 'left' or 'right', got {look_direction!r}")
        self.eo, self.shape = eo, shape
        self._n_lines, self._n_samples = int(n_lines), int(n_samples)
        self.t_start, self.line_period, self.pixel_width = float(t_start), float(line_period), float(pixel_width)
        self.range_conversion = range_conversion
        self.look_direction = look
        self.t_end = float(t_start + n_lines * line_period if t_end is None else t_end)
        self.wavelength = float(wavelength)
        self.name = name
        self._side = 1.0 if look == "right" else -1.0
        # The Doppler condition uses the velocity samples themselves, interpolated, as usgscsm does
        # (Lagrange on them), not the derivative of the position spline: ISD states corrected for light
        # time (Mini-RF: LT+S) have velocities that are not the positions' derivative (by ~3 mm/s for
        # usgscsm's orbitalSar.json), which moves the zero-Doppler time by ~1e-5 s (2 cm).
        self._velocity = CubicSpline(eo.times, eo.velocities, axis=0)

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state.pop("_velocity")
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._velocity = CubicSpline(self.eo.times, self.eo.velocities, axis=0)

    def velocity_at(self, t: ArrayLike) -> Array:
        """Sensor velocity (m/s, body-fixed) defining the zero-Doppler planes, at times ``t`` (s after epoch)."""
        return self._velocity(np.asarray(t, dtype=float))

    def _velocity_rate(self, t: Array) -> Array:
        return self._velocity(t, 1)

    @classmethod
    def from_image_support(cls, isd: ImageSupport, shape: Shape) -> "SarSensor":
        """The SAR sensor of an ISD (``model == "sar"``)."""
        if isd.sar is None:
            raise InvalidInputError(f"ISD of {isd.name_sensor!r} is a {isd.model} image, not SAR")
        eo = isd.exterior_orientation()
        p = isd.sar
        return cls(eo, shape, isd.image_lines, isd.image_samples, isd.starting_ephemeris_time - eo.epoch,
                   p.line_exposure_duration, p.scaled_pixel_width,
                   RangeConversion(p.range_conversion_times - eo.epoch, p.range_conversion_coefficients),
                   p.look_direction, t_end=p.ending_ephemeris_time - eo.epoch, wavelength=p.wavelength,
                   name=isd.name_sensor)

    def __repr__(self) -> str:
        return (f"SarSensor({self.name or 'unnamed'}, {self._n_lines} x {self._n_samples}, "
                f"{self.pixel_width} m/sample, looking {self.look_direction})")

    # -- SensorModel basics --------------------------------------------------------
    @property
    def n_lines(self) -> int:
        return self._n_lines

    @property
    def n_samples(self) -> int:
        return self._n_samples

    @property
    def reference_radius(self) -> float:
        return float(self.shape.reference_radius)

    @property
    def center_time(self) -> float:
        """Zero-Doppler time of the middle line, ephemeris seconds."""
        return float(self.eo.epoch + self.image_time(0.5 * self._n_lines))

    def image_time(self, line: ArrayLike) -> Array:
        """Zero-Doppler time (s after ``eo.epoch``) of image lines."""
        return self.t_start + (np.asarray(line, dtype=float) - 0.5) * self.line_period

    def sensor_position(self, line: ArrayLike, sample: ArrayLike) -> Array:
        """Sensor position (metres, body-fixed) at the zero-Doppler time of image coordinates."""
        line, sample = _finite_pixels(line, sample)
        return self.eo.position_at(self.image_time(line))

    def corrections(self, degree: int | None = 1) -> "SarCorrections":
        """Position correction polynomials of ``degree`` (0-2) in time (:class:`SarCorrections`)."""
        return SarCorrections(self, 1 if degree is None else degree)

    # -- image to ground ---------------------------------------------------------------
    def _range_circle(self, line: Array, sample: Array) -> tuple[Array, Array, Array, Array, Array]:
        """Sensor position, zero-Doppler frame (t̂, û) and slant range of image coordinates (flat arrays)."""
        t = self.image_time(line)
        c, _ = self.range_conversion.at(t)
        rho = _poly(c, (sample - 0.5) * self.pixel_width)
        P, V = self.eo.position_at(t), self.velocity_at(t)
        vhat = V / np.linalg.norm(V, axis=1, keepdims=True)
        radial = P - np.einsum("ni,ni->n", P, vhat)[:, None] * vhat
        that = radial / np.linalg.norm(radial, axis=1, keepdims=True)
        uhat = np.cross(vhat, that)
        return P, that, uhat, rho, t

    def _circle_at_radius(self, P: Array, that: Array, uhat: Array, rho: Array, r: Array) -> Array:
        """Where the range circles meet spheres of radius ``r`` on the look side; NaN rows where they do not."""
        nadir = np.einsum("ni,ni->n", P, that)
        alpha = (r * r - rho * rho - np.einsum("ni,ni->n", P, P)) / (2.0 * nadir)
        with np.errstate(invalid="ignore"):
            beta = self._side * np.sqrt(rho * rho - alpha * alpha)
        return P + alpha[:, None] * that + beta[:, None] * uhat

    def image_to_ground(self, line: ArrayLike, sample: ArrayLike, height: ArrayLike = 0.0,
                        dtm: xr.DataArray | DtmSampler | None = None, on_miss: OnMiss = "raise",
                        tol: float = 1e-3) -> Array:
        """Ground points (body-fixed metres, ``(..., 3)``) at image coordinates, at ``height`` or on a DTM.

        Raises
        ------
        InvalidInputError
            NaN or infinite coordinates or heights.
        NoIntersectionError
            The range circle misses the surface and ``on_miss="raise"``.
        """
        line, sample = _finite_pixels(line, sample)
        shape = line.shape
        P, that, uhat, rho, _ = self._range_circle(line.ravel(), sample.ravel())
        if dtm is not None:
            def point_at(idx: NDArray[np.intp], r: Array) -> Array:
                return self._circle_at_radius(P[idx], that[idx], uhat[idx], rho[idx], r)

            out = surface_points_on_dtm(point_at, P.shape[0], dtm, self.shape.reference_radius, tol=tol)
            return _finish(out.reshape(shape + (3,)), on_miss, "the DTM")
        h = np.asarray(height, dtype=float)
        if not np.all(np.isfinite(h)):
            raise InvalidInputError("heights hold NaN or infinite values")
        h = np.broadcast_to(h, shape).ravel()
        axes = self.shape.axes_at_height(h)
        axes = np.broadcast_to(axes, (h.size, 3))
        r = axes[:, 0].copy()
        G = self._circle_at_radius(P, that, uhat, rho, r)
        if not np.allclose(axes, axes[:, :1], rtol=0.0, atol=0.0):
            # an ellipsoid: adjust the sphere until the point lies on it (usgscsm iterates the same way)
            for _ in range(_MAX_ITER):
                scale = np.linalg.norm(G / axes, axis=1)
                dr = np.linalg.norm(G, axis=1) * (1.0 - 1.0 / scale)
                r = r - dr
                G = self._circle_at_radius(P, that, uhat, rho, r)
                if not np.any(np.abs(dr) > 1e-9 * r):
                    break
        return _finish(G.reshape(shape + (3,)), on_miss, "the body (range circle)")

    def rays(self, line: ArrayLike, sample: ArrayLike) -> tuple[Array, Array]:
        """Sensor positions and unit directions towards the ground point at height 0 (NaN where none).

        A SAR pixel's imaging locus is a circle, not a ray: this is usgscsm's "remote imaging locus".
        """
        line, sample = _finite_pixels(line, sample)
        P = self.eo.position_at(self.image_time(line))
        G = self.image_to_ground(line, sample, 0.0, on_miss="nan")
        d = G - P
        return P, d / np.linalg.norm(d, axis=-1, keepdims=True)

    def look_vector(self, line: ArrayLike, sample: ArrayLike) -> Array:
        """Unit vectors from the sensor to the ground point at height 0 of image coordinates."""
        return self.rays(line, sample)[1]

    # -- ground to image -------------------------------------------------------------------
    def _zero_doppler(self, G: Array, offset: Any = None) -> Array:
        """Zero-Doppler times (s after ``eo.epoch``) of points ``(n, 3)``; NaN where none in the search span.

        ``offset(t) -> (dP, dV)`` adds position/velocity corrections (:class:`SarCorrections`).
        """
        pad = 0.25 * self._n_lines * self.line_period
        lo, hi = self.t_start - pad, self.t_end + pad

        def state(t: Array) -> tuple[Array, Array]:
            P, V = self.eo.position_at(t), self.velocity_at(t)
            if offset is not None:
                dP, dV = offset(t)
                P, V = P + dP, V + dV
            return P, V

        grid = np.linspace(lo, hi, _COARSE)
        Pg, Vg = (a.reshape(_COARSE, 3) for a in state(grid))
        f = np.einsum("ki,ki->k", Pg, Vg)[None, :] - G @ Vg.T           # (n, k)
        change = f[:, :-1] * f[:, 1:] <= 0.0
        has = change.any(axis=1)
        k = np.argmax(change, axis=1)
        n = G.shape[0]
        t = np.full(n, np.nan)
        idx = np.flatnonzero(has)
        if idx.size == 0:
            return t
        a, b = grid[k[idx]], grid[k[idx] + 1]
        fa, fb = f[idx, k[idx]], f[idx, k[idx] + 1]
        g = G[idx]
        side_a = np.zeros(idx.size)            # Illinois: halve the retained end's value when it repeats
        done = np.zeros(idx.size, dtype=bool)
        x = a.copy()
        for _ in range(_MAX_ITER):
            with np.errstate(divide="ignore", invalid="ignore"):
                x_new = np.where(fb != fa, b - fb * (b - a) / (fb - fa), 0.5 * (a + b))
            x_new = np.where((x_new > np.minimum(a, b)) & (x_new < np.maximum(a, b)), x_new, 0.5 * (a + b))
            P, V = state(x_new)
            fx = np.einsum("ni,ni->n", P - g, V)
            left = fx * fa > 0.0
            # replace the end with fx's sign; Illinois weighting of the other end
            a, fa = np.where(left, x_new, a), np.where(left, fx, fa)
            b, fb = np.where(left, b, x_new), np.where(left, fb, fx)
            fb = np.where(left & (side_a > 0), 0.5 * fb, fb)
            fa = np.where(~left & (side_a < 0), 0.5 * fa, fa)
            side_a = np.where(left, 1.0, -1.0)
            step = np.abs(x_new - x)
            x = x_new
            done = (step < _TIME_TOL) | (fx == 0.0) | (np.abs(b - a) < _TIME_TOL)
            if np.all(done):
                break
        if not np.all(done):
            raise ConvergenceError(f"zero-Doppler time did not converge for {int(np.sum(~done))} point(s)")
        t[idx] = x
        return t

    def _ground_range(self, rho: Array, c: Array) -> Array:
        """Ground range solving the slant-range cubic, Newton from usgscsm's mid-swath guess."""
        g = np.full(rho.shape, 0.5 * self._n_samples * self.pixel_width)
        for _ in range(_MAX_ITER):
            with np.errstate(divide="ignore", invalid="ignore"):
                step = (_poly(c, g) - rho) / _dpoly(c, g)
            g = g - step
            if not np.any(np.abs(step) > _RANGE_TOL):
                break
        return g

    def _image_of(self, G: Array, t: Array, P: Array, V: Array) -> tuple[Array, Array, Array, NDArray[np.bool_]]:
        """Line, sample, ground range and validity of points at their zero-Doppler times (finite ``t``)."""
        c, _ = self.range_conversion.at(t)
        d = G - P
        rho = np.linalg.norm(d, axis=1)
        g = self._ground_range(rho, c)
        vhat = V / np.linalg.norm(V, axis=1, keepdims=True)
        radial = P - np.einsum("ni,ni->n", P, vhat)[:, None] * vhat
        uhat = np.cross(vhat, radial)
        on_side = self._side * np.einsum("ni,ni->n", d, uhat) > 0.0
        line = (t - self.t_start) / self.line_period + 0.5
        sample = g / self.pixel_width + 0.5
        ok = on_side & np.isfinite(sample) & ~occluded_by_body(self.shape, P, G)
        return line, sample, g, ok

    def ground_to_image(self, xyz: ArrayLike, on_miss: OnMiss = "nan",
                        within_image: bool = True) -> tuple[Array, Array]:
        """Image coordinates of body-fixed ground points (module docstring).

        Points not seen: no zero-Doppler time within the image span widened by 25 % at each end, on the
        other side of the track than the radar looks, hidden by the body, or outside the image (with
        ``within_image``).
        """
        _check_ground_on_miss(on_miss)
        xyz = _finite_xyz(xyz)
        shape = xyz.shape[:-1]
        G = np.ascontiguousarray(xyz.reshape(-1, 3))
        t = self._zero_doppler(G)
        line = np.full(G.shape[0], np.nan)
        sample = np.full(G.shape[0], np.nan)
        ok = np.isfinite(t)
        idx = np.flatnonzero(ok)
        if idx.size:
            ti = t[idx]
            li, si, _, oi = self._image_of(G[idx], ti, self.eo.position_at(ti), self.velocity_at(ti))
            line[idx], sample[idx], ok[idx] = li, si, oi
        line, sample = finish_ground_to_image(line, sample, ok, self._n_lines, self._n_samples, within_image,
                                              on_miss, self.name)
        return line.reshape(shape), sample.reshape(shape)

    def ground_partials(self, xyz: ArrayLike) -> tuple[Array, Array, Array]:
        """Image coordinates and ``d(line, sample) / d(x, y, z)`` ``(..., 2, 3)`` (analytic), pixels per metre."""
        xyz = _finite_xyz(xyz)
        corr = self.corrections(degree=0)
        pix, _, jac = corr.partials(np.zeros(corr.n_params), xyz.reshape(-1, 3))
        shape = xyz.shape[:-1]
        return pix[:, 0].reshape(shape), pix[:, 1].reshape(shape), jac.reshape(shape + (2, 3))


class SarCorrections:
    """Sensor position corrections of a :class:`SarSensor`: polynomials ``c(tau) = sum_k c_k tau^k``.

    ``3 (degree + 1)`` parameters ``[c_0, c_1, ...]`` (metres, body-fixed; ``tau`` in [-1, 1] over the
    image lines), the velocity corrected by ``dc/dt`` alike, as usgscsm's SAR model adjusts position and
    velocity. The partials follow the implicit-function rule through the zero-Doppler condition
    ``(P + c - G) . (V + c') = 0`` and the slant-range cubic.

    Parameters
    ----------
    sensor : SarSensor
        The reference sensor.
    degree : int
        0, 1 or 2.
    """

    def __init__(self, sensor: SarSensor, degree: int = 1) -> None:
        if degree not in (0, 1, 2):
            raise InvalidInputError(f"SAR correction degree must be 0, 1 or 2, got {degree!r}")
        self.sensor = sensor
        self.degree = int(degree)
        self.n_params = 3 * (self.degree + 1)
        self.names = tuple(f"c{ax}_{k}" for k in range(self.degree + 1) for ax in "xyz")
        self.units = ("m",) * self.n_params
        t0, t1 = sensor.image_time(np.array([0.5, sensor.n_lines + 0.5]))
        self.t_mid = 0.5 * float(t0 + t1)
        self.t_half = 0.5 * float(t1 - t0)

    def __repr__(self) -> str:
        return f"SarCorrections({self.sensor!r}, degree={self.degree})"

    def _params(self, params: ArrayLike) -> Array:
        p = np.asarray(params, dtype=float).reshape(-1)
        if p.size != self.n_params or not np.all(np.isfinite(p)):
            raise InvalidInputError(f"SarCorrections takes {self.n_params} finite parameters, got {p.size}")
        return p.reshape(self.degree + 1, 3)

    def _basis(self, t: Array) -> tuple[Array, Array, Array]:
        """``tau^k``, ``d/dt tau^k`` and ``d²/dt² tau^k``, each ``(n, degree + 1)``."""
        tau = (t - self.t_mid) / self.t_half
        k = np.arange(self.degree + 1)
        b = tau[:, None] ** k
        db = np.where(k > 0, k * tau[:, None] ** np.maximum(k - 1, 0), 0.0) / self.t_half
        ddb = np.where(k > 1, k * (k - 1) * tau[:, None] ** np.maximum(k - 2, 0), 0.0) / self.t_half ** 2
        return b, db, ddb

    def _offset(self, C: Array):
        def offset(t: Array) -> tuple[Array, Array]:
            t = np.atleast_1d(t)
            b, db, _ = self._basis(t.ravel())
            return (b @ C).reshape(t.shape + (3,)), (db @ C).reshape(t.shape + (3,))
        return offset

    def _solve(self, C: Array, X: Array):
        sen = self.sensor
        t = sen._zero_doppler(X, self._offset(C) if np.any(C) else None)
        lost = ~np.isfinite(t)
        tt = np.where(lost, self.t_mid, t)
        b, db, ddb = self._basis(tt)
        P = sen.eo.position_at(tt) + b @ C
        V = sen.velocity_at(tt) + db @ C
        A = sen._velocity_rate(tt) + ddb @ C
        Pdot = sen.eo.velocity_at(tt) + db @ C      # d P / d t (position spline), ~ V
        return tt, lost, P, V, A, Pdot, b, db

    def project(self, params: ArrayLike, xyz: ArrayLike) -> Array:
        C = self._params(params)
        X = np.asarray(xyz, dtype=float).reshape(-1, 3)
        tt, lost, P, V, _, _, _, _ = self._solve(C, X)
        line, sample, _, _ = self.sensor._image_of(X, tt, P, V)
        out = np.column_stack([line, sample])
        out[lost] = np.nan
        return out

    def partials(self, params: ArrayLike, xyz: ArrayLike) -> tuple[Array, Array, Array]:
        """Pixels ``(n, 2)``, ``d/d params (n, 2, n_params)``, ``d/d xyz (n, 2, 3)`` (pixels per metre)."""
        C = self._params(params)
        X = _finite_xyz(xyz).reshape(-1, 3)
        sen = self.sensor
        n = X.shape[0]
        tt, lost, P, V, A, Pdot, b, db = self._solve(C, X)
        line, sample, g, _ = sen._image_of(X, tt, P, V)
        d = P - X
        f_t = np.einsum("ni,ni->n", Pdot, V) + np.einsum("ni,ni->n", d, A)    # d f / d t
        # d f / d c_k,a = tau^k V_a + d_a dtau^k/dt
        df_dc = b[:, :, None] * V[:, None, :] + db[:, :, None] * d[:, None, :]   # (n, k, 3)
        dt_dc = -df_dc.reshape(n, -1) / f_t[:, None]
        dt_dx = V / f_t[:, None]                                                # -(-V) / f_t
        rho = np.linalg.norm(d, axis=1)
        u = -d / rho[:, None]                                                   # (G - P) / rho
        uv = np.einsum("ni,ni->n", u, Pdot)
        drho_dx = u - uv[:, None] * dt_dx
        drho_dc = -(b[:, :, None] * u[:, None, :]).reshape(n, -1) - uv[:, None] * dt_dc
        c, dc = sen.range_conversion.at(tt)
        q = dc[:, 0] + g * (dc[:, 1] + g * (dc[:, 2] + g * dc[:, 3]))           # d poly / d t at fixed g
        pd = _dpoly(c, g)
        dg_dx = (drho_dx - q[:, None] * dt_dx) / pd[:, None]
        dg_dc = (drho_dc - q[:, None] * dt_dc) / pd[:, None]
        jx = np.stack([dt_dx / sen.line_period, dg_dx / sen.pixel_width], axis=1)
        jc = np.stack([dt_dc / sen.line_period, dg_dc / sen.pixel_width], axis=1)
        pix = np.column_stack([line, sample])
        pix[lost], jx[lost], jc[lost] = np.nan, np.nan, np.nan
        return pix, jc, jx

    def apply(self, params: ArrayLike) -> SarSensor:
        """A new :class:`SarSensor` whose trajectory samples carry the corrections."""
        C = self._params(params)
        sen = self.sensor
        eo = sen.eo
        b, db, _ = self._basis(eo.times)
        new = ExteriorOrientation(epoch=eo.epoch, times=eo.times, positions=eo.positions + b @ C,
                                  velocities=eo.velocities + db @ C, quaternions=eo.quaternions,
                                  sun_times=eo.sun_times, sun_positions=eo.sun_positions, body_frame=eo.body_frame,
                                  attrs={**eo.attrs, "corrected": f"SAR position corrections, degree {self.degree}"})
        return SarSensor(new, sen.shape, sen.n_lines, sen.n_samples, sen.t_start, sen.line_period, sen.pixel_width,
                         sen.range_conversion, sen.look_direction, t_end=sen.t_end, wavelength=sen.wavelength,
                         name=sen.name)
