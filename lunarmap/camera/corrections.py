"""Correction parameters of sensor models, with analytic partials: what the adjustment estimates.

Frame camera (:class:`FrameCorrections`), 6 parameters ``[w (3), c (3)]``::

    v = exp([w]x) R^T (X - P - c)

``R`` rotates sensor-frame vectors into the body-fixed frame and ``P`` is the sensor position
(metres) of the camera's exterior orientation at its exposure time; ``w`` is a small rotation
in the sensor frame (radians), ``c`` a position offset (metres, body-fixed). The sensor-frame
vector ``v`` is projected by the pinhole ``(x, y) = f (v_x, v_y) / v_z`` (millimetres), distorted
by the camera's distortion model and mapped to pixels by the interior orientation's affine
``focal2pixel`` transform, exactly as :meth:`FrameCamera.ground_to_image` does.

Line-scan camera (:class:`LineScanCorrections`), ``6 (degree + 1)`` parameters
``[w_0, c_0, w_1, c_1, ...]``: the same with ``w(tau) = sum_k w_k tau^k`` and
``c(tau) = sum_k c_k tau^k``, ``tau = (t - t_mid) / t_half`` in [-1, 1] over the image lines.
A ground point is imaged at the time ``t`` whose projection falls on the detector line (image
line coordinate 0 of the projection, see :mod:`lunarmap.camera.linescan`); the partials follow
the implicit-function rule ``dt/dp = -(dr/dp) / (dr/dt)``.

Line-scan jitter (``LineScanCorrections(camera, degree, jitter_lines=N)``): the attitude correction
gets a uniform cubic B-spline in the image line coordinate on top of the polynomial,
``w(t) = sum_k w_k tau^k + sum_j B_j(line(t) / h) s_j`` with knots every ``h`` lines from line 0 to
the last line: ``h = n_lines / round(n_lines / N)`` for the requested spacing ``N`` (a whole number
of segments over the image), ``round(n_lines / N) + 3`` coefficients ``s_j`` per axis, radians; the
spline holds its end values outside the image lines. A cubic B-spline reproduces every polynomial
of degree <= 3 exactly, so its constant, linear (and quadratic) part would be collinear with the
polynomial: the knot coefficients are parametrised as ``s = Q z`` with ``Q`` an orthonormal basis of
the coefficients whose spline is orthogonal, over the image lines, to every polynomial of the
polynomial's degree in ``tau``. The parameters ``jw*_l`` are ``z``; the knot coefficients are
:meth:`LineScanCorrections.knot_coefficients`. The spline then carries only what the polynomial
cannot, whatever priors the adjustment adds (a prior alone would leave the split between the two
to the prior's weight), and ``|s| = |z|``.

Any sensor (:class:`AffineCorrections`), 6 image-space affine parameters (LROC multi-image
study, ``seeds/001`` Eq. 13)::

    line   = r' + a0 + a1 (c' - c_0) + a2 (r' - r_0)
    sample = c' + b0 + b1 (c' - c_0) + b2 (r' - r_0)

with ``(r', c')`` the sensor's own projection; the RFM's default origin ``(r_0, c_0)`` is its
line/sample offset (image centre).

Partial derivatives are analytic at fixed time, through the distortion
(:meth:`~lunarmap.camera.distortion.Distortion.distort_with_jacobian`); the tests compare them
with central finite differences.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InvalidInputError, JitterKnotSpacingError
from ..orientation.exterior import ExteriorOrientation
from ..orientation.rotation import left_jacobian, matrix_to_quat, quat_to_matrix, rotvec_to_matrix, skew
from .distortion import Distortion
from .interior import InteriorOrientation

try:  # optional: the frame stack's per-observation algebra in two fused passes instead of numpy temporaries
    import numba
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None

__all__ = ["FrameCorrections", "LineScanCorrections", "PushFrameCorrections", "AffineCorrections", "AffineCorrectedSensor",
           "FrameStack", "pinhole_image", "cubic_bspline_basis"]

Array = NDArray[np.float64]

_EO_NAMES = ("w_x", "w_y", "w_z", "c_x", "c_y", "c_z")
_EO_UNITS = ("rad", "rad", "rad", "m", "m", "m")
_NEWTON_MAX = 40
# Line-scan time solution: steps below this (lines) stop the iteration. The residual itself is
# only known to ~1e-9 line (a body-fixed coordinate near 1.7e6 m carries ~2e-10 m of rounding).
_LINE_TOL = 5e-9
_DT = 1e-4            # s, central difference of dr/dt (1e-3 s left 3e-6 relative error on a 6.5-ms-line camera)
# A line-scan point's last solved time starts its next time search if it moved less than this (m).
_WARM_RADIUS_M = 1000.0
# EO records per jitter knot spacing (at most one per line) of a corrected camera with jitter
_JITTER_SAMPLES_PER_KNOT = 8.0


def _xyz(xyz: ArrayLike) -> Array:
    a = np.asarray(xyz, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3:
        a = a.reshape(-1, 3)
    if not np.all(np.isfinite(a)):
        raise InvalidInputError(f"{int(np.sum(~np.all(np.isfinite(a), axis=1)))} ground point(s) hold NaN or "
                                "infinite coordinates")
    return a


def _params(params: ArrayLike, n: int, what: str) -> Array:
    p = np.asarray(params, dtype=float).reshape(-1)
    if p.size != n:
        raise InvalidInputError(f"{what} takes {n} correction parameters, got {p.size}")
    if not np.all(np.isfinite(p)):
        raise InvalidInputError(f"{what}: correction parameters hold NaN or infinite values")
    return p


def _pixel_affine(io: InteriorOrientation) -> tuple[Array, Array]:
    """``A (2, 2)``, ``b (2,)``: ``(line, sample) = A (x, y) + b`` for distorted focal-plane mm."""
    il, is_ = io.focal2pixel_lines, io.focal2pixel_samples
    A = np.array([[il[1] / io.line_summing, il[2] / io.line_summing],
                  [is_[1] / io.sample_summing, is_[2] / io.sample_summing]])
    b = np.array([(il[0] + io.detector_center_line - io.starting_detector_line) / io.line_summing,
                  (is_[0] + io.detector_center_sample - io.starting_detector_sample) / io.sample_summing])
    return A, b


def pinhole_image(v: Array, f: Array, distortion: Distortion | Sequence[tuple[Distortion, NDArray[np.bool_]]],
                  A: Array, b: Array, jacobian: bool = True) -> tuple[Array, Array | None]:
    """Image coordinates of sensor-frame vectors and their partials with respect to the vectors.

    Parameters
    ----------
    v : ndarray (n, 3)
        Sensor-frame vectors towards the ground points (any length; boresight +z).
    f : ndarray (n,) or float
        Focal length, millimetres.
    distortion : Distortion, or sequence of (Distortion, mask (n,))
        The distortion model (one for all rows, or one per group of rows).
    A, b : ndarray (n, 2, 2) / (2, 2) and (n, 2) / (2,)
        Distorted focal plane (mm) to ``(line, sample)`` pixels: ``A (x, y) + b``.
    jacobian : bool
        Also return ``d(line, sample) / d v`` ``(n, 2, 3)``, pixels per unit of ``v``.

    Returns
    -------
    pix : ndarray (n, 2)
        ``(line, sample)`` pixels; NaN for vectors behind the sensor or outside the distortion
        model's domain.
    jac : ndarray (n, 2, 3) or None
    """
    n = v.shape[0]
    f = np.broadcast_to(np.asarray(f, dtype=float), (n,))
    in_front = v[:, 2] * f > 0.0   # a negative focal length looks along -z (ISIS z direction -1)
    with np.errstate(divide="ignore", invalid="ignore"):
        iz = np.where(in_front, 1.0 / v[:, 2], np.nan)
    ux = f * v[:, 0] * iz
    uy = f * v[:, 1] * iz
    groups = [(distortion, np.ones(n, dtype=bool))] if isinstance(distortion, Distortion) else distortion
    dx = np.empty(n)
    dy = np.empty(n)
    jd = np.empty((n, 2, 2)) if jacobian else None
    for dist, m in groups:
        if not np.any(m):
            continue
        if jd is not None:
            dx[m], dy[m], jd[m] = dist.distort_with_jacobian(ux[m], uy[m])
        else:
            dx[m], dy[m] = dist.distort(ux[m], uy[m])
    A = np.asarray(A, dtype=float)
    d = np.stack([dx, dy], axis=-1)
    pix = (np.einsum("nij,nj->ni", A, d) if A.ndim == 3 else d @ A.T) + b
    if jd is None:
        return pix, None
    # d(ux, uy)/dv = f / v_z [[1, 0, -v_x / v_z], [0, 1, -v_y / v_z]]
    dp = np.zeros((n, 2, 3))
    fz = f * iz
    dp[:, 0, 0] = fz
    dp[:, 1, 1] = fz
    dp[:, 0, 2] = -ux * iz
    dp[:, 1, 2] = -uy * iz
    ajd = np.einsum("nij,njk->nik", A, jd) if A.ndim == 3 else np.einsum("ij,njk->nik", A, jd)
    return pix, np.einsum("nij,njk->nik", ajd, dp)


def _eo_partials(dpix_dv: Array, v: Array, M: Array, w: Array) -> tuple[Array, Array, Array]:
    """``d/dX``, ``d/dc``, ``d/dw`` of image coordinates with ``v = exp([w]x) R^T (X - P - c)``, ``M = exp([w]x) R^T``."""
    d_x = np.einsum("nij,njk->nik", dpix_dv, M)
    # dv/dw = -[v]x J_l(w)  (left perturbation of exp([w]x))
    d_w = np.einsum("nij,njk->nik", dpix_dv, -skew(v) @ left_jacobian(w))
    return d_x, -d_x, d_w


# -- frame cameras ------------------------------------------------------------------------------

def _frame_focal_py(M, P, c, f, idx, X):
    """Sensor vectors ``v = M (X - P - c)`` and undistorted focal-plane mm of observations (NaN behind)."""
    n = idx.shape[0]
    v = np.empty((n, 3))
    u = np.empty((n, 2))
    for i in range(n):
        k = idx[i]
        d0 = X[i, 0] - P[k, 0] - c[k, 0]
        d1 = X[i, 1] - P[k, 1] - c[k, 1]
        d2 = X[i, 2] - P[k, 2] - c[k, 2]
        for r in range(3):
            v[i, r] = M[k, r, 0] * d0 + M[k, r, 1] * d1 + M[k, r, 2] * d2
        if v[i, 2] * f[k] > 0.0:
            s = f[k] / v[i, 2]
            u[i, 0] = v[i, 0] * s
            u[i, 1] = v[i, 1] * s
        else:
            u[i, 0] = np.nan
            u[i, 1] = np.nan
    return v, u


def _frame_pixels_py(v, u, d, jd, A, b, M, Jl, f, idx, want_jac):
    """Pixels ``A d + b`` and, if wanted, ``d/d[w, c]`` (n, 2, 6) and ``d/dX`` (n, 2, 3) of observations."""
    n = idx.shape[0]
    pix = np.empty((n, 2))
    jc = np.empty((n if want_jac else 0, 2, 6))
    jx = np.empty((n if want_jac else 0, 2, 3))
    for i in range(n):
        k = idx[i]
        for r in range(2):
            pix[i, r] = A[k, r, 0] * d[i, 0] + A[k, r, 1] * d[i, 1] + b[k, r]
        if not want_jac:
            continue
        iz = 1.0 / v[i, 2]
        fz = f[k] * iz
        for r in range(2):
            # row r of A Jd, then times d(ux, uy)/dv = [[fz, 0, -ux iz], [0, fz, -uy iz]]
            a0 = A[k, r, 0] * jd[i, 0, 0] + A[k, r, 1] * jd[i, 1, 0]
            a1 = A[k, r, 0] * jd[i, 0, 1] + A[k, r, 1] * jd[i, 1, 1]
            g0 = a0 * fz
            g1 = a1 * fz
            g2 = -(a0 * u[i, 0] + a1 * u[i, 1]) * iz
            # d/dX = g M; d/dc = -d/dX; d/dw = g (-[v]x) J_l = (v x g)^T J_l
            for m in range(3):
                dx = g0 * M[k, 0, m] + g1 * M[k, 1, m] + g2 * M[k, 2, m]
                jx[i, r, m] = dx
                jc[i, r, 3 + m] = -dx
            q0 = v[i, 1] * g2 - v[i, 2] * g1
            q1 = v[i, 2] * g0 - v[i, 0] * g2
            q2 = v[i, 0] * g1 - v[i, 1] * g0
            for m in range(3):
                jc[i, r, m] = q0 * Jl[k, 0, m] + q1 * Jl[k, 1, m] + q2 * Jl[k, 2, m]
    return pix, jc, jx


_frame_focal = numba.njit(cache=True)(_frame_focal_py) if numba is not None else None
_frame_pixels = numba.njit(cache=True)(_frame_pixels_py) if numba is not None else None

class FrameStack:
    """Vectorised projection and partials of many frame cameras' corrections at once.

    Observations of all images are evaluated in one pass (the adjustment of a block of hundreds
    of frame images would otherwise be dominated by per-image Python overhead); images sharing a
    distortion model (same class and coefficients) share its evaluation.
    """

    def __init__(self, items: Sequence["FrameCorrections"]) -> None:
        self.items = list(items)
        cams = [c.sensor for c in self.items]
        self.P = np.ascontiguousarray(np.array([c._position for c in cams]).reshape(-1, 3))
        self.Rt = np.ascontiguousarray(np.array([c._rotation.T for c in cams]).reshape(-1, 3, 3))  # body -> sensor
        self.f = np.array([c.interior.focal_length for c in cams], dtype=float)
        ab = [_pixel_affine(c.interior) for c in cams]
        self.A = np.ascontiguousarray(np.array([a for a, _ in ab]).reshape(-1, 2, 2))
        self.b = np.ascontiguousarray(np.array([b for _, b in ab]).reshape(-1, 2))
        keys: dict[str, int] = {}
        self.dist_of = np.empty(len(cams), dtype=np.int64)
        self.distortions: list[Distortion] = []
        for i, c in enumerate(cams):
            k = f"{type(c.distortion).__name__}:{c.distortion!r}"
            if k not in keys:
                keys[k] = len(self.distortions)
                self.distortions.append(c.distortion)
            self.dist_of[i] = keys[k]

    def partials(self, params: Array, idx: NDArray[np.int64], X: Array, jacobian: bool = True,
                 compiled: bool = True) -> tuple[Array, Array | None, Array | None]:
        """Pixels ``(n, 2)``, ``d/d params (n, 2, 6)``, ``d/dX (n, 2, 3)`` of observations of images ``idx``.

        ``params (n_images, >= 6)``: the first 6 columns are ``[w, c]`` of each stacked image.
        ``compiled=False`` forces the numpy path (the compiled one is used when numba is installed).
        """
        params = np.asarray(params, dtype=float)
        if compiled and _frame_focal is not None:
            return self._partials_compiled(params, np.ascontiguousarray(idx, dtype=np.int64),
                                           np.ascontiguousarray(X, dtype=float), jacobian)
        w_img = params[:, 0:3]
        M_img = rotvec_to_matrix(w_img) @ self.Rt            # exp([w]x) R^T per image
        M = M_img[idx]
        d = X - self.P[idx] - params[idx, 3:6]
        v = np.einsum("nij,nj->ni", M, d)
        dist_idx = self.dist_of[idx]
        groups = [(dist, dist_idx == k) for k, dist in enumerate(self.distortions)]
        pix, dv = pinhole_image(v, self.f[idx], groups, self.A[idx], self.b[idx], jacobian)
        if not jacobian:
            return pix, None, None
        d_x, d_c, d_w = _eo_partials(dv, v, M, w_img[idx])  # type: ignore[arg-type]
        jc = np.concatenate([d_w, d_c], axis=2)
        return pix, jc, d_x

    def _partials_compiled(self, params: Array, idx: NDArray[np.int64], X: Array, jacobian: bool):
        w_img = np.ascontiguousarray(params[:, 0:3])
        M_img = np.ascontiguousarray(rotvec_to_matrix(w_img) @ self.Rt)
        c_img = np.ascontiguousarray(params[:, 3:6])
        v, u = _frame_focal(M_img, self.P, c_img, self.f, idx, X)  # type: ignore[misc]
        n = idx.size
        d = np.empty((n, 2))
        jd = np.empty((n if jacobian else 0, 2, 2))
        dist_idx = self.dist_of[idx]
        single = len(self.distortions) == 1
        for k, dist in enumerate(self.distortions):
            m = slice(None) if single else dist_idx == k
            if jacobian:
                dx, dy, j = dist.distort_with_jacobian(u[m, 0], u[m, 1])
                jd[m] = j
            else:
                dx, dy = dist.distort(u[m, 0], u[m, 1])
            d[m, 0], d[m, 1] = dx, dy
        Jl = np.ascontiguousarray(left_jacobian(w_img)) if jacobian else np.empty((0, 3, 3))
        pix, jc, jx = _frame_pixels(v, u, d, jd, self.A, self.b, M_img, Jl, self.f, idx, jacobian)  # type: ignore[misc]
        return (pix, jc, jx) if jacobian else (pix, None, None)


#: Guards the lazy one-camera FrameStack of every FrameCorrections (microseconds to build).
_STACK_LOCK = threading.Lock()


class FrameCorrections:
    """Six exterior-orientation corrections of a :class:`~lunarmap.camera.FrameCamera` (module docstring).

    Parameters
    ----------
    camera : FrameCamera
        The reference camera (for an adjustment: its navigation orientation).

    Raises
    ------
    DistortionPartialsError
        The camera's distortion model has no partial derivatives.
    """

    names = _EO_NAMES
    units = _EO_UNITS
    n_params = 6

    def __init__(self, camera: Any) -> None:
        camera.distortion.undistort_jacobian(0.0, 0.0)   # a model without partials fails here, by name
        self.sensor = camera
        self._stack: FrameStack | None = None

    def __repr__(self) -> str:
        return f"FrameCorrections({self.sensor!r})"

    def _one(self) -> FrameStack:
        stack = self._stack
        if stack is None:
            with _STACK_LOCK:   # built once (FrameStack is immutable), whichever thread asks first
                if self._stack is None:
                    self._stack = FrameStack([self])
                stack = self._stack
        return stack

    def project(self, params: ArrayLike, xyz: ArrayLike) -> Array:
        p = _params(params, 6, "FrameCorrections")
        X = _xyz(xyz)
        return self._one().partials(p[None, :], np.zeros(X.shape[0], np.int64), X, jacobian=False)[0]

    def partials(self, params: ArrayLike, xyz: ArrayLike) -> tuple[Array, Array, Array]:
        p = _params(params, 6, "FrameCorrections")
        X = _xyz(xyz)
        pix, jc, jx = self._one().partials(p[None, :], np.zeros(X.shape[0], np.int64), X)
        return pix, jc, jx  # type: ignore[return-value]

    def apply(self, params: ArrayLike) -> Any:
        """A new :class:`FrameCamera` whose EO carries the corrections (at every EO sample)."""
        p = _params(params, 6, "FrameCorrections")
        cam = self.sensor
        E = rotvec_to_matrix(p[0:3])
        eo = cam.eo
        R = quat_to_matrix(eo.quaternions) @ E.T        # R' = R exp([w]x)^T, so R'^T = exp([w]x) R^T
        new = _replace_eo(eo, eo.positions + p[3:6], eo.velocities, matrix_to_quat(R), "frame EO corrections")
        return type(cam)(cam.interior, new, cam.shape, time=cam.time)

    @staticmethod
    def stack(items: Sequence["FrameCorrections"]) -> FrameStack:
        """Evaluate many frame cameras' corrections in one vectorised pass."""
        return FrameStack(items)


