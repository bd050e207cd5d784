"""Reseau-grid correction of image measurements (the Ranger paper's "Mensuration", ``seeds/000``).

Ranger's A and B cameras image a calibrated 25-point reseau (5 x 5 marks) with every picture; the
measured marks show the image distortion of the vidicon, the transmission and the print (the
paper's Fig. 6). The paper corrects photo coordinates "by applying a projective transformation",
"each of the 16 small squares bounded by a set of four grid marks treated as a separate unit".

:class:`ReseauCorrection` does exactly that for any ``rows x cols`` grid: a point measured inside
the quadrilateral of four measured marks is mapped by the transformation that takes those four
marks onto their calibrated positions, either

* ``"projective"`` (the paper): the 8-parameter plane projective transformation of the four
  corners; neighbouring cells agree at the shared marks and map the shared edge onto the same
  straight line, but not point for point along it;
* ``"bilinear"``: the cell's bilinear parameters ``(s, t)`` of the measured point (inverse bilinear
  interpolation, Newton) mapped onto the calibrated quadrilateral; continuous across cell edges.

Both reproduce the marks exactly, so the marks themselves have no residuals under them; the
report (:meth:`ReseauCorrection.report`) gives per mark the measured - calibrated displacement
after removing the best-fitting affine and projective transformations of the whole grid: the
non-projective distortion that the per-cell correction removes, and the size of what a single
global transformation would leave. Coordinates are millimetres in the photo frame (any consistent
unit works).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from ..errors import ReseauError

__all__ = ["ReseauGrid", "ReseauCorrection", "fit_projective", "apply_projective"]

Array = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class ReseauGrid:
    """Calibrated reseau marks, ``calibrated[row, col] = (x, y)`` millimetres, rows along y, columns along x.

    Parameters
    ----------
    calibrated : array_like, shape (rows, cols, 2)
        Calibrated positions; rows x cols >= 2 x 2.
    ids : sequence of str, optional
        Mark names, row-major (default ``"r<row>c<col>"``).
    """

    calibrated: Array
    ids: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        cal = np.asarray(self.calibrated, float)
        if cal.ndim != 3 or cal.shape[2] != 2 or cal.shape[0] < 2 or cal.shape[1] < 2:
            raise ReseauError(f"a reseau grid needs calibrated positions of shape (rows >= 2, cols >= 2, 2), "
                              f"got {cal.shape}")
        if not np.all(np.isfinite(cal)):
            raise ReseauError("calibrated reseau positions must be finite")
        object.__setattr__(self, "calibrated", cal)
        ids = tuple(self.ids) if self.ids else tuple(f"r{r}c{c}" for r in range(cal.shape[0]) for c in range(cal.shape[1]))
        if len(ids) != cal.shape[0] * cal.shape[1]:
            raise ReseauError(f"{len(ids)} mark ids for {cal.shape[0] * cal.shape[1]} marks")
        object.__setattr__(self, "ids", ids)
        _check_cells(cal, "calibrated", ids)

    @classmethod
    def regular(cls, rows: int = 5, cols: int = 5, spacing: float = 2.0) -> "ReseauGrid":
        """A square grid centred on the principal point (row 0 at the top, ``+y``)."""
        x = (np.arange(cols) - (cols - 1) / 2.0) * spacing
        y = ((rows - 1) / 2.0 - np.arange(rows)) * spacing
        X, Y = np.meshgrid(x, y)
        return cls(np.stack([X, Y], axis=-1))

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.calibrated.shape[0]), int(self.calibrated.shape[1])


def _cross(a: Array, b: Array) -> Array:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _cells(p: Array) -> Array:
    """Corners of every cell, ``(rows-1, cols-1, 4, 2)``: (r,c), (r,c+1), (r+1,c+1), (r+1,c) (a loop)."""
    return np.stack([p[:-1, :-1], p[:-1, 1:], p[1:, 1:], p[1:, :-1]], axis=2)


def _check_cells(p: Array, what: str, ids: Sequence[str]) -> None:
    quads = _cells(p)
    edges = np.roll(quads, -1, axis=2) - quads
    turn = _cross(edges, np.roll(edges, -1, axis=2))            # (r, c, 4): convex <=> all of one sign
    sign = np.sign(turn)
    ok = np.all(sign == sign[..., :1], axis=2) & np.all(np.abs(turn) > 0, axis=2)
    if not np.all(ok):
        r, c = np.argwhere(~ok)[0]
        cols = p.shape[1]
        marks = [ids[r * cols + c], ids[r * cols + c + 1], ids[(r + 1) * cols + c + 1], ids[(r + 1) * cols + c]]
        raise ReseauError(f"{what} reseau cell {r},{c} (marks {', '.join(marks)}) is not a convex quadrilateral: "
                          "folded or degenerate marks")


def fit_projective(src: ArrayLike, dst: ArrayLike) -> Array:
    """The plane projective transformation (3x3, ``h33 = 1``) taking ``src`` points onto ``dst`` (least squares).

    Four points in general position determine it exactly; more are fitted by linear least squares
    (algebraic error, after centring and scaling both point sets).
    """
    s, d = np.asarray(src, float).reshape(-1, 2), np.asarray(dst, float).reshape(-1, 2)
    if s.shape[0] < 4 or s.shape != d.shape:
        raise ReseauError(f"a projective transformation needs >= 4 point pairs, got {s.shape[0]}")
    ts, td = _normaliser(s), _normaliser(d)
    sn = (np.column_stack([s, np.ones(len(s))]) @ ts.T)[:, :2]
    dn = (np.column_stack([d, np.ones(len(d))]) @ td.T)[:, :2]
    n = len(s)
    a = np.zeros((2 * n, 8))
    a[0::2, 0:2], a[0::2, 2] = sn, 1.0
    a[0::2, 6:8] = -sn * dn[:, :1]
    a[1::2, 3:5], a[1::2, 5] = sn, 1.0
    a[1::2, 6:8] = -sn * dn[:, 1:]
    h, *_ = np.linalg.lstsq(a, dn.reshape(-1), rcond=None)
    hn = np.append(h, 1.0).reshape(3, 3)
    out = np.linalg.inv(td) @ hn @ ts
    return out / out[2, 2]


def _normaliser(p: Array) -> Array:
    c = p.mean(axis=0)
    scale = np.sqrt(2.0) / max(float(np.mean(np.linalg.norm(p - c, axis=1))), 1e-300)
    return np.array([[scale, 0.0, -scale * c[0]], [0.0, scale, -scale * c[1]], [0.0, 0.0, 1.0]])


def apply_projective(h: Array, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
    """Points ``(x, y)`` mapped by the projective transformation(s) ``h`` (``(3, 3)`` or one per point)."""
    x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
    h = np.asarray(h, float)
    w = h[..., 2, 0] * x + h[..., 2, 1] * y + h[..., 2, 2]
    return (h[..., 0, 0] * x + h[..., 0, 1] * y + h[..., 0, 2]) / w, (h[..., 1, 0] * x + h[..., 1, 1] * y + h[..., 1, 2]) / w


def _bilinear(q: Array, s: Array, t: Array) -> Array:
    """Points of quadrilaterals ``q (..., 4, 2)`` at parameters ``(s, t)`` (corner order of :func:`_cells`)."""
    s, t = s[..., None], t[..., None]
    return (1 - s) * (1 - t) * q[..., 0, :] + s * (1 - t) * q[..., 1, :] + s * t * q[..., 2, :] + (1 - s) * t * q[..., 3, :]


def _inverse_bilinear(q: Array, pts: Array) -> tuple[Array, Array]:
    """Bilinear parameters ``(s, t)`` of points in quadrilaterals (Newton; ``q (..., 4, 2)``, ``pts (..., 2)``)."""
    s = np.full(pts.shape[:-1], 0.5)
    t = np.full(pts.shape[:-1], 0.5)
    e = q[..., 1, :] - q[..., 0, :]
    f = q[..., 3, :] - q[..., 0, :]
    g = q[..., 0, :] - q[..., 1, :] + q[..., 2, :] - q[..., 3, :]
    for _ in range(30):
        r = _bilinear(q, s, t) - pts
        ds = e + t[..., None] * g                  # d/ds
        dt = f + s[..., None] * g                  # d/dt
        det = _cross(ds, dt)
        with np.errstate(divide="ignore", invalid="ignore"):
            step_s = _cross(r, dt) / det
            step_t = _cross(ds, r) / det
        s, t = s - step_s, t - step_t
        if np.nanmax(np.abs(np.concatenate([np.ravel(step_s), np.ravel(step_t)]))) < 1e-14:
            break
    return s, t


class ReseauCorrection:
    """Per-cell correction of one photo's measurements by its measured reseau (module docstring).

    Parameters
    ----------
    grid : ReseauGrid
        Calibrated marks.
    measured : array_like, shape (rows, cols, 2)
        Measured positions of the same marks on the photo (NaN for a mark not measured).
    method : {"projective", "bilinear"}
        Transformation per cell.

    Raises
    ------
    ReseauError
        Wrong shape, missing (NaN) marks (named: every cell needs its four corners), a folded cell.
    """

    def __init__(self, grid: ReseauGrid, measured: ArrayLike, method: str = "projective") -> None:
        if method not in ("projective", "bilinear"):
            raise ReseauError(f"method must be 'projective' or 'bilinear', got {method!r}")
        m = np.asarray(measured, float)
        if m.shape != grid.calibrated.shape:
            raise ReseauError(f"measured reseau marks have shape {m.shape}, the grid {grid.calibrated.shape}")
        missing = [grid.ids[i] for i in np.flatnonzero(~np.all(np.isfinite(m.reshape(-1, 2)), axis=1))]
        if missing:
            raise ReseauError(f"{len(missing)} of {len(grid.ids)} reseau marks are missing ({', '.join(missing[:8])}"
                              f"{' ...' if len(missing) > 8 else ''}): every grid cell needs its four marks; "
                              f"{len(grid.ids)} are needed")
        _check_cells(m, "measured", grid.ids)
        self.grid = grid
        self.measured = m
        self.method = method
        self._mq = _cells(m)                      # (R, C, 4, 2)
        self._cq = _cells(grid.calibrated)
        R, C = self._mq.shape[:2]
        self._h = np.empty((R, C, 3, 3))
        for r in range(R):
            for c in range(C):
                self._h[r, c] = fit_projective(self._mq[r, c], self._cq[r, c])

    def _locate(self, pts: Array) -> tuple[NDArray[np.int64], NDArray[np.int64], Array, Array, NDArray[np.bool_]]:
        """Cell (row, col), bilinear parameters and 'inside' flag of every point (nearest cell outside)."""
        R, C = self._mq.shape[:2]
        q = self._mq.reshape(R * C, 4, 2)
        s, t = _inverse_bilinear(q[:, None], np.broadcast_to(pts, (R * C,) + pts.shape))   # (cells, n)
        # distance outside the unit square (0 inside); the smallest picks the cell
        out = np.hypot(np.maximum(np.maximum(-s, s - 1), 0.0), np.maximum(np.maximum(-t, t - 1), 0.0))
        out = np.where(np.isfinite(out), out, np.inf)
        k = np.argmin(out, axis=0)
        n = np.arange(pts.shape[0])
        inside = out[k, n] <= 1e-9
        return k // C, k % C, s[k, n], t[k, n], inside

    def apply(self, x: ArrayLike, y: ArrayLike, outside: str = "raise") -> tuple[Array, Array]:
        """Corrected (calibrated-frame) coordinates of measured photo coordinates.

        Parameters
        ----------
        x, y : array_like
            Measured coordinates, millimetres.
        outside : {"raise", "extrapolate", "nan"}
            Points outside the outer marks: :class:`~lunarmap.errors.ReseauError`, the nearest
            border cell's transformation, or NaN.
        """
        if outside not in ("raise", "extrapolate", "nan"):
            raise ReseauError(f"outside must be 'raise', 'extrapolate' or 'nan', got {outside!r}")
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        shape = x.shape
        pts = np.column_stack([x.ravel(), y.ravel()])
        if not np.all(np.isfinite(pts)):
            raise ReseauError("measured coordinates must be finite")
        if pts.shape[0] == 0:
            return x.astype(float), y.astype(float)
        r, c, s, t, inside = self._locate(pts)
        if outside == "raise" and not inside.all():
            i = int(np.argmin(inside))
            raise ReseauError(f"{int((~inside).sum())} point(s) lie outside the reseau (first: "
                              f"({pts[i, 0]:.4f}, {pts[i, 1]:.4f}) mm); use outside='extrapolate' or 'nan'")
        if self.method == "projective":
            u, v = apply_projective(self._h[r, c], pts[:, 0], pts[:, 1])
        else:
            u, v = _bilinear(self._cq[r, c], s, t).T
        if outside == "nan":
            u, v = np.where(inside, u, np.nan), np.where(inside, v, np.nan)
        return u.reshape(shape), v.reshape(shape)

    def report(self) -> xr.Dataset:
        """Per mark: calibrated and measured positions and their displacement after a global affine and a
        global projective transformation of the whole grid (millimetres); attributes hold the RMS."""
        cal = self.grid.calibrated.reshape(-1, 2)
        mea = self.measured.reshape(-1, 2)
        a = np.column_stack([mea, np.ones(len(mea))])
        coef, *_ = np.linalg.lstsq(a, cal, rcond=None)
        res_aff = a @ coef - cal
        h = fit_projective(mea, cal)
        res_proj = np.column_stack(apply_projective(h, mea[:, 0], mea[:, 1])) - cal
        rows, cols = self.grid.shape
        rr, cc = np.divmod(np.arange(rows * cols), cols)
        ds = xr.Dataset(
            {"row": ("mark", rr), "col": ("mark", cc),
             "calibrated": (("mark", "xy"), cal, {"units": "mm"}),
             "measured": (("mark", "xy"), mea, {"units": "mm"}),
             "residual_affine": (("mark", "xy"), res_aff, {"units": "mm", "long_name": "after the best global affine"}),
             "residual_projective": (("mark", "xy"), res_proj,
                                     {"units": "mm", "long_name": "after the best global projective transformation"}),
             "residual_cells": (("mark", "xy"), np.zeros_like(cal),
                                {"units": "mm", "long_name": "after the per-cell correction (exact at the marks)"})},
            coords={"mark": list(self.grid.ids), "xy": ["x", "y"]},
            attrs={"method": self.method,
                   "rms_affine_mm": float(np.sqrt(np.mean(np.sum(res_aff ** 2, axis=1)))),
                   "rms_projective_mm": float(np.sqrt(np.mean(np.sum(res_proj ** 2, axis=1))))})
        return ds
