"""The distortion models of usgscsm that the lunar drivers do not produce: ``transverse``, ``radtan``,
``dawnfc``, ``kplo_shadowcam``.

They let lunarmap load every ISD usgscsm loads (its test ISDs, other pipelines' output) and give
``lunarmap isd --csm`` a model usgscsm applies (a fitted ``transverse`` polynomial replaces the
Lunar Orbiter and Apollo metric models usgscsm lacks, :func:`fit_transverse`). Each is written from
usgscsm's ``Distortion.cpp`` (``removeDistortion`` / ``applyDistortion``); all coordinates are
focal-plane millimetres, as in :mod:`lunarmap.camera.distortion`.

``"transverse"``
    ``distorted = T(undistorted)``, a third-order polynomial per axis in the basis
    ``(1, x, y, x², xy, y², x³, x²y, xy², y³)`` with ALE's ``{"x": [10], "y": [10]}`` (shorter lists
    padded with zeros). Undistorting inverts ``T`` by 2-D Newton iteration from ``u = d``, as usgscsm
    does; where the Jacobian's determinant falls below 1e-6 usgscsm stops and keeps the current
    iterate, and so does lunarmap (usgscsm's ``simpleFramerISD.json`` has the singular
    ``y = x``; its tests pass because of that rule).
``"radtan"``
    OpenCV's radial-tangential model ``(k1, k2, p1, p2, k3)`` on coordinates normalised by the focal
    length, distorted = f(undistorted); undistorted by Newton iteration.
``"dawnfc"``
    Dawn Framing Camera: ``d = u (1 + k r_u²)``; undistorted by Newton on the radius.
``"kplo_shadowcam"``
    KPLO ShadowCam (ISIS ``ShadowCamDistortionMap``): ``ux = dx``, ``uy = dy (1 + k dy²)``; the
    inverse solves the cubic by Newton iteration.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InvalidInputError
from .distortion import DISTORTION_MODELS, Distortion, _jacobian, _xy

__all__ = ["TransverseDistortion", "RadTanDistortion", "DawnFcDistortion", "ShadowCamDistortion",
           "transverse_basis", "fit_transverse", "fit_radtan"]

Array = NDArray[np.float64]

_TOL = 1e-13
_MAXITER = 50
#: usgscsm's ``newtonRaphson`` stops at a Jacobian determinant below this and keeps its iterate
_SINGULAR = 1e-6


def transverse_basis(x: Array, y: Array) -> tuple[Array, Array, Array]:
    """The 10 monomials of the transverse model and their x and y derivatives, each ``(..., 10)``."""
    one, zero = np.ones_like(x), np.zeros_like(x)
    f = np.stack([one, x, y, x * x, x * y, y * y, x ** 3, x * x * y, x * y * y, y ** 3], axis=-1)
    fx = np.stack([zero, one, zero, 2 * x, y, zero, 3 * x * x, 2 * x * y, y * y, zero], axis=-1)
    fy = np.stack([zero, zero, one, zero, x, 2 * y, zero, x * x, 2 * x * y, 3 * y * y], axis=-1)
    return f, fx, fy


class TransverseDistortion(Distortion):
    """usgscsm's transverse model: distorted coordinates are third-order polynomials of undistorted ones.

    Parameters
    ----------
    x, y : sequence of float
        Up to 10 coefficients each (mm-based), basis ``(1, x, y, x², xy, y², x³, x²y, xy², y³)``.
    """

    name = "transverse"

    def __init__(self, x: Sequence[float] | NDArray, y: Sequence[float] | NDArray) -> None:
        cx = [float(c) for c in np.atleast_1d(x)]
        cy = [float(c) for c in np.atleast_1d(y)]
        if len(cx) > 10 or len(cy) > 10:
            raise InvalidInputError("transverse distortion takes at most 10 coefficients per axis")
        self.cx = np.array(cx + [0.0] * (10 - len(cx)))
        self.cy = np.array(cy + [0.0] * (10 - len(cy)))

    def _apply(self, x: Array, y: Array) -> tuple[Array, Array, Array]:
        f, fx, fy = transverse_basis(x, y)
        jac = _jacobian(fx @ self.cx, fy @ self.cx, fx @ self.cy, fy @ self.cy)
        return f @ self.cx, f @ self.cy, jac

    def distort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        ux, uy = _xy(x, y)
        dx, dy, _ = self._apply(ux, uy)
        return dx, dy

    def distort_with_jacobian(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array, Array]:
        ux, uy = _xy(x, y)
        return self._apply(ux, uy)

    def undistort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        dx, dy = _xy(x, y)
        ux, uy = dx.copy(), dy.copy()
        active = np.ones(dx.shape, dtype=bool)
        with np.errstate(all="ignore"):
            for _ in range(_MAXITER):
                fx, fy, j = self._apply(ux, uy)
                det = j[..., 0, 0] * j[..., 1, 1] - j[..., 0, 1] * j[..., 1, 0]
                active &= np.abs(det) >= _SINGULAR      # usgscsm's rule: keep the iterate, stop
                rx, ry = dx - fx, dy - fy
                sx = np.where(active, (j[..., 1, 1] * rx - j[..., 0, 1] * ry) / det, 0.0)
                sy = np.where(active, (j[..., 0, 0] * ry - j[..., 1, 0] * rx) / det, 0.0)
                ux, uy = ux + sx, uy + sy
                active &= np.maximum(np.abs(sx), np.abs(sy)) > _TOL * np.maximum(1.0, np.hypot(ux, uy))
                if not np.any(active):
                    break
        return ux, uy

    def undistort_jacobian(self, x: ArrayLike, y: ArrayLike) -> Array:
        ux, uy = self.undistort(x, y)
        _, _, j = self._apply(ux, uy)
        return _inverse2(j)

    def __repr__(self) -> str:
        return f"TransverseDistortion(x={self.cx.tolist()!r}, y={self.cy.tolist()!r})"


def _inverse2(j: Array) -> Array:
    det = j[..., 0, 0] * j[..., 1, 1] - j[..., 0, 1] * j[..., 1, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        return _jacobian(j[..., 1, 1] / det, -j[..., 0, 1] / det, -j[..., 1, 0] / det, j[..., 0, 0] / det)


class RadTanDistortion(Distortion):
    """OpenCV radial-tangential distortion ``(k1, k2, p1, p2, k3)`` on ``u / f`` (usgscsm ``RADTAN``).

    Parameters
    ----------
    coefficients : sequence of 5 float
        ``k1, k2, p1, p2, k3`` (dimensionless: the model works on coordinates divided by ``f``).
    focal_length : float
        Focal length, mm.
    """

    name = "radtan"

    def __init__(self, coefficients: Sequence[float] | NDArray, focal_length: float) -> None:
        k = [float(c) for c in coefficients]
        if len(k) != 5:
            raise InvalidInputError(f"radtan distortion takes 5 coefficients (k1, k2, p1, p2, k3), got {len(k)}")
        if not np.isfinite(focal_length) or focal_length == 0.0:
            raise InvalidInputError(f"radtan distortion needs a finite non-zero focal length, got {focal_length!r}")
        self.k1, self.k2, self.p1, self.p2, self.k3 = k
        self.f = float(focal_length)

    def _normalised(self, x: Array, y: Array) -> tuple[Array, Array, Array]:
        """Distorted normalised coordinates of normalised ``(x, y)`` and their Jacobian."""
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        drad = self.k1 + r2 * (2.0 * self.k2 + 3.0 * r2 * self.k3)       # d radial / d r2
        dx = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x)
        dy = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y
        j00 = radial + 2.0 * x * x * drad + 2.0 * self.p1 * y + 6.0 * self.p2 * x
        j01 = 2.0 * x * y * drad + 2.0 * self.p1 * x + 2.0 * self.p2 * y
        j10 = 2.0 * x * y * drad + 2.0 * self.p1 * x + 2.0 * self.p2 * y
        j11 = radial + 2.0 * y * y * drad + 6.0 * self.p1 * y + 2.0 * self.p2 * x
        return dx, dy, _jacobian(j00, j01, j10, j11)

    def distort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        ux, uy = _xy(x, y)
        dx, dy, _ = self._normalised(ux / self.f, uy / self.f)
        return dx * self.f, dy * self.f

    def distort_with_jacobian(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array, Array]:
        ux, uy = _xy(x, y)
        dx, dy, j = self._normalised(ux / self.f, uy / self.f)
        return dx * self.f, dy * self.f, j

    def undistort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        dx, dy = _xy(x, y)
        nx, ny = dx / self.f, dy / self.f
        ux, uy = nx.copy(), ny.copy()
        active = np.ones(nx.shape, dtype=bool)
        with np.errstate(all="ignore"):
            for _ in range(_MAXITER):
                fx, fy, j = self._normalised(ux, uy)
                det = j[..., 0, 0] * j[..., 1, 1] - j[..., 0, 1] * j[..., 1, 0]
                rx, ry = nx - fx, ny - fy
                sx = (j[..., 1, 1] * rx - j[..., 0, 1] * ry) / det
                sy = (j[..., 0, 0] * ry - j[..., 1, 0] * rx) / det
                ux, uy = np.where(active, ux + sx, ux), np.where(active, uy + sy, uy)
                active &= np.maximum(np.abs(sx), np.abs(sy)) > _TOL
                if not np.any(active):
                    break
        bad = active | ~np.isfinite(ux)
        return np.where(bad, np.nan, ux * self.f), np.where(bad, np.nan, uy * self.f)

    def undistort_jacobian(self, x: ArrayLike, y: ArrayLike) -> Array:
        ux, uy = self.undistort(x, y)
        _, _, j = self._normalised(ux / self.f, uy / self.f)
        return _inverse2(j)

    def __repr__(self) -> str:
        return (f"RadTanDistortion(coefficients={[self.k1, self.k2, self.p1, self.p2, self.k3]!r}, "
                f"focal_length={self.f!r})")


class DawnFcDistortion(Distortion):
    """Dawn Framing Camera: ``d = u (1 + k |u|²)`` (usgscsm ``DAWNFC``).

    Parameters
    ----------
    k : float
        Coefficient, mm^-2.
    """

    name = "dawnfc"

    def __init__(self, k: float) -> None:
        self.k = float(k)

    def distort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        ux, uy = _xy(x, y)
        s = 1.0 + self.k * (ux * ux + uy * uy)
        return ux * s, uy * s

    def distort_with_jacobian(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array, Array]:
        ux, uy = _xy(x, y)
        s = 1.0 + self.k * (ux * ux + uy * uy)
        g = 2.0 * self.k
        return ux * s, uy * s, _jacobian(s + g * ux * ux, g * ux * uy, g * ux * uy, s + g * uy * uy)

    def undistort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        dx, dy = _xy(x, y)
        rd = np.hypot(dx, dy)
        r = rd.copy()
        with np.errstate(all="ignore"):
            for _ in range(_MAXITER):     # r (1 + k r^2) = rd for the undistorted radius r
                step = (r * (1.0 + self.k * r * r) - rd) / (1.0 + 3.0 * self.k * r * r)
                r = r - step
                if not np.any(np.abs(step) > _TOL * np.maximum(1.0, rd)):
                    break
            ratio = np.where(rd > 0.0, r / rd, 1.0)
        ratio = np.where(np.isfinite(ratio) & (1.0 + 3.0 * self.k * r * r > 0.0), ratio, np.nan)
        return dx * ratio, dy * ratio

    def undistort_jacobian(self, x: ArrayLike, y: ArrayLike) -> Array:
        ux, uy = self.undistort(x, y)
        return _inverse2(self.distort_with_jacobian(ux, uy)[2])

    def __repr__(self) -> str:
        return f"DawnFcDistortion(k={self.k!r})"


class ShadowCamDistortion(Distortion):
    """KPLO ShadowCam: ``ux = dx``, ``uy = dy (1 + k dy²)`` (usgscsm ``KPLOSHADOWCAM``).

    Parameters
    ----------
    k : float
        Coefficient, mm^-2.
    """

    name = "kplo_shadowcam"

    def __init__(self, k: float) -> None:
        self.k = float(k)

    def undistort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        dx, dy = _xy(x, y)
        return dx.copy(), dy * (1.0 + self.k * dy * dy)

    def undistort_jacobian(self, x: ArrayLike, y: ArrayLike) -> Array:
        dx, dy = _xy(x, y)
        zero = np.zeros_like(dx)
        return _jacobian(np.ones_like(dx), zero, zero, 1.0 + 3.0 * self.k * dy * dy)

    def distort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        ux, uy = _xy(x, y)
        dy = uy.copy()
        with np.errstate(all="ignore"):
            for _ in range(_MAXITER):
                der = 1.0 + 3.0 * self.k * dy * dy
                step = (dy * (1.0 + self.k * dy * dy) - uy) / der
                dy = dy - step
                if not np.any(np.abs(step) > _TOL * np.maximum(1.0, np.abs(uy))):
                    break
        ok = np.isfinite(dy) & (1.0 + 3.0 * self.k * dy * dy > 0.0)
        return ux.copy(), np.where(ok, dy, np.nan)

    def __repr__(self) -> str:
        return f"ShadowCamDistortion(k={self.k!r})"


def _one(block: Mapping[str, Any], model: str) -> float:
    k = np.atleast_1d(block.get("coefficients", []))
    if k.size != 1:
        raise InvalidInputError(f"{model} distortion takes exactly 1 coefficient, got {k.size}")
    return float(k[0])


def _make_transverse(block: Mapping[str, Any]) -> Distortion:
    try:
        return TransverseDistortion(block["x"], block["y"])
    except KeyError as exc:
        raise InvalidInputError(f"transverse distortion block lacks {exc.args[0]!r}") from None


def _make_radtan(block: Mapping[str, Any]) -> Distortion:
    if "focal_length" not in block:
        raise InvalidInputError("radtan distortion needs the focal length (distortion_from_interior passes it)")
    return RadTanDistortion(np.atleast_1d(block.get("coefficients", [])), float(block["focal_length"]))


DISTORTION_MODELS["transverse"] = _make_transverse
DISTORTION_MODELS["radtan"] = _make_radtan
DISTORTION_MODELS["dawnfc"] = lambda block: DawnFcDistortion(_one(block, "dawnfc"))
DISTORTION_MODELS["kplo_shadowcam"] = lambda block: ShadowCamDistortion(_one(block, "kplo_shadowcam"))


def fit_transverse(distortion: Distortion, x: ArrayLike, y: ArrayLike) -> tuple[TransverseDistortion, Array]:
    """The transverse polynomial closest (least squares) to a distortion model over focal-plane points.

    Parameters
    ----------
    distortion : Distortion
        The model to replace (e.g. Apollo metric, Lunar Orbiter).
    x, y : array_like
        *Distorted* focal-plane points covering the image, mm.

    Returns
    -------
    TransverseDistortion
        ``T`` with ``T(undistort(d)) ~= d``.
    residual : ndarray (n, 2)
        ``T(u) - d`` at the points, mm.
    """
    dx, dy = (np.ravel(v) for v in _xy(x, y))
    ux, uy = distortion.undistort(dx, dy)
    ok = np.isfinite(ux) & np.isfinite(uy)
    if np.count_nonzero(ok) < 10:
        raise InvalidInputError("fitting a transverse polynomial needs at least 10 points the model undistorts")
    f, _, _ = transverse_basis(ux[ok], uy[ok])
    # scale the columns: coordinates of ~100 mm make the cubic terms 1e6 times the constant one
    scale = np.maximum(np.abs(f).max(axis=0), 1e-300)
    cx, *_ = np.linalg.lstsq(f / scale, dx[ok], rcond=None)
    cy, *_ = np.linalg.lstsq(f / scale, dy[ok], rcond=None)
    model = TransverseDistortion(cx / scale, cy / scale)
    px, py = model.distort(ux[ok], uy[ok])
    return model, np.column_stack([px - dx[ok], py - dy[ok]])


def fit_radtan(distortion: Distortion, x: ArrayLike, y: ArrayLike,
               focal_length: float) -> tuple[RadTanDistortion, tuple[float, float], Array]:
    """The radial-tangential model closest (least squares) to a distortion model, about its optical axis.

    The radtan model is centred on the focal-plane origin; models with a principal point off the origin
    (Apollo metric) are fitted about the distorted position of the optical axis, ``distort(0, 0)``, which
    the caller moves to the origin by shifting the focal plane (``shift``, mm, to subtract from distorted
    coordinates). The model is linear in its 5 coefficients, so the fit is one linear least-squares solve
    on coordinates normalised by the focal length.

    Returns
    -------
    RadTanDistortion
        ``R`` with ``R(undistort(d)) ~= d - shift``.
    shift : (float, float)
        Distorted position of the optical axis, mm.
    residual : ndarray (n, 2)
        ``R(u) - (d - shift)`` at the points, mm.
    """
    dx, dy = (np.ravel(v) for v in _xy(x, y))
    sx, sy = (float(v) for v in distortion.distort(0.0, 0.0))
    ux, uy = distortion.undistort(dx, dy)
    ok = np.isfinite(ux) & np.isfinite(uy)
    f = float(focal_length)
    nx, ny = ux[ok] / f, uy[ok] / f
    r2 = nx * nx + ny * ny
    a = np.vstack([np.stack([nx * r2, nx * r2 ** 2, 2 * nx * ny, r2 + 2 * nx * nx, nx * r2 ** 3], 1),
                   np.stack([ny * r2, ny * r2 ** 2, r2 + 2 * ny * ny, 2 * nx * ny, ny * r2 ** 3], 1)])
    b = np.concatenate([(dx[ok] - sx) / f - nx, (dy[ok] - sy) / f - ny])
    k1, k2, p1, p2, k3 = np.linalg.lstsq(a, b, rcond=None)[0]
    model = RadTanDistortion([k1, k2, p1, p2, k3], f)
    px, py = model.distort(ux[ok], uy[ok])
    return model, (sx, sy), np.column_stack([px - (dx[ok] - sx), py - (dy[ok] - sy)])