def _replace_eo(eo: ExteriorOrientation, positions: Array, velocities: Array, quaternions: Array,
                note: str) -> ExteriorOrientation:
    return ExteriorOrientation(epoch=eo.epoch, times=eo.times, positions=positions, velocities=velocities,
                               quaternions=quaternions, sun_times=eo.sun_times, sun_positions=eo.sun_positions,
                               body_frame=eo.body_frame, attrs={**eo.attrs, "corrected": note})


# -- line-scan cameras --------------------------------------------------------------------------

class LineScanCorrections:
    """Position and attitude corrections of a :class:`~lunarmap.camera.LineScanCamera`, polynomials in time.

    Parameters
    ----------
    camera : LineScanCamera
        The reference camera (for an adjustment: its navigation orientation).
    degree : int
        Polynomial degree 0, 1 or 2 in normalised image time ``tau``.
    jitter_lines : float, optional
        Knot spacing, image lines (>= 1), of a cubic B-spline attitude correction on top of the
        polynomial (module docstring); ``None`` (default): the polynomial only.

    Raises
    ------
    JitterKnotSpacingError
        ``jitter_lines`` not finite or below one line.

    Notes
    -----
    Polynomial attitude and position corrections of a narrow-angle camera are strongly
    correlated: give them a-priori sigmas (navigation observations) or fix some. The jitter
    spline's coefficients are not determined by tie points alone where a ground deformation can
    follow them (images of one track direction): give it a smoothness prior
    (:class:`~lunarmap.adjust.jitter.JitterSmoothness`) and a datum (a jitter-free image, terrain).
    """

    # set by _init_polynomial
    sensor: Any
    degree: int
    n_params: int
    names: tuple[str, ...]
    units: tuple[str, ...]

    def __init__(self, camera: Any, degree: int = 1, jitter_lines: float | None = None) -> None:
        _init_polynomial(self, camera, degree, "line-scan")
        t0, t1 = camera.image_time(np.array([0.0, float(camera.interior.n_lines)]))
        self.t_mid = 0.5 * float(t0 + t1)
        self.t_half = 0.5 * abs(float(t1 - t0))
        if not self.t_half > 0.0:
            raise InvalidInputError("line-scan corrections need an image spanning a positive time interval")
        self._A, self._b = _pixel_affine(camera.interior)
        self._warm: tuple[Array, Array] | None = None      # (points, times) of the last time search
        self.n_poly = self.n_params
        self.jitter_lines: float | None = None
        self.knot_spacing = 0.0   # lines, the requested spacing rounded to whole segments over the image
        self.n_segments = 0
        self.n_knots = 0          # B-spline coefficients per axis
        self.n_jitter = 0         # spline parameters per axis (n_knots - degree - 1)
        self._Q = np.zeros((0, 0))
        if jitter_lines is not None:
            self._init_jitter(jitter_lines)

    def _init_jitter(self, jitter_lines: float) -> None:
        try:
            N = float(jitter_lines)
        except (TypeError, ValueError):
            raise JitterKnotSpacingError(f"jitter knot spacing must be a number of lines, got {jitter_lines!r}") from None
        if not (np.isfinite(N) and N >= 1.0):
            raise JitterKnotSpacingError(f"jitter knot spacing must be >= 1 line (an attitude sample per exposure "
                                         f"at most), got {jitter_lines!r}")
        n_lines = float(self.sensor.interior.n_lines)
        self.jitter_lines = N
        # a whole number of segments over the image lines: a span ending past the last line would leave
        # coefficients whose support barely touches the image (unobservable)
        self.n_segments = max(1, int(np.round(n_lines / N)))
        self.knot_spacing = n_lines / self.n_segments
        self.n_knots = self.n_segments + 3
        # The spline's functions are made orthogonal (over the image lines, uniformly weighted) to the
        # polynomials in tau: coefficients in the complement of B^T P. Removing the knot-index polynomials
        # instead (s_j = p(j)) would leave the spline able to mimic a constant to ~10 % through its end
        # coefficients, whose knots lie outside the image: near-collinear with the polynomial.
        lines = np.linspace(0.0, n_lines, 16 * self.n_segments + 1)
        lines = 0.5 * (lines[1:] + lines[:-1])
        tau = self.tau(self.sensor.image_time(lines))
        C = cubic_bspline_basis(lines / self.knot_spacing, self.n_segments).T @ (tau[:, None] ** np.arange(self.degree + 1)[None, :])
        Q, _ = np.linalg.qr(C, mode="complete")
        self._Q = np.ascontiguousarray(Q[:, self.degree + 1:])
        self.n_jitter = self.n_knots - self.degree - 1
        self.n_params = self.n_poly + 3 * self.n_jitter
        self.names = self.names + tuple(f"jw{ax}_{j}" for j in range(self.n_jitter) for ax in "xyz")
        self.units = self.units + ("rad",) * (3 * self.n_jitter)

    def __repr__(self) -> str:
        jit = "" if self.jitter_lines is None else f", jitter_lines={self.jitter_lines:g}"
        return f"LineScanCorrections({self.sensor!r}, degree={self.degree}{jit})"

    @property
    def jitter_projector(self) -> Array:
        """``Q (n_knots, n_jitter)``: knot coefficients ``s = Q z`` of the spline parameters ``z`` of one axis."""
        return self._Q.copy()

    def knot_lines(self) -> Array:
        """Image line coordinate of every B-spline coefficient's knot ``(n_knots,)`` (the first and last two
        lie outside the image, as a uniform cubic B-spline needs)."""
        if self.jitter_lines is None:
            return np.zeros(0)
        return (np.arange(self.n_knots, dtype=np.float64) - 1.0) * float(self.knot_spacing)

    def knot_coefficients(self, params: ArrayLike) -> Array:
        """B-spline coefficients ``(n_knots, 3)`` (radians, sensor frame) of the jitter part of ``params``."""
        p = _params(params, self.n_params, "LineScanCorrections")
        if self.jitter_lines is None:
            return np.zeros((0, 3))
        return self._Q @ p[self.n_poly:].reshape(self.n_jitter, 3)

    def _jitter_rows(self, t: Array) -> Array:
        """Rows ``(n, n_jitter)`` of the spline's parameter basis ``b(line(t) / N) Q`` at times ``t``."""
        s = self.sensor.line_times.line(t) / self.knot_spacing
        return cubic_bspline_basis(s, self.n_segments) @ self._Q

    def jitter(self, params: ArrayLike, t: ArrayLike) -> Array:
        """The spline's attitude correction ``(n, 3)`` radians (sensor frame) at times ``t`` (s after ``eo.epoch``);
        zero without jitter."""
        p = _params(params, self.n_params, "LineScanCorrections")
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if self.jitter_lines is None:
            return np.zeros((t.size, 3))
        return self._jitter_rows(t) @ p[self.n_poly:].reshape(self.n_jitter, 3)

    def attitude_correction(self, params: ArrayLike, t: ArrayLike) -> Array:
        """The whole attitude correction ``w(t)`` ``(n, 3)`` radians (polynomial plus spline) at times ``t``."""
        p = _params(params, self.n_params, "LineScanCorrections")
        t = np.atleast_1d(np.asarray(t, dtype=float))
        powers = self.tau(t)[:, None] ** np.arange(self.degree + 1)[None, :]
        return powers @ p[:self.n_poly].reshape(self.degree + 1, 2, 3)[:, 0, :] + self.jitter(p, t)

    def tau(self, t: ArrayLike) -> Array:
        """Normalised image time (dimensionless, -1 .. 1 over the image) of times ``t`` (s after ``eo.epoch``)."""
        return (np.asarray(t, dtype=float) - self.t_mid) / self.t_half

    def _geometry(self, p: Array, X: Array, t: Array, jacobian: bool):
        cam = self.sensor
        # a point whose time search failed (no finite time: far off the image's plane) projects to NaN,
        # like a frame camera's point behind it, instead of stopping the block's projection
        lost = ~np.isfinite(t)
        if lost.any():
            t = np.where(lost, self.t_mid, t)
        tau = self.tau(t)
        powers = tau[:, None] ** np.arange(self.degree + 1)[None, :]           # (n, d+1)
        P = p[:self.n_poly].reshape(self.degree + 1, 2, 3)                     # [k, (w, c), xyz]
        w = powers @ P[:, 0, :]
        dC = powers @ P[:, 1, :]
        g = None
        if self.jitter_lines is not None:
            g = self._jitter_rows(t)                                           # (n, n_jitter)
            w = w + g @ p[self.n_poly:].reshape(self.n_jitter, 3)
        Rt = np.swapaxes(cam.eo.rotation_at(t), -1, -2)                        # body -> sensor
        M = rotvec_to_matrix(w) @ Rt
        v = np.einsum("nij,nj->ni", M, X - cam.eo.position_at(t) - dC)
        pix, dv = pinhole_image(v, cam.interior.focal_length, cam.distortion, self._A, self._b, jacobian)
        if lost.any():
            pix = np.where(lost[:, None], np.nan, pix)
            v = np.where(lost[:, None], np.nan, v)
            if dv is not None:
                dv = np.where(lost.reshape((-1,) + (1,) * (dv.ndim - 1)), np.nan, dv)
        return pix, dv, v, M, w, powers, g

    def _residual(self, p: Array, X: Array, t: Array) -> Array:
        # the projection's image-line coordinate: 0 on the detector line (the image line is time)
        return self._geometry(p, X, t, False)[0][:, 0]

    def _start_times(self, X: Array) -> Array:
        """Start times (s) of the time search: the uncorrected camera's exposure times of ``X`` (image mid-time
        where it sees none)."""
        cam = self.sensor
        with np.errstate(invalid="ignore"):
            start, _ = cam.ground_to_image(X, on_miss="nan", within_image=False)
        return np.where(np.isfinite(start), cam.image_time(np.where(np.isfinite(start), start, 0.0)), self.t_mid)

    def _solve_time(self, p: Array, X: Array) -> Array:
        # Warm start: an adjustment evaluates the same observations again and again while its points and
        # corrections move by metres; the times solved last time are then within a fraction of a line of the
        # new ones, so Newton needs one or two steps and the uncorrected camera's own time search (the
        # largest part of a cold start, measured 17 of 35 s in a 192-image block's adjustment) is skipped.
        # A point that moved more than _WARM_RADIUS_M, or whose warm Newton found no time, starts cold; both
        # starts end on the same root to the Newton tolerance (the exposure condition has one in the image).
        n = X.shape[0]
        t = np.empty(n)
        cold = np.ones(n, dtype=bool)
        warm = self._warm
        if warm is not None and warm[0].shape == X.shape:
            X_prev, t_prev = warm
            d = X - X_prev
            cold = ~(np.isfinite(t_prev) & (np.einsum("ij,ij->i", d, d) < _WARM_RADIUS_M ** 2))
            t[~cold] = t_prev[~cold]
        if cold.any():
            t[cold] = self._start_times(X[cold])
        t = self._newton_time(p, X, t)
        retry = np.flatnonzero(~np.isfinite(t) & ~cold)
        if retry.size:
            t[retry] = self._newton_time(p, X[retry], self._start_times(X[retry]))
        self._warm = (X.copy(), t.copy())
        return t

    def _newton_time(self, p: Array, X: Array, t: Array) -> Array:
        """Times (s) solving the corrected exposure condition by Newton from ``t`` (modified); NaN where none."""
        rate = float(np.min(np.abs(self.sensor.line_times.rates)))
        r = self._residual(p, X, t)
        slope = (self._residual(p, X, t + _DT) - self._residual(p, X, t - _DT)) / (2.0 * _DT)
        act = np.arange(X.shape[0])
        for _ in range(_NEWTON_MAX):
            with np.errstate(divide="ignore", invalid="ignore"):
                step = r / slope
            t[act] -= step
            small = np.abs(step) < _LINE_TOL * rate
            keep = ~small & np.isfinite(step)
            act, slope = act[keep], slope[keep]
            if act.size == 0:
                return t
            r = self._residual(p, X[act], t[act])
        # no time for these points (a trial step of the adjustment far off, a point dragged by a gross error):
        # NaN, which the projection carries to their rows only; the solver rejects such a step, quality
        # control sets such a point aside
        t[act] = np.nan
        return t

    def project(self, params: ArrayLike, xyz: ArrayLike) -> Array:
        p = _params(params, self.n_params, "LineScanCorrections")
        X = _xyz(xyz)
        t = self._solve_time(p, X)
        pix = self._geometry(p, X, t, False)[0]
        return np.column_stack([self.sensor.line_times.line(t), pix[:, 1]])

    def partials(self, params: ArrayLike, xyz: ArrayLike) -> tuple[Array, Array, Array]:
        p = _params(params, self.n_params, "LineScanCorrections")
        X = _xyz(xyz)
        t = self._solve_time(p, X)
        pix, dv, v, M, w, powers, g = self._geometry(p, X, t, True)
        d_x, d_c, d_w = _eo_partials(dv, v, M, w)
        d_p = _polynomial_partials(d_w, d_c, powers)
        if g is not None:
            # d/dz_(j, axis) = d/dw_axis * b_j(line(t) / N)   (parameters ordered [j, axis])
            d_s = (g[:, None, :, None] * d_w[:, :, None, :]).reshape(d_w.shape[0], 2, 3 * self.n_jitter)
            d_p = np.concatenate([d_p, d_s], axis=2)
        # implicit time: r(t, p, X) = 0
        plus = self._geometry(p, X, t + _DT, False)[0]
        minus = self._geometry(p, X, t - _DT, False)[0]
        drs_dt = (plus - minus) / (2.0 * _DT)                                  # (n, 2)
        dt_dp = -d_p[:, 0, :] / drs_dt[:, :1]
        dt_dx = -d_x[:, 0, :] / drs_dt[:, :1]
        lt = self.sensor.line_times
        dl_dt = 1.0 / lt.rates[lt._segment(lt.line(t))]
        jc = np.empty_like(d_p)
        jx = np.empty_like(d_x)
        jc[:, 0] = dl_dt[:, None] * dt_dp
        jx[:, 0] = dl_dt[:, None] * dt_dx
        jc[:, 1] = d_p[:, 1] + drs_dt[:, 1:] * dt_dp
        jx[:, 1] = d_x[:, 1] + drs_dt[:, 1:] * dt_dx
        return np.column_stack([lt.line(t), pix[:, 1]]), jc, jx

    def apply(self, params: ArrayLike) -> Any:
        """A new :class:`LineScanCamera` whose EO samples carry the corrections.

        The corrected EO is sampled at the original EO's times; its interpolation then follows
        the corrected trajectory as closely as the original follows its own (corrections are
        low-order polynomials in time). With jitter, the EO is resampled over the spline's span (8
        quaternion records per knot spacing, at most one per line) so that the spline's attitude is
        in the records and a kernel written from the camera carries it; the spline holds its end
        values beyond its span.
        """
        p = _params(params, self.n_params, "LineScanCorrections")
        cam = self.sensor
        if self.jitter_lines is None:
            new = _polynomial_eo(cam.eo, p, self.degree, self.tau(cam.eo.times), self.t_half,
                                 f"line-scan EO corrections, degree {self.degree}")
            return type(cam)(cam.interior, new, cam.shape, line_times=cam.line_times, workers=cam.workers)
        eo = cam.eo
        # the spline's span (0 .. n_segments knots) and one knot spacing either side, where it holds its end values
        N = self.knot_spacing
        step = max(1.0, N / _JITTER_SAMPLES_PER_KNOT)
        first, last = -N, (self.n_segments + 1) * N
        dense = cam.image_time(np.linspace(first, last, int(np.ceil((last - first) / step)) + 1))
        # never beyond the original samples: the EO would be extrapolated there
        t_lo, t_hi = eo.time_range
        dense = dense[(dense >= t_lo) & (dense <= t_hi)]
        if dense.size < 2:
            dense = np.array([t_lo, t_hi])
        lo, hi = float(np.min(dense)), float(np.max(dense))
        gap = 0.5 * float(np.min(np.abs(np.diff(dense))))
        # the original samples away from the dense grid keep the trajectory's span and shape
        outside = eo.times[(eo.times < lo - gap) | (eo.times > hi + gap)]
        times = np.unique(np.concatenate([outside, dense]))
        base = ExteriorOrientation(epoch=eo.epoch, times=times, positions=eo.position_at(times),
                                   velocities=eo.velocity_at(times), quaternions=eo.quaternion_at(times),
                                   sun_times=eo.sun_times, sun_positions=eo.sun_positions, body_frame=eo.body_frame,
                                   attrs=eo.attrs)
        poly = _polynomial_eo(base, p[:self.n_poly], self.degree, self.tau(times), self.t_half, "")
        E = rotvec_to_matrix(self.attitude_correction(p, times))
        R = quat_to_matrix(base.quaternions) @ np.swapaxes(E, -1, -2)
        note = f"line-scan EO corrections, degree {self.degree}, jitter spline every {self.jitter_lines:g} lines"
        new = ExteriorOrientation(epoch=eo.epoch, times=times, positions=poly.positions, velocities=poly.velocities,
                                  quaternions=matrix_to_quat(R), sun_times=eo.sun_times, sun_positions=eo.sun_positions,
                                  body_frame=eo.body_frame, attrs={**eo.attrs, "corrected": note})
        return type(cam)(cam.interior, new, cam.shape, line_times=cam.line_times, workers=cam.workers)


