"""Line-scan image model: position and attitude corrections as polynomials in time (degree 0-2).

Each image has a reference line-scan camera (:class:`lunarmap.camera.LineScanCamera`: its
exterior orientation ``C_ref(t)``, ``R_ref(t)`` sensor -> body, line timing and interior
orientation, distortion-free).  The adjusted sensor at exposure time ``t`` is::

    C(t) = C_ref(t) + sum_k c_k tau^k                       (metres, body-fixed)
    v    = exp([w(tau)]x) R_ref(t)^T (X - C(t)),  w(tau) = sum_k w_k tau^k   (radians, sensor frame)
    tau  = (t - t_mid) / t_half                              (-1 .. 1 over the image)

and the focal-plane point ``(x, y) = f (v_x, v_y) / v_z`` (millimetres) maps to the detector by
the interior orientation's affine ``focal2pixel`` transforms.  A ground point is imaged at the
time whose detector-line coordinate is zero (the image line is time); it is found by Newton
steps in ``t``.  Image coordinates are ``(line, sample)``, pixels, CSM convention.

Partial derivatives are analytic in the parameters and the point at fixed ``t`` and follow the
implicit-function rule for ``t``: with ``r(t, p) = 0``, ``dt/dp = -(dr/dp) / (dr/dt)``;
``dr/dt`` (reference trajectory and ``tau``) is a central difference over 1 ms.

Parameters per image (``n_params = 6 (degree + 1)``): ``[w_0 (3), c_0 (3), w_1, c_1, ...]``.
Polynomial attitude and position corrections are strongly correlated for a narrow-angle camera;
give them a-priori sigmas (e.g. :class:`~lunarmap.adjust.navigation.NavigationObservations` with
zero observations) or fix some of them.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from ..errors import AdjustmentInputError, ConvergenceError
from .rotation import left_jacobian, rotvec_to_matrix, skew

__all__ = ["LineScanPolyModel"]

_NEWTON_MAX = 30
_NEWTON_TOL_LINES = 1e-9
_DT = 1e-3   # s, central difference of the reference trajectory


class LineScanPolyModel:
    """Line-scan cameras with polynomial position/attitude corrections (see the module docstring).

    Parameters
    ----------
    cameras : sequence of LineScanCamera
        Reference cameras (their EO is the navigation); distortion must be ``none``.
    degree : int
        Polynomial degree 0, 1 or 2 of the corrections (same for all images).
    """

    def __init__(self, cameras: Sequence, degree: int = 1):
        if degree not in (0, 1, 2):
            raise AdjustmentInputError(f"polynomial degree must be 0, 1 or 2, got {degree}")
        self.cameras = list(cameras)
        if not self.cameras:
            raise AdjustmentInputError("LineScanPolyModel needs at least one camera")
        for i, cam in enumerate(self.cameras):
            if cam.interior.distortion_model not in ("none", None):
                raise AdjustmentInputError(f"camera {i}: distortion {cam.interior.distortion_model!r} is not "
                                           "supported (the model is distortion-free)")
        self.degree = degree
        self.n_params = 6 * (degree + 1)
        self.param_names = tuple(f"{q}{ax}_{k}" for k in range(degree + 1) for q in ("w", "c") for ax in "xyz")
        self._t_mid = np.empty(len(self.cameras))
        self._t_half = np.empty(len(self.cameras))
        for i, cam in enumerate(self.cameras):
            t0, t1 = cam.image_time(np.array([0.0, float(cam.interior.n_lines)]))
            self._t_mid[i], self._t_half[i] = 0.5 * (t0 + t1), 0.5 * abs(t1 - t0)

    @property
    def n_images(self) -> int:
        return len(self.cameras)

    def initial_params(self) -> NDArray[np.float64]:
        """Zero corrections: the reference cameras."""
        return np.zeros((self.n_images, self.n_params))

    def tau(self, cam: int, t: NDArray) -> NDArray:
        """Normalised time of image ``cam`` (dimensionless, -1 .. 1 over the image)."""
        return (t - self._t_mid[cam]) / self._t_half[cam]

    def initial_points(self, params: NDArray, cam_idx: NDArray, pt_idx: NDArray, xy: NDArray, n_pt: int,
                       height: float = 0.0) -> NDArray[np.float64]:
        """Start values of the points (metres): mean of the reference cameras' rays at ``height`` metres.

        The corrections are ignored (they are small); refine with
        :func:`lunarmap.adjust.intersection.intersect_points`.
        """
        cam_idx = np.asarray(cam_idx, np.int64)
        pt_idx = np.asarray(pt_idx, np.int64)
        g = np.empty((cam_idx.size, 3))
        for i in np.unique(cam_idx):
            m = cam_idx == i
            g[m] = self.cameras[i].image_to_ground(xy[m, 0], xy[m, 1], height)
        cnt = np.maximum(np.bincount(pt_idx, minlength=n_pt), 1)
        return np.column_stack([np.bincount(pt_idx, weights=g[:, k], minlength=n_pt) for k in range(3)]) / cnt[:, None]

    # -- one image: focal-plane residual at given times ---------------------------
    def _geometry(self, cam: int, params: NDArray, X: NDArray, t: NDArray):
        """Sensor-frame vectors v, the pieces for the partials, detector (r, s) pixels."""
        c = self.cameras[cam]
        io = c.interior
        tau = self.tau(cam, t)
        powers = tau[:, None] ** np.arange(self.degree + 1)[None, :]          # (n, d+1)
        P = params.reshape(self.degree + 1, 2, 3)                            # [k, (w, c), xyz]
        w = powers @ P[:, 0, :]
        dC = powers @ P[:, 1, :]
        Rref = c.eo.rotation_at(t)                                           # sensor -> body
        u = np.einsum("nji,nj->ni", Rref, X - c.eo.position_at(t) - dC)     # R_ref^T (X - C)
        E = rotvec_to_matrix(w)
        v = np.einsum("nij,nj->ni", E, u)
        f = io.focal_length
        il, is_ = io.focal2pixel_lines, io.focal2pixel_samples
        x, y = f * v[:, 0] / v[:, 2], f * v[:, 1] / v[:, 2]
        r = (il[0] + il[1] * x + il[2] * y + io.detector_center_line - io.starting_detector_line) / io.line_summing
        s = (is_[0] + is_[1] * x + is_[2] * y + io.detector_center_sample - io.starting_detector_sample) \
            / io.sample_summing
        return r, s, v, E, Rref, w, powers

    def _detector(self, cam, params, X, t):
        r, s, *_ = self._geometry(cam, params, X, t)
        return r, s

    def _solve_time(self, cam: int, params: NDArray, X: NDArray) -> NDArray:
        c = self.cameras[cam]
        rate = abs(float(c.image_time(1.0) - c.image_time(0.0)))
        t = np.full(X.shape[0], self._t_mid[cam])
        for _ in range(_NEWTON_MAX):
            r = self._detector(cam, params, X, t)[0]
            rp = self._detector(cam, params, X, t + _DT)[0]
            rm = self._detector(cam, params, X, t - _DT)[0]
            step = r / ((rp - rm) / (2 * _DT))
            t = t - step
            if np.all(np.abs(step) < _NEWTON_TOL_LINES * rate):
                return t
        raise ConvergenceError(f"line-scan ground-to-image did not converge for image {cam} "
                               f"(max |dt| {np.max(np.abs(step)):.2e} s)")

    # -- image model protocol ----------------------------------------------------
    def project(self, params: NDArray, cam_idx: NDArray, X: NDArray) -> NDArray[np.float64]:
        """Image ``(line, sample)`` pixels ``(n, 2)`` of points ``X (n, 3)`` metres in images ``cam_idx``."""
        cam_idx = np.asarray(cam_idx, np.int64)
        out = np.empty((cam_idx.size, 2))
        for i in np.unique(cam_idx):
            m = cam_idx == i
            t = self._solve_time(i, params[i], X[m])
            out[m, 0] = self.cameras[i].line_times.line(t)
            out[m, 1] = self._detector(i, params[i], X[m], t)[1]
        return out

    def linearize(self, params: NDArray, cam_idx: NDArray, X: NDArray):
        """``(line, sample) (n, 2)``, ``d/d params (n, 2, n_params)``, ``d/d X (n, 2, 3)`` (pixels per metre)."""
        cam_idx = np.asarray(cam_idx, np.int64)
        n = cam_idx.size
        xy = np.empty((n, 2))
        Jc = np.empty((n, 2, self.n_params))
        Jp = np.empty((n, 2, 3))
        for i in np.unique(cam_idx):
            m = cam_idx == i
            xy[m], Jc[m], Jp[m] = self._linearize_image(i, params[i], X[m])
        return xy, Jc, Jp

    def _linearize_image(self, cam: int, params: NDArray, X: NDArray):
        c = self.cameras[cam]
        io = c.interior
        t = self._solve_time(cam, params, X)
        r, s, v, E, Rref, w, powers = self._geometry(cam, params, X, t)
        n = X.shape[0]
        f = io.focal_length
        il, is_ = io.focal2pixel_lines, io.focal2pixel_samples
        # d(r, s)/dv at fixed t: d(x, y)/dv = f / v_z [[1, 0, -x/f], [0, 1, -y/f]]
        iz = 1.0 / v[:, 2]
        dxy = np.zeros((n, 2, 3))
        dxy[:, 0, 0] = f * iz
        dxy[:, 1, 1] = f * iz
        dxy[:, 0, 2] = -f * v[:, 0] * iz * iz
        dxy[:, 1, 2] = -f * v[:, 1] * iz * iz
        A = np.array([[il[1] / io.line_summing, il[2] / io.line_summing],
                      [is_[1] / io.sample_summing, is_[2] / io.sample_summing]])
        drs_dv = np.einsum("ij,njk->nik", A, dxy)                           # (n, 2, 3)
        M = np.einsum("nij,nkj->nik", E, Rref)                              # E R_ref^T: dv/dX
        d_X = np.einsum("nij,njk->nik", drs_dv, M)
        # dv/dw = -[v]x J_l(w); dv/dc = -M; both times tau^k

        d_w = np.einsum("nij,njk->nik", drs_dv, -skew(v) @ left_jacobian(w))
        d_c = -d_X
        d_p = np.empty((n, 2, self.n_params))
        for k in range(self.degree + 1):
            d_p[:, :, 6 * k:6 * k + 3] = d_w * powers[:, k, None, None]
            d_p[:, :, 6 * k + 3:6 * k + 6] = d_c * powers[:, k, None, None]
        # implicit time: r(t, p, X) = 0
        rp, sp_ = self._detector(cam, params, X, t + _DT)
        rm, sm = self._detector(cam, params, X, t - _DT)
        dr_dt = (rp - rm) / (2 * _DT)
        ds_dt = (sp_ - sm) / (2 * _DT)
        dt_dp = -d_p[:, 0, :] / dr_dt[:, None]
        dt_dX = -d_X[:, 0, :] / dr_dt[:, None]
        lines = c.line_times.line(t)
        dL_dt = (c.line_times.line(t + _DT) - c.line_times.line(t - _DT)) / (2 * _DT)
        Jc = np.empty((n, 2, self.n_params))
        Jp = np.empty((n, 2, 3))
        Jc[:, 0] = dL_dt[:, None] * dt_dp
        Jp[:, 0] = dL_dt[:, None] * dt_dX
        Jc[:, 1] = d_p[:, 1] + ds_dt[:, None] * dt_dp
        Jp[:, 1] = d_X[:, 1] + ds_dt[:, None] * dt_dX
        return np.column_stack([lines, s]), Jc, Jp
