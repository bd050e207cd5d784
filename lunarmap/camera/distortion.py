"""Optical distortion models of the focal plane, keyed by ALE's model names.

Every model maps between *distorted* focal-plane coordinates (where the
light actually lands, what the detector measures) and *undistorted* ones
(the pinhole projection ``(x, y) = f * (vx/vz, vy/vz)``), both millimetres in
the sensor frame:

* :meth:`Distortion.undistort` removes distortion from measured coordinates
  (ISIS ``SetFocalPlane``, usgscsm ``removeDistortion``);
* :meth:`Distortion.distort` adds it to ideal coordinates (ISIS
  ``SetUndistortedFocalPlane``, usgscsm ``applyDistortion``).

Each published model defines one direction in closed form; the other is
solved here in closed form where one exists or by vectorised Newton
iteration to below 1e-12 mm, so that both directions are exact inverses of
each other (the ISIS/usgscsm fixed-point loops stop at 1e-6 to 1e-10 mm).
Where the model has no inverse (far outside the field of view, beyond the
turning point of a polynomial) the result is NaN, never an exception:
callers such as ``ground_to_image`` treat such points as not imaged.

Models
------
``"none"``
    Identity.
``"lrolrocnac"``
    LRO NAC, IK ``OD_K = k1`` (1.81e-5 mm^-2 for NAC-L). Implemented from ISIS
    ``LroNarrowAngleDistortionMap::SetFocalPlane`` (ISIS3 >= 2010-08, where the
    IK sign was aligned with the calibration report) and usgscsm
    ``removeDistortion`` case ``LROLROCNAC``, which are identical::

        ux = dx
        uy = dy / (1 + k1 * dy**2)

    Only the sample (``y``, across the single detector line) coordinate is
    distorted. The inverse solves ``k1*uy*dy**2 - dy + uy = 0`` for its small
    root in closed form (ISIS iterates); it has no solution for
    ``|uy| > 1/(2*sqrt(k1))`` (about 117 mm, far off the 35 mm detector), where
    NaN is returned.
``"radial"``
    ISIS ``CameraDistortionMap::SetFocalPlane`` (the default ``OD_K`` map used
    by e.g. Clementine UVVIS) and usgscsm ``removeDistortion`` case
    ``RADIAL``, identical::

        r2 = dx**2 + dy**2
        (ux, uy) = (dx, dy) * (1 - (k0 + k1*r2 + k2*r2**2))

    with ``OD_K = (k0, k1, k2)`` (fewer coefficients are padded with zeros).
    Note the minus sign: ISIS subtracts ``dr/r`` from the *distorted*
    position; it is not ``1 + k1 + k2 r^2 + ...``. ISIS skips the correction
    for ``r2 <= 1e-6 mm^2``; we do not, so that the model is smooth (the
    difference there is below 1e-9 mm for the coefficients in use).
    The inverse is a 1-D Newton iteration on the radius.
``"kaguyalism"``
    Kaguya TC / MI (SEL_TC_V01.TI), implemented from usgscsm
    ``removeDistortion`` case ``KAGUYALISM`` (ISIS
    ``KaguyaTcCameraDistortionMap::SetFocalPlane`` is the same without the
    boresight terms)::

        r = hypot(dx, dy)
        ux = dx + (a0 + a1*r + a2*r**2 + a3*r**3) + boresight_x
        uy = dy + (b0 + b1*r + b2*r**2 + b3*r**3) + boresight_y

    with ALE's ``{"x": [a0..a3], "y": [b0..b3], "boresight_x", "boresight_y"}``.
    The inverse is a 2-D Newton iteration.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, Callable, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import DistortionPartialsError, InvalidInputError

__all__ = [
    "Distortion",
    "NoDistortion",
    "LroNacDistortion",
    "RadialDistortion",
    "KaguyaLismDistortion",
    "DISTORTION_MODELS",
    "make_distortion",
    "distortion_from_interior",
]

# Newton iterations stop below this step (mm): far below the 1e-9 mm
# round-trip requirement, still above float64 noise on a ~20 mm coordinate.
_NEWTON_TOL = 1e-13
_NEWTON_MAXITER = 50

Array = NDArray[np.float64]


def _xy(x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
    x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    return x, y


class Distortion(ABC):
    """A focal-plane distortion model; all coordinates in millimetres."""

    #: ALE / usgscsm name of the model.
    name: str = ""

    @abstractmethod
    def undistort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        """Remove distortion from measured (distorted) focal-plane coordinates.

        Parameters
        ----------
        x, y : array_like
            Distorted focal-plane coordinates, mm (broadcast together).

        Returns
        -------
        (ndarray, ndarray)
            Undistorted coordinates, mm.
        """

    @abstractmethod
    def distort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        """Add distortion to ideal (undistorted) focal-plane coordinates.

        Parameters
        ----------
        x, y : array_like
            Undistorted focal-plane coordinates, mm.

        Returns
        -------
        (ndarray, ndarray)
            Distorted coordinates, mm; NaN where the model has no solution.
        """

    def undistort_jacobian(self, x: ArrayLike, y: ArrayLike) -> Array:
        """Partial derivatives of :meth:`undistort` at distorted focal-plane coordinates.

        Parameters
        ----------
        x, y : array_like
            Distorted focal-plane coordinates, mm.

        Returns
        -------
        ndarray, shape (..., 2, 2)
            ``d(ux, uy) / d(x, y)``, dimensionless (mm per mm).

        Raises
        ------
        DistortionPartialsError
            The model defines no partial derivatives (the adjustment cannot use it).
        """
        raise DistortionPartialsError(
            f"distortion model {type(self).__name__} ({self.name or 'unnamed'}) has no analytic partial "
            "derivatives (undistort_jacobian): images with it cannot be adjusted")

    def distort_with_jacobian(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array, Array]:
        """Distorted coordinates of ideal ones and the partials ``d(distorted) / d(undistorted)``.

        The partials are the inverse of :meth:`undistort_jacobian` at the distorted point
        (inverse-function rule), so every model needs only one direction's derivatives.

        Parameters
        ----------
        x, y : array_like
            Undistorted focal-plane coordinates, mm.

        Returns
        -------
        dx, dy : ndarray
            Distorted coordinates, mm (NaN where the model has no solution).
        jac : ndarray, shape (..., 2, 2)
            ``d(dx, dy) / d(x, y)``, dimensionless.
        """
        dx, dy = self.distort(x, y)
        ju = self.undistort_jacobian(dx, dy)
        det = ju[..., 0, 0] * ju[..., 1, 1] - ju[..., 0, 1] * ju[..., 1, 0]
        jac = np.empty_like(ju)
        with np.errstate(divide="ignore", invalid="ignore"):
            jac[..., 0, 0] = ju[..., 1, 1] / det
            jac[..., 0, 1] = -ju[..., 0, 1] / det
            jac[..., 1, 0] = -ju[..., 1, 0] / det
            jac[..., 1, 1] = ju[..., 0, 0] / det
        return dx, dy, jac

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


def _jacobian(j00: Array, j01: Array, j10: Array, j11: Array) -> Array:
    j00, j01, j10, j11 = np.broadcast_arrays(j00, j01, j10, j11)
    out = np.empty(j00.shape + (2, 2))
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = j00, j01, j10, j11
    return out


class NoDistortion(Distortion):
    """The identity model (ALE ``"none"`` or no ``optical_distortion`` block)."""

    name = "none"

    def undistort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        x, y = _xy(x, y)
        return x.copy(), y.copy()

    def distort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        x, y = _xy(x, y)
        return x.copy(), y.copy()

    def undistort_jacobian(self, x: ArrayLike, y: ArrayLike) -> Array:
        x, _ = _xy(x, y)
        return _jacobian(np.ones_like(x), np.zeros_like(x), np.zeros_like(x), np.ones_like(x))


class LroNacDistortion(Distortion):
    """LRO NAC sample-direction distortion, ``uy = dy / (1 + k1 dy^2)``.

    Parameters
    ----------
    k1 : float
        IK ``OD_K``, mm^-2 (1.81e-5 for NAC-L, 1.83e-5 for NAC-R).
    """

    name = "lrolrocnac"

    def __init__(self, k1: float) -> None:
        self.k1 = float(k1)

    def undistort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        x, y = _xy(x, y)
        with np.errstate(divide="ignore", invalid="ignore"):
            return x.copy(), y / (1.0 + self.k1 * y * y)

    def distort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        x, y = _xy(x, y)
        # Small root of k1*uy*dy^2 - dy + uy = 0 written without cancellation:
        # dy = 2 uy / (1 + sqrt(1 - 4 k1 uy^2)); equals uy for k1 = 0.
        disc = 1.0 - 4.0 * self.k1 * y * y
        with np.errstate(invalid="ignore"):
            dy = 2.0 * y / (1.0 + np.sqrt(disc))
        return x.copy(), np.where(disc >= 0.0, dy, np.nan)

    def undistort_jacobian(self, x: ArrayLike, y: ArrayLike) -> Array:
        x, y = _xy(x, y)
        q = 1.0 + self.k1 * y * y
        zero = np.zeros_like(x)
        return _jacobian(np.ones_like(x), zero, zero, (1.0 - self.k1 * y * y) / (q * q))

    def __repr__(self) -> str:
        return f"LroNacDistortion(k1={self.k1!r})"


class RadialDistortion(Distortion):
    """ISIS ``OD_K`` radial polynomial, ``u = d * (1 - (k0 + k1 r^2 + k2 r^4))``, r of d.

    Parameters
    ----------
    coefficients : sequence of float
        ``(k0, k1, k2)``: dimensionless, mm^-2, mm^-4; shorter sequences are
        padded with zeros.
    """

    name = "radial"

    def __init__(self, coefficients: Sequence[float] | NDArray) -> None:
        k = [float(c) for c in coefficients]
        if len(k) > 3:
            raise InvalidInputError(f"radial distortion takes at most 3 coefficients (OD_K), got {len(k)}")
        self.k = tuple(k + [0.0] * (3 - len(k)))

    def _scale(self, r2: Array) -> Array:
        k0, k1, k2 = self.k
        return 1.0 - (k0 + r2 * (k1 + r2 * k2))

    def undistort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        x, y = _xy(x, y)
        s = self._scale(x * x + y * y)
        return x * s, y * s

    def distort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        x, y = _xy(x, y)
        k0, k1, k2 = self.k
        ru = np.hypot(x, y)
        # Solve g(r) = r (1 - k0 - k1 r^2 - k2 r^4) - ru = 0 for the distorted radius.
        r = ru.copy()
        big = np.zeros(ru.shape, dtype=bool)
        for _ in range(_NEWTON_MAXITER):
            r2 = r * r
            g = r * (1.0 - (k0 + r2 * (k1 + r2 * k2))) - ru
            dg = 1.0 - k0 - 3.0 * k1 * r2 - 5.0 * k2 * r2 * r2
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                step = g / dg
            r = r - step
            big = np.abs(step) > _NEWTON_TOL * np.maximum(1.0, ru)
            if not np.any(big):
                break
        # Beyond the turning point of r (1 - dr/r) there is no distorted
        # radius (Newton wanders or lands on the folded branch): no solution.
        r2 = r * r
        fold = (1.0 - k0 - 3.0 * k1 * r2 - 5.0 * k2 * r2 * r2) <= 0.0
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(ru > 0.0, r / ru, 1.0 / (1.0 - k0))
        ratio = np.where(big | fold | (r < 0.0), np.nan, ratio)
        return x * ratio, y * ratio

    def undistort_jacobian(self, x: ArrayLike, y: ArrayLike) -> Array:
        x, y = _xy(x, y)
        _, k1, k2 = self.k
        r2 = x * x + y * y
        s = self._scale(r2)
        g = -2.0 * (k1 + 2.0 * k2 * r2)      # 2 ds/d(r^2): d(u_i)/d(d_j) = s delta_ij + g d_i d_j
        return _jacobian(s + g * x * x, g * x * y, g * x * y, s + g * y * y)

    def __repr__(self) -> str:
        return f"RadialDistortion(coefficients={self.k!r})"


class KaguyaLismDistortion(Distortion):
    """Kaguya TC/MI per-axis polynomials in the distorted radius, plus boresight offsets.

    Parameters
    ----------
    x, y : sequence of 4 float
        ``(a0, a1, a2, a3)`` and ``(b0, b1, b2, b3)``: mm, dimensionless,
        mm^-1, mm^-2 (IK ``DISTORTION_COEF_X`` / ``_Y``).
    boresight_x, boresight_y : float
        Boresight offsets, mm (IK ``BORESIGHT``).
    """

    name = "kaguyalism"

    def __init__(self, x: Sequence[float] | NDArray, y: Sequence[float] | NDArray, boresight_x: float = 0.0,
                 boresight_y: float = 0.0) -> None:
        ax = [float(c) for c in x]
        ay = [float(c) for c in y]
        if len(ax) > 4 or len(ay) > 4:
            raise InvalidInputError("kaguyalism distortion takes at most 4 coefficients per axis")
        self.a = tuple(ax + [0.0] * (4 - len(ax)))
        self.b = tuple(ay + [0.0] * (4 - len(ay)))
        self.boresight_x = float(boresight_x)
        self.boresight_y = float(boresight_y)

    @staticmethod
    def _poly(c: tuple[float, ...], r: Array) -> Array:
        return c[0] + r * (c[1] + r * (c[2] + r * c[3]))

    @staticmethod
    def _dpoly(c: tuple[float, ...], r: Array) -> Array:
        return c[1] + r * (2.0 * c[2] + r * 3.0 * c[3])

    def undistort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        x, y = _xy(x, y)
        r = np.hypot(x, y)
        return (x + self._poly(self.a, r) + self.boresight_x,
                y + self._poly(self.b, r) + self.boresight_y)

    def undistort_jacobian(self, x: ArrayLike, y: ArrayLike) -> Array:
        x, y = _xy(x, y)
        r = np.hypot(x, y)
        # d r / d(x, y) = (x, y) / r; the a1*r term has no derivative at r = 0 (0 is used, as in distort)
        cx = np.where(r > 0.0, x / np.where(r > 0.0, r, 1.0), 0.0)
        cy = np.where(r > 0.0, y / np.where(r > 0.0, r, 1.0), 0.0)
        pa, pb = self._dpoly(self.a, r), self._dpoly(self.b, r)
        return _jacobian(1.0 + pa * cx, pa * cy, pb * cx, 1.0 + pb * cy)

    def distort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        ux, uy = _xy(x, y)
        # Fixed-point start as in usgscsm applyDistortion, then 2-D Newton.
        dx = ux - self.boresight_x - self.a[0]
        dy = uy - self.boresight_y - self.b[0]
        for _ in range(_NEWTON_MAXITER):
            with np.errstate(all="ignore"):  # diverging points end as NaN below
                dx, dy, big = self._newton_step(ux, uy, dx, dy)
            if not np.any(big):
                break
        # No convergence means no preimage near the field of view.
        return np.where(big, np.nan, dx), np.where(big, np.nan, dy)

    def _newton_step(self, ux: Array, uy: Array, dx: Array, dy: Array
                     ) -> tuple[Array, Array, NDArray[np.bool_]]:
        """One 2-D Newton step of ``undistort(d) = u``; also whether it was still large."""
        r = np.hypot(dx, dy)
        fx = dx + self._poly(self.a, r) + self.boresight_x - ux
        fy = dy + self._poly(self.b, r) + self.boresight_y - uy
        # d r / d(dx, dy) = (dx, dy) / r; the a1*r term has no derivative at r = 0, use 0
        cx = np.where(r > 0.0, dx / r, 0.0)
        cy = np.where(r > 0.0, dy / r, 0.0)
        pa = self._dpoly(self.a, r)
        pb = self._dpoly(self.b, r)
        j11 = 1.0 + pa * cx
        j12 = pa * cy
        j21 = pb * cx
        j22 = 1.0 + pb * cy
        det = j11 * j22 - j12 * j21
        sx = (j22 * fx - j12 * fy) / det
        sy = (j11 * fy - j21 * fx) / det
        big = np.maximum(np.abs(sx), np.abs(sy)) > _NEWTON_TOL * np.maximum(1.0, r)
        return dx - sx, dy - sy, big

    def __repr__(self) -> str:
        return (f"KaguyaLismDistortion(x={self.a!r}, y={self.b!r}, boresight_x={self.boresight_x!r}, "
                f"boresight_y={self.boresight_y!r})")


def _coefficients(block: Mapping[str, Any]) -> list[float]:
    if "coefficients" not in block:
        raise InvalidInputError(f"distortion block needs 'coefficients', got keys {sorted(block)}")
    return [float(c) for c in np.atleast_1d(block["coefficients"])]


def _make_lroc(block: Mapping[str, Any]) -> Distortion:
    k = _coefficients(block)
    if len(k) != 1:
        raise InvalidInputError(f"lrolrocnac distortion takes exactly 1 coefficient (OD_K), got {len(k)}")
    return LroNacDistortion(k[0])


def _make_kaguya(block: Mapping[str, Any]) -> Distortion:
    try:
        return KaguyaLismDistortion(block["x"], block["y"], block.get("boresight_x", 0.0),
                                    block.get("boresight_y", 0.0))
    except KeyError as exc:
        raise InvalidInputError(f"kaguyalism distortion block lacks {exc.args[0]!r}") from None


#: Constructors keyed by ALE model name; each takes the ``optical_distortion.<model>`` block.
DISTORTION_MODELS: dict[str, Callable[[Mapping[str, Any]], Distortion]] = {
    "none": lambda block: NoDistortion(),
    "lrolrocnac": _make_lroc,
    "radial": lambda block: RadialDistortion(_coefficients(block)),
    "kaguyalism": _make_kaguya,
}


def make_distortion(model: str, coefficients: Mapping[str, Any] | None = None) -> Distortion:
    """Build a distortion model from ALE's name and ``optical_distortion`` block.

    Parameters
    ----------
    model : str
        A name of :data:`DISTORTION_MODELS` (case-insensitive): ``"none"``, ``"lrolrocnac"``, ``"radial"``,
        ``"kaguyalism"``, the film cameras' ``"lunarorbiter"`` and ``"apollometric"``, and usgscsm's
        ``"transverse"``, ``"radtan"``, ``"dawnfc"``, ``"kplo_shadowcam"``
        (:mod:`lunarmap.camera.distortion_csm`).
    coefficients : mapping, optional
        The block, e.g. ``{"coefficients": [1.81e-05]}`` or, for kaguyalism,
        ``{"x": [...], "y": [...], "boresight_x": ..., "boresight_y": ...}``.

    Raises
    ------
    InvalidInputError
        Unknown model or malformed block.
    """
    key = (model or "none").lower()
    if key not in DISTORTION_MODELS:
        raise InvalidInputError(f"unknown distortion model {model!r}; known: {sorted(DISTORTION_MODELS)}")
    return DISTORTION_MODELS[key](dict(coefficients or {}))


def distortion_from_interior(interior: Any) -> Distortion:
    """The distortion model of an :class:`~lunarmap.camera.interior.InteriorOrientation`.

    Models defined on coordinates normalised by the focal length (``radtan``) get it from the
    interior orientation.
    """
    block = dict(interior.distortion_coefficients)
    if str(interior.distortion_model).lower() == "radtan":
        block["focal_length"] = float(interior.focal_length)
    return make_distortion(interior.distortion_model, block)


# --- Film cameras of the historical missions (issue 13: Lunar Orbiter, Apollo metric) ----------------

class LunarOrbiterDistortion(Distortion):
    """Lunar Orbiter high-resolution camera: perspective correction, then radial about a point of symmetry.

    Implemented from ISIS ``LoHighDistortionMap::SetFocalPlane`` (the defining direction; ISIS's
    ``SetUndistortedFocalPlane`` is a first-order approximation of its inverse, here the exact
    inverse is solved by 2-D Newton iteration)::

        s = 1 + px * dx + py * dy                      (perspective factors)
        (pcx, pcy) = (dx, dy) * s
        (qx, qy) = (pcx - x0, pcy - y0)                (point of symmetry)
        ux = pcx - (k0 + k1 * r2) * qx,  r2 = qx**2 + qy**2 (likewise uy)

    with IK ``PERSPECTIVE_FACTORS = (px, py)`` (mm^-1), ``POINT_OF_SYMMETRY = (x0, y0)`` (mm) and
    ``OD_K = (k0, k1)`` (dimensionless, mm^-2). ALE's ``lunarorbiter`` block carries ``perspective_x``,
    ``perspective_y``, ``center_point_x``, ``center_point_y`` but not the ``OD_K`` coefficients;
    lunarmap adds them as ``coefficients`` (absent: zero, the radial part is then off). ISIS skips the
    radial term within 1e-3 mm of the point of symmetry; here it is not skipped (smooth model).
    """

    name = "lunarorbiter"

    def __init__(self, perspective_x: float, perspective_y: float, center_point_x: float, center_point_y: float,
                 coefficients: Sequence[float] | NDArray = (0.0, 0.0)) -> None:
        k = [float(c) for c in coefficients]
        if len(k) > 3 or (len(k) == 3 and k[2] != 0.0):
            raise InvalidInputError(f"lunarorbiter distortion uses OD_K = (k0, k1) (a third value must be 0), got {k}")
        self.px, self.py = float(perspective_x), float(perspective_y)
        self.x0, self.y0 = float(center_point_x), float(center_point_y)
        self.k = tuple((k + [0.0, 0.0])[:2])

    def undistort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        x, y = _xy(x, y)
        s = 1.0 + self.px * x + self.py * y
        pcx, pcy = x * s, y * s
        qx, qy = pcx - self.x0, pcy - self.y0
        g = self.k[0] + self.k[1] * (qx * qx + qy * qy)
        return pcx - g * qx, pcy - g * qy

    def undistort_jacobian(self, x: ArrayLike, y: ArrayLike) -> Array:
        x, y = _xy(x, y)
        s = 1.0 + self.px * x + self.py * y
        # d(pc)/d(d): pc = d * s(d)
        a00, a01, a10, a11 = s + x * self.px, x * self.py, y * self.px, s + y * self.py
        qx, qy = x * s - self.x0, y * s - self.y0
        g = self.k[0] + self.k[1] * (qx * qx + qy * qy)
        # d(u)/d(pc) = (1 - g) I - 2 k1 q q^T
        b00, b11 = 1.0 - g - 2.0 * self.k[1] * qx * qx, 1.0 - g - 2.0 * self.k[1] * qy * qy
        b01 = -2.0 * self.k[1] * qx * qy
        return _jacobian(b00 * a00 + b01 * a10, b00 * a01 + b01 * a11, b01 * a00 + b11 * a10, b01 * a01 + b11 * a11)

    def distort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        return _newton_inverse(self, *_xy(x, y))

    def __repr__(self) -> str:
        return (f"LunarOrbiterDistortion(perspective_x={self.px!r}, perspective_y={self.py!r}, "
                f"center_point_x={self.x0!r}, center_point_y={self.y0!r}, coefficients={self.k!r})")


class ApolloMetricDistortion(Distortion):
    """Apollo 15-17 metric (mapping) camera: principal point, radial and decentering distortion.

    Implemented from ISIS ``ApolloMetricDistortionMap::SetFocalPlane`` (the defining direction; ISIS
    inverts it by fixed-point iteration to 1e-6 mm, here by 2-D Newton to 1e-13 mm)::

        (x, y) = (dx - xp, dy - yp)                    (principal point, IK PP)
        rr = x**2 + y**2
        dr = 1 + k1 rr + k2 rr**2 + k3 rr**3           (IK OD_K, mm^-2, mm^-4, mm^-6)
        dt = j1 rr + j2 rr**2                          (IK DECENTER = (j1, j2, t0); mm^-1, mm^-3, rad)
        ux = dr * x - dt * sin(t0),  uy = dr * y + dt * cos(t0)

    The undistorted coordinates are relative to the principal point. ALE models this camera without
    distortion; lunarmap's ISD names the model ``apollometric`` with ``principal_point`` (mm),
    ``coefficients`` (``OD_K``) and ``decentering`` (``DECENTER``).
    """

    name = "apollometric"

    def __init__(self, principal_point: Sequence[float] | NDArray = (0.0, 0.0), coefficients: Sequence[float] | NDArray = (0.0,) * 3,
                 decentering: Sequence[float] | NDArray = (0.0, 0.0, 0.0)) -> None:
        pp = [float(c) for c in principal_point]
        k = [float(c) for c in coefficients]
        j = [float(c) for c in decentering]
        if len(pp) != 2 or len(k) > 3 or len(j) != 3:
            raise InvalidInputError("apollometric distortion needs principal_point (2 values), at most 3 "
                                    f"coefficients (OD_K) and decentering (3 values: j1, j2, t0); got {pp}, {k}, {j}")
        self.xp, self.yp = pp
        self.k = tuple(k + [0.0] * (3 - len(k)))
        self.j1, self.j2, self.t0 = j

    def undistort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        x, y = _xy(x, y)
        x, y = x - self.xp, y - self.yp
        rr = x * x + y * y
        dr = 1.0 + rr * (self.k[0] + rr * (self.k[1] + rr * self.k[2]))
        dt = rr * (self.j1 + rr * self.j2)
        return dr * x - dt * np.sin(self.t0), dr * y + dt * np.cos(self.t0)

    def undistort_jacobian(self, x: ArrayLike, y: ArrayLike) -> Array:
        x, y = _xy(x, y)
        x, y = x - self.xp, y - self.yp
        rr = x * x + y * y
        dr = 1.0 + rr * (self.k[0] + rr * (self.k[1] + rr * self.k[2]))
        ddr = self.k[0] + rr * (2.0 * self.k[1] + 3.0 * rr * self.k[2])   # d dr / d rr
        ddt = self.j1 + 2.0 * self.j2 * rr                                  # d dt / d rr
        st, ct = np.sin(self.t0), np.cos(self.t0)
        # d rr / d(x, y) = 2 (x, y)
        return _jacobian(dr + 2.0 * x * x * ddr - 2.0 * x * ddt * st, 2.0 * x * y * ddr - 2.0 * y * ddt * st,
                         2.0 * x * y * ddr + 2.0 * x * ddt * ct, dr + 2.0 * y * y * ddr + 2.0 * y * ddt * ct)

    def distort(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        ux, uy = _xy(x, y)
        return _newton_inverse(self, ux, uy, start=(ux + self.xp, uy + self.yp))

    def __repr__(self) -> str:
        return (f"ApolloMetricDistortion(principal_point={(self.xp, self.yp)!r}, coefficients={self.k!r}, "
                f"decentering={(self.j1, self.j2, self.t0)!r})")


def _newton_inverse(model: Distortion, ux: Array, uy: Array,
                    start: tuple[Array, Array] | None = None) -> tuple[Array, Array]:
    """Distorted coordinates solving ``model.undistort(d) = u`` by 2-D Newton iteration; NaN where it fails."""
    dx, dy = (ux.copy(), uy.copy()) if start is None else (np.array(start[0], float), np.array(start[1], float))
    big = np.ones(ux.shape, dtype=bool)
    with np.errstate(all="ignore"):  # diverging points end as NaN below
        for _ in range(_NEWTON_MAXITER):
            fx, fy = model.undistort(dx, dy)
            j = model.undistort_jacobian(dx, dy)
            det = j[..., 0, 0] * j[..., 1, 1] - j[..., 0, 1] * j[..., 1, 0]
            rx, ry = fx - ux, fy - uy
            sx = (j[..., 1, 1] * rx - j[..., 0, 1] * ry) / det
            sy = (j[..., 0, 0] * ry - j[..., 1, 0] * rx) / det
            dx, dy = dx - sx, dy - sy
            big = ~(np.maximum(np.abs(sx), np.abs(sy)) <= _NEWTON_TOL * np.maximum(1.0, np.hypot(dx, dy)))
            if not np.any(big):
                break
    return np.where(big, np.nan, dx), np.where(big, np.nan, dy)


def _make_lunar_orbiter(block: Mapping[str, Any]) -> Distortion:
    try:
        return LunarOrbiterDistortion(block["perspective_x"], block["perspective_y"], block["center_point_x"],
                                      block["center_point_y"], np.atleast_1d(block.get("coefficients", [0.0, 0.0])))
    except KeyError as exc:
        raise InvalidInputError(f"lunarorbiter distortion block lacks {exc.args[0]!r}") from None


def _make_apollo_metric(block: Mapping[str, Any]) -> Distortion:
    try:
        return ApolloMetricDistortion(np.atleast_1d(block["principal_point"]), np.atleast_1d(block["coefficients"]),
                                      np.atleast_1d(block["decentering"]))
    except KeyError as exc:
        raise InvalidInputError(f"apollometric distortion block lacks {exc.args[0]!r}") from None


DISTORTION_MODELS["lunarorbiter"] = _make_lunar_orbiter
DISTORTION_MODELS["apollometric"] = _make_apollo_metric
__all__ += ["LunarOrbiterDistortion", "ApolloMetricDistortion"]