def cubic_bspline_basis(s: ArrayLike, n_segments: int) -> Array:
    """Values ``(n, n_segments + 3)`` of the uniform cubic B-spline basis at ``s`` (knot units, 0 .. n_segments).

    Segment ``k = floor(s)`` (``0 <= k < n_segments``) carries coefficients ``k .. k + 3`` with the
    weights ``(1 - u)^3 / 6``, ``(3u^3 - 6u^2 + 4) / 6``, ``(-3u^3 + 3u^2 + 3u + 1) / 6``, ``u^3 / 6``
    of ``u = s - k``; they sum to 1. ``s`` outside ``[0, n_segments]`` takes the end value.
    """
    x: Array = np.clip(np.asarray(s, dtype=float).reshape(-1), 0.0, float(n_segments))
    k = np.minimum(np.floor(x), n_segments - 1).astype(np.int64)
    u = x - k
    u2, u3 = u * u, u * u * u
    b = np.stack([(1.0 - u) ** 3, 3.0 * u3 - 6.0 * u2 + 4.0, -3.0 * u3 + 3.0 * u2 + 3.0 * u + 1.0, u3], axis=1) / 6.0
    out = np.zeros((x.size, n_segments + 3))
    rows = np.arange(x.size)
    for i in range(4):
        out[rows, k + i] = b[:, i]
    return out


