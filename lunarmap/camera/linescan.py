"""Push-broom (line-scan) camera model.

Timing
------
The exposure time of image line coordinate ``L`` (CSM convention, continuous)
is ``t(L) = t0 + L * dt`` seconds after ``eo.epoch``: ``t0`` is the start of
the first line, so the centre of the first line (``L = 0.5``) is exposed at
``t0 + dt/2``. This is usgscsm's ``UsgsAstroLsSensorModel::getImageTime``
(current form: ``startTime[k] + intTime[k] * (line - intTimeLine[k] + 0.5)``)
with ALE's ``line_scan_rate = [[0.5, t_start - t_center, dt]]``; several
``[line, time, rate]`` rows (variable line rate) are accepted too, see
:class:`LineTimes`.

Focal plane
-----------
The image line is time, not a detector position: as usgscsm's ``losToEcf``
does, the focal-plane point of ``(L, S)`` is computed with image line 0, i.e.
on the detector line ``starting_detector_line`` (offset from the principal
point by ``starting_detector_line - detector_center_line`` detector lines).

Ground to image
---------------
A ground point is imaged at the line ``L`` whose exposure geometry puts its
(distorted) projection on that detector line: ``r(L) = 0`` where ``r`` is the
image-line coordinate that usgscsm's ``computePixel`` returns for the
projection at time ``t(L)`` (usgscsm ``groundToImage`` iterates ``L += r(L)``
from a linear approximation, which assumes ``dr/dL = -1`` and diverges when
the spacecraft flies the other way relative to the sign of
``focal2pixel_lines``, e.g. yawed by 180 degrees). Here, for all points at once:

1. the sign of the distance of every point to the (undistorted) exposure
   planes of a few dozen grid lines, one per ~2000 lines (one small matrix
   product), brackets each point's line; the few brackets that distortion
   invalidates are shifted or shrunk until ``r`` changes sign across them;
2. safeguarded secant steps (regula falsi / bisection when a step leaves the
   bracket) on ``r`` evaluated from a per-line table of sensor positions and
   rotations (exact at the nodes, linear in between) shrink the step below
   1e-9 line;
3. final Newton corrections with the exact EO interpolation remove the table's
   interpolation error, to ``|dL| < 1e-7`` line.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import ConvergenceError, InvalidInputError
from ..orientation.exterior import ExteriorOrientation
from .corrections import LineScanCorrections
from .frame import _CameraModel, _check_ground_on_miss, _finite_pixels, _finite_xyz
from .interior import InteriorOrientation
from .intersect import OnMiss
from .shape import Shape

__all__ = ["LineScanCamera", "LineTimes"]

Array = NDArray[np.float64]

_CHUNK = 32768          # points per vectorised block: keeps temporaries in cache
_TABLE_MAX = 4_000_000  # per-line EO table nodes (each 96 bytes)
_LINE_TOL = 1e-7        # line convergence of the exact final step
_SECANT_TOL = 1e-9      # line convergence of the table-based secant iteration
_MAX_SECANT = 40
_TABLE_EXACT_PX = 1e-6  # table error bound (pixels) below which the exact EO step is skipped
_MAX_FAST = 4           # secant steps of the fast path before a point takes the bracketed path
_MAX_EXACT = 4
_MAX_REPAIR = 12
_COARSE_LINES = 2048.0  # lines per bracketing cell (between 12 and 64 cells)


class LineTimes:
    """Piecewise-linear exposure time of image lines.

    Parameters
    ----------
    start_lines : array_like, shape (m,)
        Image line coordinate where each constant-rate segment starts (CSM
        convention; the first is normally 0).
    start_times : array_like, shape (m,)
        Exposure time at ``start_lines``, seconds relative to ``eo.epoch``.
    rates : array_like, shape (m,)
        Line period of each segment, seconds per line (> 0).
    """

    def __init__(self, start_lines: ArrayLike, start_times: ArrayLike, rates: ArrayLike) -> None:
        self.start_lines = np.atleast_1d(np.asarray(start_lines, dtype=float))
        self.start_times = np.atleast_1d(np.asarray(start_times, dtype=float))
        self.rates = np.atleast_1d(np.asarray(rates, dtype=float))
        m = self.start_lines.size
        if self.start_times.size != m or self.rates.size != m or m == 0:
            raise InvalidInputError("line times need equally many start lines, start times and rates (>= 1)")
        for name, a in (("start_lines", self.start_lines), ("start_times", self.start_times),
                        ("rates", self.rates)):
            if not np.all(np.isfinite(a)):
                raise InvalidInputError(f"line times: {name} hold NaN or infinite values")
        if np.any(self.rates <= 0.0):
            raise InvalidInputError("line periods must be positive")
        if np.any(np.diff(self.start_lines) <= 0.0):
            raise InvalidInputError("line-time segments must start at increasing lines")

    @classmethod
    def uniform(cls, t0: float, dt: float) -> "LineTimes":
        """``t(L) = t0 + L * dt``: ``t0`` start of the first line, ``dt`` line period, seconds."""
        return cls([0.0], [t0], [dt])

    @classmethod
    def from_line_scan_rate(cls, rows: Sequence[Sequence[float]] | NDArray, time_offset: float = 0.0) -> "LineTimes":
        """From ALE/usgscsm ``line_scan_rate`` rows ``[line, time, rate]``.

        ``line`` is the ISIS-convention line (1-based pixel centres, so 0.5 is
        the top edge of the image) where the segment starts and ``time`` is
        relative to the ISD's centre time; ``time_offset`` (seconds) converts
        it to time relative to ``eo.epoch`` (``center_et - eo.epoch``).
        usgscsm evaluates ``time + rate * (line_csm - line + 0.5)``.
        """
        rows_a = np.asarray(rows, dtype=float).reshape(-1, 3)
        return cls(rows_a[:, 0] - 0.5, rows_a[:, 1] + time_offset, rows_a[:, 2])

    def _segment(self, line: Array) -> NDArray[np.intp]:
        return np.clip(np.searchsorted(self.start_lines, line, side="right") - 1, 0, self.start_lines.size - 1)

    def time(self, line: ArrayLike) -> Array:
        """Exposure time (s after ``eo.epoch``) of image line coordinates."""
        line = np.asarray(line, dtype=float)
        k = self._segment(line)
        return self.start_times[k] + self.rates[k] * (line - self.start_lines[k])

    def line(self, time: ArrayLike) -> Array:
        """Image line coordinate exposed at ``time`` (inverse of :meth:`time`)."""
        time = np.asarray(time, dtype=float)
        ends = self.start_times
        k = np.clip(np.searchsorted(ends, time, side="right") - 1, 0, ends.size - 1)
        return self.start_lines[k] + (time - self.start_times[k]) / self.rates[k]

    def __repr__(self) -> str:
        if self.rates.size == 1:
            return f"LineTimes.uniform(t0={self.time(0.0).item()!r}, dt={self.rates[0]!r})"
        return f"LineTimes({self.rates.size} segments)"


def _cross(a: Array, b: Array) -> Array:
    out = np.empty_like(a)
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def _quat_rotate_inverse(q: Array, v: Array) -> Array:
    """``R(q)^T v`` for unit quaternions ``(w, x, y, z)``, without forming matrices.

    ``R(q) v = v + w t + u x t`` with ``t = 2 u x v``; the transpose is the
    same with ``u -> -u``.
    """
    w = q[:, :1]
    u = q[:, 1:]
    t = 2.0 * _cross(v, u)
    return v + w * t + _cross(t, u)


class LineScanCamera(_CameraModel):
    """A push-broom camera: one detector line, one exposure time per image line.

    Parameters
    ----------
    interior : InteriorOrientation
        Camera constants and distortion.
    eo : ExteriorOrientation
        Sensor trajectory and attitude covering the exposure times.
    shape : Shape, optional
        Body shape; the 1737.4 km Moon sphere by default.
    line_times : tuple (t0, dt) or LineTimes
        Exposure timing: ``t(L) = t0 + L * dt``, seconds relative to
        ``eo.epoch`` (``t0``: start of the first line, ``dt``: line period).
    workers : int, optional
        Threads for :meth:`ground_to_image` over blocks of points (numpy
        releases the GIL inside each operation). Default 1: the gain measured
        on 2 cores was about 10 %, and under dask the cores are already busy.
    """

    def __init__(self, interior: InteriorOrientation, eo: ExteriorOrientation, shape: Shape | None = None,
                 line_times: tuple[float, float] | LineTimes | None = None, workers: int | None = None) -> None:
        super().__init__(interior, eo, shape)
        if line_times is None:
            raise InvalidInputError("a line-scan camera needs line_times=(t0, dt) or a LineTimes")
        if isinstance(line_times, LineTimes):
            self.line_times = line_times
        else:
            lt = np.asarray(line_times, dtype=float)
            if lt.shape != (2,):
                raise InvalidInputError("line_times must be (t0, dt) or a LineTimes (use "
                                        "LineTimes.from_line_scan_rate for ALE line_scan_rate rows)")
            self.line_times = LineTimes.uniform(float(lt[0]), float(lt[1]))
        self.workers = max(1, int(workers if workers is not None else 1))
        self._table: dict[str, object] | None = None
        # Sensor-frame normal of the exposure plane of the detector line
        # (undistorted approximation, used only to bracket): with
        # ``il = focal2pixel_lines`` the detector line condition
        # il1*x + il2*y = c with (x, y) = f (vx, vy)/vz is the plane
        # (il1 f, il2 f, -c) . v = 0.
        il = interior.focal2pixel_lines
        c = interior.starting_detector_line - interior.detector_center_line - il[0]
        self._plane_normal = np.array([il[1] * interior.focal_length, il[2] * interior.focal_length, -c])

    def __repr__(self) -> str:
        return (f"LineScanCamera({self.interior.name or 'unnamed'}, {self.interior.n_lines} lines, "
                f"{self.line_times!r}, {self.distortion!r})")

    @property
    def center_time(self) -> float:
        """Exposure time of the image's middle line, ephemeris seconds (TDB past J2000)."""
        return float(self.eo.epoch + self.image_time(0.5 * self.interior.n_lines))

    def corrections(self, degree: int | None = 1, jitter_lines: float | None = None) -> "Any":
        """Position/attitude correction polynomials of ``degree`` (0-2) in time, optionally with a jitter
        spline of the attitude with knots every ``jitter_lines`` lines.

        See :class:`~lunarmap.camera.corrections.LineScanCorrections`; ``None`` means degree 1.
        """
        return LineScanCorrections(self, 1 if degree is None else degree, jitter_lines=jitter_lines)

    # -- image to ground -------------------------------------------------
    def image_time(self, line: ArrayLike) -> Array:
        """Exposure time (s after ``eo.epoch``) of image line coordinates."""
        return self.line_times.time(line)

    def sensor_position(self, line: ArrayLike, sample: ArrayLike) -> Array:
        """Sensor position (metres, body-fixed) at the exposure of image coordinates; shape ``(..., 3)``."""
        line, sample = _finite_pixels(line, sample)
        return self.eo.position_at(self.image_time(line))

    def _rays(self, line: Array, sample: Array) -> tuple[Array, Array]:
        look_s = self._sensor_look(np.zeros_like(line), sample)
        tab = self._build_table()
        s = (line - tab["line0"]) / tab["step"]
        if tab["exact_px"] <= _TABLE_EXACT_PX and s.size and s.min() >= 0.0 and s.max() <= tab["n"] - 1:
            # The per-line table equals the EO interpolation to < 1e-6 px
            # (see _table_error_px) and costs one gather instead of two spline
            # evaluations and a quaternion-to-matrix conversion.
            row = self._table_rows(tab, line.ravel())
            rt = row[:, 3:].reshape(-1, 3, 3)          # R^T: rows are the sensor axes in body-fixed
            look = np.einsum("nji,nj->ni", rt, look_s.reshape(-1, 3)).reshape(look_s.shape)
            pos = row[:, :3].reshape(look_s.shape)
        else:
            t = self.image_time(line)
            look = np.einsum("...ij,...j->...i", self.eo.rotation_at(t), look_s)
            pos = self.eo.position_at(t)
        look /= np.linalg.norm(look, axis=-1, keepdims=True)
        return pos, look

    # -- ground to image ---------------------------------------------------
    def _line_range(self) -> tuple[float, float]:
        """Lines searched by ground_to_image: the image plus a margin, within EO coverage."""
        n = float(self.interior.n_lines)
        pad = max(64.0, 0.05 * n)
        t_first, t_last = self.eo.time_range
        if self.eo.times.size == 1:
            t_first, t_last = -np.inf, np.inf
        # One line of extrapolation at each end: sampled EO grids computed in
        # absolute ET end a few 1e-8 s short of the last line (ET spacing at
        # 8e8 s is 1.2e-7 s), and the cubic EO splines are exact over 1 ms.
        lo = max(-pad, float(self.line_times.line(t_first)) - 1.0)
        hi = min(n + pad, float(self.line_times.line(t_last)) + 1.0)
        if not hi > lo + 2.0:
            raise InvalidInputError("the exterior orientation does not cover the image's exposure times")
        return lo, hi

    def _build_table(self) -> dict[str, Any]:
        table = self._table
        if table is not None:
            return table
        with self._cache_lock:   # built once: concurrent first calls wait for the first builder
            if self._table is None:
                self._table = self._new_table()
            return self._table

    def _new_table(self) -> dict[str, Any]:
        """The per-line EO table (built once per camera by :meth:`_build_table`)."""
        lo, hi = self._line_range()
        n_nodes = int(np.ceil(hi - lo)) + 1
        step = max(1.0, (hi - lo) / (_TABLE_MAX - 1))
        n_nodes = min(n_nodes, _TABLE_MAX)
        lines = lo + step * np.arange(n_nodes)
        t = self.image_time(lines)
        pos = self.eo.position_at(t)
        rot = self.eo.rotation_at(t)
        # Row layout [P (3), R^T row-major (9)] so one gather fetches a node.
        table = np.concatenate([pos, np.swapaxes(rot, -1, -2).reshape(-1, 9)], axis=1)
        n_coarse = int(np.clip((n_nodes - 1) / _COARSE_LINES, 12, 64))
        coarse_idx = np.unique(np.round(np.linspace(0, n_nodes - 1, n_coarse + 1)).astype(np.intp))
        normals = np.einsum("kij,j->ki", rot[coarse_idx], self._plane_normal)
        offsets = np.einsum("ki,ki->k", normals, pos[coarse_idx])
        # Each row holds a node and its forward difference, so a table
        # evaluation is a single gather of 24 contiguous doubles.
        pairs = np.concatenate([table[:-1], np.diff(table, axis=0)], axis=1)
        for a in (table, pairs, coarse_idx, normals, offsets):
            a.setflags(write=False)   # shared by every thread using the camera: never written after this
        return {
            "line0": lo, "step": step, "n": n_nodes, "table": table, "pairs": pairs,
            "exact_px": self._table_error_px(lines, pos, rot),
            "coarse_idx": coarse_idx, "normals": normals, "offsets": offsets,
        }

    def _table_error_px(self, lines: NDArray, pos: Array, rot: Array) -> float:
        """Upper bound (pixels) of the image error of linear table interpolation vs the EO's own.

        The EO is evaluated half-way between table nodes, where linear
        interpolation errs most; the rotation error (Frobenius norm, which
        bounds the angle) is divided by the IFOV, the position error by the
        ground sample distance at the closest possible range (sensor to the
        highest point of the body plus 20 km of terrain).
        """
        mid_t = self.image_time(0.5 * (lines[:-1] + lines[1:]))
        pos_err = np.linalg.norm(self.eo.position_at(mid_t) - 0.5 * (pos[:-1] + pos[1:]), axis=-1).max()
        rot_err = np.linalg.norm(self.eo.rotation_at(mid_t) - 0.5 * (rot[:-1] + rot[1:]), axis=(-2, -1)).max()
        it = self.interior
        scale = np.hypot(it.focal2pixel_samples[1], it.focal2pixel_samples[2])
        scale = min(scale, np.hypot(it.focal2pixel_lines[1], it.focal2pixel_lines[2]))
        ifov = 1.0 / (it.focal_length * scale)   # radians per pixel
        top = max(self.shape.a, self.shape.b, self.shape.c) + 20_000.0
        closest = max(float(np.linalg.norm(pos, axis=-1).min()) - top, 1_000.0)
        return float(rot_err / ifov + pos_err / (ifov * closest))

    def _residual_from(self, pt: Array, pr: Array, g: Array) -> tuple[Array, Array, NDArray[np.bool_]]:
        """Image-line residual, sample and validity of points ``g`` given positions and R^T rows."""
        d = g - pt
        v = np.empty_like(d)
        v[:, 0] = pr[:, 0] * d[:, 0] + pr[:, 1] * d[:, 1] + pr[:, 2] * d[:, 2]
        v[:, 1] = pr[:, 3] * d[:, 0] + pr[:, 4] * d[:, 1] + pr[:, 5] * d[:, 2]
        v[:, 2] = pr[:, 6] * d[:, 0] + pr[:, 7] * d[:, 1] + pr[:, 8] * d[:, 2]
        return self._project(v)

    @staticmethod
    def _table_rows(tab: dict, line: Array) -> Array:
        """Linearly interpolated table rows ``[P (3), R^T row-major (9)]`` at image lines ``(n,)``."""
        s = (line - tab["line0"]) / tab["step"]
        i = np.clip(np.floor(s).astype(np.intp), 0, tab["n"] - 2)
        node = tab["pairs"][i]
        return node[:, :12] + (s - i)[:, None] * node[:, 12:]

    def _residual_table(self, tab: dict, g: Array, line: Array) -> tuple[Array, Array, NDArray[np.bool_]]:
        row = self._table_rows(tab, line)
        return self._residual_from(row[:, :3], row[:, 3:], g)

    def _residual_exact(self, g: Array, line: Array) -> tuple[Array, Array, NDArray[np.bool_]]:
        t = self.image_time(line)
        pos = self.eo.position_at(t)
        q = self.eo.quaternion_at(t)
        v = _quat_rotate_inverse(q, g - pos)
        return self._project(v)

    def _solve_chunk(self, g: Array) -> tuple[Array, Array, NDArray[np.bool_]]:
        tab = self._build_table()
        n = g.shape[0]
        line = np.full(n, np.nan)
        sample = np.full(n, np.nan)
        ok = np.zeros(n, dtype=bool)
        cidx: NDArray[np.intp] = tab["coarse_idx"]
        # 1. bracket: sign of the distance to the coarse grid's exposure planes.
        dist = g @ tab["normals"].T - tab["offsets"]
        pos_side = dist > 0.0
        change = pos_side[:, 1:] != pos_side[:, :-1]
        has = change.any(axis=1)
        k = np.argmax(change, axis=1)
        # Distortion (e.g. Kaguya TC's boresight offset of ~10 lines) can move the exact root inside the
        # table while the undistorted plane crosses just beyond one end: such points, whose plane
        # distance at an end node is within two coarse cells of zero, try the end cell; the bracketed
        # path then repairs or rejects the bracket on the exact residual.
        last = dist.shape[1] - 1
        near_first = np.abs(dist[:, 0]) < 2.0 * np.abs(dist[:, 1] - dist[:, 0])
        near_last = np.abs(dist[:, last]) < 2.0 * np.abs(dist[:, last] - dist[:, last - 1])
        edge = ~has & (near_first | near_last)
        k = np.where(edge & ~near_first, last - 1, np.where(edge, 0, k))
        idx = np.flatnonzero(has | edge)
        if idx.size == 0:
            return line, sample, ok
        k = k[idx]
        on_edge = edge[idx]
        line0, step = tab["line0"], tab["step"]
        a = line0 + step * cidx[k].astype(float)
        b = line0 + step * cidx[k + 1].astype(float)
        # 2a. fast path: the plane distance is nearly linear in the line over
        # a coarse cell, so interpolating it starts a secant within a few lines
        # of the root; most points converge in two or three table evaluations.
        da, db = dist[idx, k], dist[idx, k + 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            x_est = a + (b - a) * (da / (da - db))
        lin = np.full(idx.size, np.nan)
        slope = np.full(idx.size, np.nan)
        fast = np.zeros(idx.size, dtype=bool)
        inner = np.flatnonzero(~on_edge)
        if inner.size:
            lin_i, slope_i = lin[inner], slope[inner]
            fast[inner] = self._fast_secant(tab, g[idx[inner]], x_est[inner], lin_i, slope_i)
            lin[inner], slope[inner] = lin_i, slope_i
        slow = np.flatnonzero(~fast)
        if slow.size:
            lin[slow], slope[slow], found = self._bracketed_secant(tab, g[idx[slow]], a[slow], b[slow])
            keep = np.ones(idx.size, dtype=bool)
            keep[slow[~found]] = False
            idx, lin, slope = idx[keep], lin[keep], slope[keep]
            if idx.size == 0:
                return line, sample, ok
        return self._refine(tab, g, idx, lin, slope, line, sample, ok)

    def _fast_secant(self, tab: dict, gi: Array, x_est: Array, lin: Array, slope: Array) -> NDArray[np.bool_]:
        """Secant from an interpolated start; fills ``lin``/``slope`` where it converged (returned mask)."""
        lo, hi = tab["line0"], tab["line0"] + tab["step"] * (tab["n"] - 1)
        n = gi.shape[0]
        done = np.zeros(n, dtype=bool)
        x0 = np.clip(np.where(np.isfinite(x_est), x_est, lo), lo, hi - 0.5)
        r0, _, v0 = self._residual_table(tab, gi, x0)
        x1 = x0 + 0.5
        r1, _, v1 = self._residual_table(tab, gi, x1)
        with np.errstate(divide="ignore", invalid="ignore"):
            sl = (r1 - r0) / (x1 - x0)
        act = np.flatnonzero(v0 & v1 & np.isfinite(sl) & (sl != 0.0))
        slope[act] = sl[act]
        x0, r0, x1, r1 = x0[act], r0[act], x1[act], r1[act]
        for _ in range(_MAX_FAST):
            with np.errstate(divide="ignore", invalid="ignore"):
                x2 = x1 - r1 * (x1 - x0) / (r1 - r0)
            ins = np.isfinite(x2) & (x2 >= lo) & (x2 <= hi)
            act, x0, r0, x1, r1, x2 = act[ins], x0[ins], r0[ins], x1[ins], r1[ins], x2[ins]
            r2, _, v2 = self._residual_table(tab, gi[act], x2)
            conv = v2 & ((np.abs(x2 - x1) < _SECANT_TOL) | (np.abs(r2) < 0.1 * _SECANT_TOL))
            lin[act[conv]] = x2[conv]
            done[act[conv]] = True
            go = v2 & ~conv & (r2 != r1)
            act, x0, r0, x1, r1 = act[go], x1[go], r1[go], x2[go], r2[go]
            if act.size == 0:
                break
        return done

    def _bracketed_secant(self, tab: dict, gi: Array, a: Array, b: Array) -> tuple[Array, Array, NDArray[np.bool_]]:
        """Safeguarded secant inside coarse brackets (the robust path): lines, slopes dr/dL, found mask."""
        line0, step = tab["line0"], tab["step"]
        n = gi.shape[0]
        found = np.zeros(n, dtype=bool)
        out_line = np.full(n, np.nan)
        out_slope = np.full(n, np.nan)
        sel = np.arange(n)
        ra, _, va = self._residual_table(tab, gi, a)
        rb, _, vb = self._residual_table(tab, gi, b)
        # Distortion moves the exact root off the undistorted plane's, possibly
        # out of the cell or next to an end where the projection is invalid
        # (beyond the distortion model's domain): repair those few brackets.
        line_end = line0 + step * (tab["n"] - 1)
        for _ in range(_MAX_REPAIR):
            redo = np.flatnonzero(~(va & vb & (np.sign(ra) != np.sign(rb))))
            if redo.size == 0:
                break
            aa, bb, rra, rrb, vva, vvb = a[redo], b[redo], ra[redo], rb[redo], va[redo], vb[redo]
            width = bb - aa
            both = vva & vvb
            left = both & (np.abs(rra) < np.abs(rrb))   # root lies before a
            right = both & ~left                           # root lies after b
            new_a = np.where(left, np.maximum(aa - width, line0), np.where(right, bb, aa))
            new_b = np.where(left, aa, np.where(right, np.minimum(bb + width, line_end), bb))
            # an invalid end moves halfway towards the other end
            new_a = np.where(~vva, 0.5 * (aa + bb), new_a)
            new_b = np.where(vva & ~vvb, 0.5 * (aa + bb), new_b)
            a[redo], b[redo] = new_a, new_b
            ra[redo], _, va[redo] = self._residual_table(tab, gi[redo], new_a)
            rb[redo], _, vb[redo] = self._residual_table(tab, gi[redo], new_b)
        good = va & vb & (np.sign(ra) != np.sign(rb))
        sel, gi, a, b, ra, rb = sel[good], gi[good], a[good], b[good], ra[good], rb[good]
        if sel.size == 0:
            return out_line, out_slope, found
        # 2b. safeguarded secant on the tabulated EO.
        x0, r0 = a.copy(), ra.copy()
        x1, r1 = b.copy(), rb.copy()
        act = np.arange(sel.size)
        xl = np.empty(sel.size)
        # dr/dL for the exact Newton steps below: the latest secant slope over
        # a pair of iterates far enough apart (>= 1e-4 line) not to be
        # dominated by round-off; the final pair may be a float ulp apart.
        slope = (rb - ra) / (b - a)
        for _ in range(_MAX_SECANT):
            with np.errstate(divide="ignore", invalid="ignore"):
                x2 = x1[act] - r1[act] * (x1[act] - x0[act]) / (r1[act] - r0[act])
            aa, bb = a[act], b[act]
            lo, hi = np.minimum(aa, bb), np.maximum(aa, bb)
            inside = (x2 > lo) & (x2 < hi)
            with np.errstate(divide="ignore", invalid="ignore"):
                falsi = aa - ra[act] * (bb - aa) / (rb[act] - ra[act])
            falsi = np.where((falsi > lo) & (falsi < hi), falsi, 0.5 * (aa + bb))
            x2 = np.where(inside, x2, falsi)
            r2, _, v2 = self._residual_table(tab, gi[act], x2)
            r2 = np.where(v2, r2, np.nan)
            dx = np.abs(x2 - x1[act])
            with np.errstate(divide="ignore", invalid="ignore"):
                sl = (r2 - r1[act]) / (x2 - x1[act])
            slope[act] = np.where((dx >= 1e-4) & np.isfinite(sl) & (sl != 0.0), sl, slope[act])
            x0[act], r0[act] = x1[act], r1[act]
            x1[act], r1[act] = x2, r2
            # keep the bracket: replace the end whose residual has r2's sign
            same_a = np.sign(r2) == np.sign(ra[act])
            a[act] = np.where(same_a, x2, a[act])
            ra[act] = np.where(same_a, r2, ra[act])
            b[act] = np.where(~same_a, x2, b[act])
            rb[act] = np.where(~same_a, r2, rb[act])
            # |r2| is in lines and |dr/dL| is about 1, so a tiny residual is
            # converged even when float spacing stops x from moving.
            done = (dx < _SECANT_TOL) | (np.abs(r2) < 0.1 * _SECANT_TOL) | ~np.isfinite(r2)
            xl[act[done]] = x2[done]
            act = act[~done]
            if act.size == 0:
                break
        if act.size:
            raise ConvergenceError(f"ground_to_image: line search did not converge for {act.size} point(s)")
        out_line[sel], out_slope[sel], found[sel] = xl, slope, True
        return out_line, out_slope, found

    def _refine(self, tab: dict, g: Array, idx: NDArray[np.intp], lin: Array, slope: Array,
                line: Array, sample: Array, ok: NDArray[np.bool_]) -> tuple[Array, Array, NDArray[np.bool_]]:
        """Exact Newton corrections of table-based lines with the EO's own interpolation; fills the outputs."""
        gi = g[idx]
        smp, val = np.full(idx.size, np.nan), np.zeros(idx.size, dtype=bool)
        act = np.arange(idx.size)
        if tab["exact_px"] <= _TABLE_EXACT_PX:
            # The table reproduces the EO's interpolation to far below the
            # accuracy claimed: its root is the exact root, so only the sample
            # (and validity) at that line remain to be computed.
            _, smp, val = self._residual_table(tab, gi, lin)
            act = act[:0]
        # 3. exact Newton corrections with the EO's own interpolation.
        for _ in range(_MAX_EXACT if act.size else 0):
            r, s, v = self._residual_exact(gi[act], lin[act])
            smp[act] = s
            val[act] = v
            with np.errstate(divide="ignore", invalid="ignore"):
                dl = r / slope[act]
            v &= np.isfinite(dl)
            val[act] = v
            lin[act] = lin[act] - np.where(v, dl, 0.0)
            act = act[v & (np.abs(dl) >= _LINE_TOL)]
            if act.size == 0:
                break
        if act.size:
            raise ConvergenceError(f"ground_to_image: exact line refinement did not converge for "
                                   f"{act.size} point(s)")
        line[idx] = lin
        sample[idx] = smp
        ok[idx] = val & np.isfinite(lin)
        # Body occlusion needs only a coarse sensor position: the table's.
        vis = np.flatnonzero(ok)
        if vis.size:
            s = np.clip((line[vis] - tab["line0"]) / tab["step"], 0, tab["n"] - 1)
            sensor = tab["table"][np.round(s).astype(np.intp), :3]
            ok[vis[self._occluded(sensor, g[vis])]] = False
        return line, sample, ok

    def ground_to_image(self, xyz: ArrayLike, on_miss: OnMiss = "nan",
                        within_image: bool = True) -> tuple[Array, Array]:
        """Image coordinates of body-fixed ground points.

        Parameters
        ----------
        xyz : array_like, shape (..., 3)
            Ground points, metres, body-fixed.
        on_miss : {"nan", "raise"}
            Points not seen: NaN coordinates, or
            :class:`~lunarmap.errors.GeometryError`. A point is not seen when
            no exposure plane within the searched lines (the image plus a 5 %
            margin, within EO coverage) contains it in front of the sensor,
            when the body hides it (sight line through the shape shrunk by
            20 km), when it lies outside ``[0, n_lines] x [0, n_samples]``
            (only with ``within_image``), or beyond the distortion model's
            domain.
        within_image : bool
            Treat coordinates outside the image as not seen.

        Returns
        -------
        line, sample : ndarray, shape (...)
            Image coordinates, pixels (CSM convention); the line solves the
            exposure condition to better than 1e-7 line.

        Raises
        ------
        InvalidInputError
            NaN or infinite coordinates.
        GeometryError
            Some point is not seen and ``on_miss="raise"``.
        ConvergenceError
            The line search failed (should not happen for a smooth EO).

        Notes
        -----
        Occlusion by terrain is not tested.
        """
        _check_ground_on_miss(on_miss)
        xyz = _finite_xyz(xyz)
        shape = xyz.shape[:-1]
        g = np.ascontiguousarray(xyz.reshape(-1, 3))
        n = g.shape[0]
        line = np.empty(n)
        sample = np.empty(n)
        ok = np.empty(n, dtype=bool)
        self._build_table()
        starts = range(0, n, _CHUNK)

        def run(i0: int) -> None:
            sl = slice(i0, min(i0 + _CHUNK, n))
            line[sl], sample[sl], ok[sl] = self._solve_chunk(g[sl])

        if self.workers > 1 and n > _CHUNK:
            with ThreadPoolExecutor(self.workers) as pool:
                list(pool.map(run, starts))
        else:
            for i0 in starts:
                run(i0)
        line, sample = self._finish_ground_to_image(line, sample, ok, within_image, on_miss)
        return line.reshape(shape), sample.reshape(shape)