def _polynomial_eo(eo: ExteriorOrientation, p: Array, degree: int, tau: Array, t_half: float,
                   note: str) -> ExteriorOrientation:
    """The EO with polynomial corrections ``[w_k, c_k]`` in normalised time ``tau`` applied at its samples."""
    k = np.arange(degree + 1)
    powers = tau[:, None] ** k[None, :]
    dpow = np.where(k[None, :] > 0, k[None, :] * tau[:, None] ** np.maximum(k - 1, 0)[None, :], 0.0) / t_half
    P = p.reshape(degree + 1, 2, 3)
    w = powers @ P[:, 0, :]
    E = rotvec_to_matrix(w)
    R = quat_to_matrix(eo.quaternions) @ np.swapaxes(E, -1, -2)
    return _replace_eo(eo, eo.positions + powers @ P[:, 1, :], eo.velocities + dpow @ P[:, 1, :],
                       matrix_to_quat(R), note)


def _poly_names(degree: int, quantities: tuple[str, ...] = ("w", "c")) -> tuple[str, ...]:
    return tuple(f"{q}{ax}_{k}" for k in range(degree + 1) for q in quantities for ax in "xyz")


def _init_polynomial(corr: Any, camera: Any, degree: int, kind: str) -> None:
    """What polynomial EO corrections (line scan, push frame) set up: degree, names, units, the sensor."""
    if degree not in (0, 1, 2):
        raise InvalidInputError(f"{kind} correction degree must be 0, 1 or 2, got {degree!r}")
    camera.distortion.undistort_jacobian(0.0, 0.0)   # a model without partials fails here, by name
    corr.sensor = camera
    corr.degree = int(degree)
    corr.n_params = 6 * (corr.degree + 1)
    corr.names = _poly_names(corr.degree)
    corr.units = tuple(u for _ in range(corr.degree + 1) for u in _EO_UNITS)


def _polynomial_partials(d_w: Array, d_c: Array, powers: Array) -> Array:
    """Partials ``(n, 2, 6 (degree + 1))`` of ``[w_k, c_k]`` from those of ``w``, ``c`` and ``tau^k``."""
    n, degree1 = powers.shape
    d_p = np.empty((n, 2, 6 * degree1))
    for k in range(degree1):
        d_p[:, :, 6 * k:6 * k + 3] = d_w * powers[:, k, None, None]
        d_p[:, :, 6 * k + 3:6 * k + 6] = d_c * powers[:, k, None, None]
    return d_p


# -- push-frame cameras -------------------------------------------------------------------------

class PushFrameCorrections:
    """Position and attitude corrections of a :class:`~lunarmap.camera.PushFrameCamera`, polynomials in time.

    The parameters are those of :class:`LineScanCorrections` (``[w_k, c_k]``, degree 0-2 in the
    normalised framelet time ``tau`` in [-1, 1] over the image), evaluated at each framelet's
    exposure time. A framelet is a frame exposure, so the partials are a frame camera's at that time:
    no implicit time. A ground point goes to the framelet the corrected geometry sees it closest to the
    centre line of (as :meth:`PushFrameCamera.ground_to_image` chooses), so the projection jumps by the
    framelets' small disagreement where a point changes framelet.

    Parameters
    ----------
    camera : PushFrameCamera
        The reference camera.
    degree : int
        Polynomial degree 0, 1 or 2.
    """

    # set by _init_polynomial
    sensor: Any
    degree: int
    n_params: int
    names: tuple[str, ...]
    units: tuple[str, ...]

    def __init__(self, camera: Any, degree: int = 1) -> None:
        _init_polynomial(self, camera, degree, "push-frame")
        t = camera.framelet_times
        self.t_mid = 0.5 * float(t[0] + t[-1])
        # one framelet spans no time: normalise by the interframe delay instead
        self.t_half = max(0.5 * float(t[-1] - t[0]), float(camera.timing.interframe_delay))
        self._A, self._b = _pixel_affine(camera.interior)
        self._sign = -1.0 if camera.timing.framelets_flipped else 1.0

    def __repr__(self) -> str:
        return f"PushFrameCorrections({self.sensor!r}, degree={self.degree})"

    def tau(self, t: ArrayLike) -> Array:
        """Normalised time (-1 .. 1 over the framelets) of times ``t`` (s after ``eo.epoch``)."""
        return (np.asarray(t, dtype=float) - self.t_mid) / self.t_half

    def _sensor_vectors(self, p: Array, X: Array, j: NDArray[np.intp]) -> tuple[Array, Array, Array, Array]:
        cam = self.sensor
        powers = self.tau(cam.framelet_times[j])[:, None] ** np.arange(self.degree + 1)[None, :]
        P = p.reshape(self.degree + 1, 2, 3)
        w = powers @ P[:, 0, :]
        M = rotvec_to_matrix(w) @ np.swapaxes(cam._rotations[j], -1, -2)
        v = np.einsum("nij,nj->ni", M, X - cam._positions[j] - powers @ P[:, 1, :])
        return v, M, w, powers

    def framelets(self, params: ArrayLike, xyz: ArrayLike) -> NDArray[np.intp]:
        """Exposure index of the framelet each point is given to under the corrections; -1 if none.

        The camera's rule (:meth:`PushFrameCamera.closest_framelets`) applied to the corrected geometry,
        so that the projection equals the corrected camera's (:meth:`apply`) ``ground_to_image``.
        """
        p = _params(params, self.n_params, "PushFrameCorrections")
        X = _xyz(xyz)
        if not np.any(p):
            return self.sensor.closest_framelets(X)
        return self.sensor.closest_framelets(X, lambda g, j: self._sensor_vectors(p, g, j)[0])

    def _geometry(self, p: Array, X: Array, jacobian: bool):
        cam = self.sensor
        j = self.framelets(p, X)
        lost = j < 0
        jj = np.where(lost, 0, j)
        v, M, w, powers = self._sensor_vectors(p, X, jj)
        pix, dv = pinhole_image(v, cam.interior.focal_length, cam.distortion, self._A, self._b, jacobian)
        pix = np.column_stack([cam.image_line(jj, pix[:, 0]), pix[:, 1]])
        pix[lost] = np.nan
        return pix, dv, v, M, w, powers, lost

    def project(self, params: ArrayLike, xyz: ArrayLike) -> Array:
        p = _params(params, self.n_params, "PushFrameCorrections")
        return self._geometry(p, _xyz(xyz), False)[0]

    def partials(self, params: ArrayLike, xyz: ArrayLike) -> tuple[Array, Array, Array]:
        p = _params(params, self.n_params, "PushFrameCorrections")
        X = _xyz(xyz)
        pix, dv, v, M, w, powers, lost = self._geometry(p, X, True)
        dv[:, 0, :] *= self._sign                  # image line = +-(detector-side framelet line) + const
        d_x, d_c, d_w = _eo_partials(dv, v, M, w)
        d_p = _polynomial_partials(d_w, d_c, powers)
        d_p[lost] = np.nan
        d_x[lost] = np.nan
        return pix, d_p, d_x

    def apply(self, params: ArrayLike) -> Any:
        """A new :class:`PushFrameCamera` whose EO samples carry the corrections (see :class:`LineScanCorrections`)."""
        p = _params(params, self.n_params, "PushFrameCorrections")
        cam = self.sensor
        new = _polynomial_eo(cam.eo, p, self.degree, self.tau(cam.eo.times), self.t_half,
                             f"push-frame EO corrections, degree {self.degree}")
        return type(cam)(cam.interior, new, cam.shape, cam.timing)


# -- affine image-space corrections (RFMs, or any sensor) ---------------------------------------

_AFFINE_NAMES = ("a0", "a1", "a2", "b0", "b1", "b2")


def apply_affine(params: Array, rc: Array, origin: Array) -> Array:
    """Eq. 13 of ``seeds/001`` forward: pixels from ``(r', c') (n, 2)`` and affine ``params (n, 6)`` or ``(6,)``."""
    params = np.broadcast_to(params, (rc.shape[0], 6))
    d = rc - origin
    line = rc[:, 0] + params[:, 0] + params[:, 1] * d[:, 1] + params[:, 2] * d[:, 0]
    samp = rc[:, 1] + params[:, 3] + params[:, 4] * d[:, 1] + params[:, 5] * d[:, 0]
    return np.column_stack([line, samp])


def _affine_matrix(p: Array) -> Array:
    """``d(line, sample) / d(r', c')`` of the affine correction."""
    return np.array([[1.0 + p[2], p[1]], [p[5], 1.0 + p[4]]])


class AffineCorrections:
    """Six affine image-space corrections of any sensor model (module docstring; ``seeds/001`` Eq. 13).

    Parameters
    ----------
    sensor : SensorModel
        The corrected sensor (an RFM in the LROC study).
    origin : (float, float)
        ``(r_0, c_0)``, pixels: the origin of the affine slopes.
    """

    names = _AFFINE_NAMES
    units = ("px", "1", "1", "px", "1", "1")
    n_params = 6

    def __init__(self, sensor: Any, origin: tuple[float, float] = (0.0, 0.0)) -> None:
        self.sensor = sensor
        self.origin = np.asarray(origin, dtype=float).reshape(2)
        if not np.all(np.isfinite(self.origin)):
            raise InvalidInputError("affine correction origin must be finite pixels")

    def __repr__(self) -> str:
        return f"AffineCorrections({self.sensor!r}, origin={tuple(self.origin)})"

    def project(self, params: ArrayLike, xyz: ArrayLike) -> Array:
        p = _params(params, 6, "AffineCorrections")
        X = _xyz(xyz)
        li, sa = self.sensor.ground_to_image(X, on_miss="nan", within_image=False)
        return apply_affine(p, np.column_stack([li, sa]), self.origin)

    def partials(self, params: ArrayLike, xyz: ArrayLike) -> tuple[Array, Array, Array]:
        p = _params(params, 6, "AffineCorrections")
        X = _xyz(xyz)
        li, sa, jac = self.sensor.ground_partials(X)
        rc = np.column_stack([li, sa])
        d = rc - self.origin
        n = X.shape[0]
        jc = np.zeros((n, 2, 6))
        jc[:, 0, 0] = 1.0
        jc[:, 0, 1] = d[:, 1]
        jc[:, 0, 2] = d[:, 0]
        jc[:, 1, 3] = 1.0
        jc[:, 1, 4] = d[:, 1]
        jc[:, 1, 5] = d[:, 0]
        return apply_affine(p, rc, self.origin), jc, np.einsum("ij,njk->nik", _affine_matrix(p), jac)

    def apply(self, params: ArrayLike) -> "AffineCorrectedSensor":
        return AffineCorrectedSensor(self.sensor, _params(params, 6, "AffineCorrections"), self.origin)


@dataclass(frozen=True, eq=False)
class AffineCorrectedSensor:
    """A sensor model followed by an affine image-space correction (the adjusted form of an RFM).

    Parameters
    ----------
    base : SensorModel
        The uncorrected model.
    params : ndarray (6,)
        ``[a0, a1, a2, b0, b1, b2]`` (pixels and dimensionless), see :class:`AffineCorrections`.
    origin : ndarray (2,)
        Origin of the affine slopes, pixels.
    """

    base: Any
    params: Array
    origin: Array

    @property
    def n_lines(self) -> int:
        return int(self.base.n_lines)

    @property
    def n_samples(self) -> int:
        return int(self.base.n_samples)

    @property
    def reference_radius(self) -> float:
        return float(self.base.reference_radius)

    def __repr__(self) -> str:
        return f"AffineCorrectedSensor({self.base!r}, params={np.round(self.params, 9).tolist()})"

    def _to_base(self, line: ArrayLike, sample: ArrayLike) -> tuple[Array, Array]:
        line, sample = np.broadcast_arrays(np.asarray(line, dtype=float), np.asarray(sample, dtype=float))
        p, o = self.params, self.origin
        rhs = np.stack([line - p[0] + p[2] * o[0] + p[1] * o[1], sample - p[3] + p[5] * o[0] + p[4] * o[1]], -1)
        rc = np.linalg.solve(_affine_matrix(p), rhs.reshape(-1, 2).T).T.reshape(rhs.shape)
        return rc[..., 0], rc[..., 1]

    def ground_to_image(self, xyz: ArrayLike, on_miss: str = "nan", within_image: bool = True
                        ) -> tuple[Array, Array]:
        xyz = np.asarray(xyz, dtype=float)
        li, sa = self.base.ground_to_image(xyz, on_miss=on_miss, within_image=False)
        shape = np.shape(li)
        out = apply_affine(self.params, np.column_stack([np.ravel(li), np.ravel(sa)]), self.origin)
        line, sample = out[:, 0].reshape(shape), out[:, 1].reshape(shape)
        if within_image and self.n_lines > 0 and self.n_samples > 0:
            tol = 1e-6
            inside = (line >= -tol) & (line <= self.n_lines + tol) & (sample >= -tol) & (sample <= self.n_samples + tol)
            if on_miss == "raise" and not np.all(inside):
                from ..errors import GeometryError

                raise GeometryError(f"{int(np.sum(~inside))} ground point(s) fall outside the image")
            line, sample = np.where(inside, line, np.nan), np.where(inside, sample, np.nan)
        return line, sample

    def image_to_ground(self, line: ArrayLike, sample: ArrayLike, height: ArrayLike = 0.0, dtm: Any = None,
                        on_miss: str = "raise") -> Array:
        r, c = self._to_base(line, sample)
        return self.base.image_to_ground(r, c, height=height, dtm=dtm, on_miss=on_miss)

    def rays(self, line: ArrayLike, sample: ArrayLike) -> tuple[Array, Array]:
        return self.base.rays(*self._to_base(line, sample))

    def look_vector(self, line: ArrayLike, sample: ArrayLike) -> Array:
        return self.rays(line, sample)[1]

    def ground_partials(self, xyz: ArrayLike) -> tuple[Array, Array, Array]:
        li, sa, jac = self.base.ground_partials(xyz)
        shape = np.shape(li)
        out = apply_affine(self.params, np.column_stack([np.ravel(li), np.ravel(sa)]), self.origin)
        return (out[:, 0].reshape(shape), out[:, 1].reshape(shape),
                np.einsum("ij,...jk->...ik", _affine_matrix(self.params), jac))

    def corrections(self, degree: int | None = None) -> AffineCorrections:
        """Further affine corrections on top of this one (same origin)."""
        return AffineCorrections(self, tuple(self.origin))
