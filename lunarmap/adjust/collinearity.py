"""Collinearity (frame-camera) projection with analytic Jacobians.

Model (DLR paper, ``seeds/004``, Eq. 1, written in the BAL sign convention)::

    X_c = R (X - C),      R = exp([w]x) R0       (body-fixed -> camera)
    p   = -X_c[:2] / X_c[2]                      (camera looks down -z_c)
    x   = f (1 + k1 |p|^2 + k2 |p|^4) p          (pixels from the principal point, x right, y up)

Per image the unknowns are the 6 exterior-orientation parameters
``[w (3, radians), C (3, length unit of the points)]``; ``R0`` is a fixed
reference attitude (for example the navigation attitude), so ``w`` is the
attitude correction and is directly comparable with attitude observations.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .rotation import left_jacobian, rotate, rotvec_to_matrix

try:  # optional: one fused pass per observation instead of ~20 numpy temporaries of (n, 3, 3)
    import numba
    from numba import prange
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None
    prange = range

__all__ = ["FrameModel", "project_frame", "frame_jacobians"]


def _frame_kernel_py(Rc, Jl, C, f, k1, k2, X, cam_idx, pt_idx, want_jac):
    """Projection (and Jacobians) of observation ``i`` of image ``cam_idx[i]`` and point ``pt_idx[i]``.

    Same equations as :func:`frame_jacobians`, written per observation for numba.
    """
    n = cam_idx.size
    x = np.empty((n, 2))
    Jc = np.empty((n if want_jac else 0, 2, 6))
    Jp = np.empty((n if want_jac else 0, 2, 3))
    for i in prange(n):
        c = cam_idx[i]
        j = pt_idx[i]
        d0 = X[j, 0] - C[c, 0]
        d1 = X[j, 1] - C[c, 1]
        d2 = X[j, 2] - C[c, 2]
        P0 = Rc[c, 0, 0] * d0 + Rc[c, 0, 1] * d1 + Rc[c, 0, 2] * d2
        P1 = Rc[c, 1, 0] * d0 + Rc[c, 1, 1] * d1 + Rc[c, 1, 2] * d2
        P2 = Rc[c, 2, 0] * d0 + Rc[c, 2, 1] * d1 + Rc[c, 2, 2] * d2
        iz = 1.0 / P2
        p0 = -P0 * iz
        p1 = -P1 * iz
        r2 = p0 * p0 + p1 * p1
        d = 1.0 + r2 * (k1[c] + k2[c] * r2)
        fc = f[c]
        x[i, 0] = fc * d * p0
        x[i, 1] = fc * d * p1
        if want_jac:
            g = 2.0 * k1[c] + 4.0 * k2[c] * r2
            m00 = fc * (g * p0 * p0 + d)
            m01 = fc * g * p0 * p1
            m11 = fc * (g * p1 * p1 + d)
            for k in range(2):
                # row k of dx/dP = dx/dp @ [[-1/z, 0, X/z^2], [0, -1/z, Y/z^2]]
                a = m00 if k == 0 else m01
                b = m01 if k == 0 else m11
                u0 = -a * iz
                u1 = -b * iz
                u2 = -(a * p0 + b * p1) * iz
                # d X_c / d w: row u^T (-[P]x) = (P x u)^T, then times the left Jacobian
                q0 = P1 * u2 - P2 * u1
                q1 = P2 * u0 - P0 * u2
                q2 = P0 * u1 - P1 * u0
                for m in range(3):
                    jp = u0 * Rc[c, 0, m] + u1 * Rc[c, 1, m] + u2 * Rc[c, 2, m]
                    Jp[i, k, m] = jp
                    Jc[i, k, 3 + m] = -jp
                    Jc[i, k, m] = q0 * Jl[c, 0, m] + q1 * Jl[c, 1, m] + q2 * Jl[c, 2, m]
    return x, Jc, Jp


_frame_kernel = (numba.njit(cache=True)(_frame_kernel_py)
                 if numba is not None else None)


def _camera_coords(w, R0, C, X):
    # R0 (X - C) first, then the small correction exp([w]x)
    Y = np.einsum("nij,nj->ni", R0, X - C)
    return rotate(w, Y)


def project_frame(w: NDArray, R0: NDArray, C: NDArray, f: NDArray, k1: NDArray, k2: NDArray,
                  X: NDArray) -> NDArray[np.float64]:
    """Image coordinates (pixels) of paired rows of cameras and points, ``(n, 2)``."""
    P = _camera_coords(w, R0, C, X)
    p = -P[:, :2] / P[:, 2:3]
    r2 = np.sum(p * p, axis=1)
    d = 1.0 + r2 * (k1 + k2 * r2)
    return (f * d)[:, None] * p


def frame_jacobians(w, R0, C, f, k1, k2, X, cam_idx=None):
    """Predicted image coordinates and their Jacobians.

    Camera arrays (``w, R0, C, f, k1, k2``) are per image when ``cam_idx`` is given
    (rotations are then built once per image, not per observation), else per observation.

    Returns
    -------
    x : (n, 2) pixels
    J_cam : (n, 2, 6) pixels per (radian, length unit), w.r.t. ``[w, C]``
    J_pt : (n, 2, 3) pixels per length unit, w.r.t. ``X``
    depth : (n,) ``-X_c[2]``, positive for points in front of the camera
    """
    Rc = rotvec_to_matrix(w) @ R0
    Jl = left_jacobian(w)
    if cam_idx is not None:
        Rc, Jl, C, f, k1, k2 = Rc[cam_idx], Jl[cam_idx], C[cam_idx], f[cam_idx], k1[cam_idx], k2[cam_idx]
    n = X.shape[0]
    P = np.einsum("nij,nj->ni", Rc, X - C)
    iz = 1.0 / P[:, 2]
    p = -P[:, :2] * iz[:, None]
    r2 = np.sum(p * p, axis=1)
    d = 1.0 + r2 * (k1 + k2 * r2)
    x = (f * d)[:, None] * p
    # dx/dP = dx/dp dp/dP with dp/dP = [[-1/z, 0, X/z^2], [0, -1/z, Y/z^2]]
    dpdP = np.zeros((n, 2, 3))
    dpdP[:, 0, 0] = -iz
    dpdP[:, 1, 1] = -iz
    dpdP[:, :, 2] = -p * iz[:, None]
    if np.any(k1) or np.any(k2):
        g = 2.0 * k1 + 4.0 * k2 * r2
        dxdp = (f * g)[:, None, None] * (p[:, :, None] * p[:, None, :])
        dxdp[:, 0, 0] += f * d
        dxdp[:, 1, 1] += f * d
        dxdP = np.einsum("nij,njk->nik", dxdp, dpdP)
    else:
        dxdP = dpdP * f[:, None, None]
    J_cam = np.empty((n, 2, 6))
    J_pt = np.einsum("nij,njk->nik", dxdP, Rc)
    # d X_c / d w = -[X_c]x J_l(w): row u^T (-[P]x) = (P x u)^T  (left perturbation of exp([w]x))
    Pb = np.broadcast_to(P[:, None, :], dxdP.shape)
    J_cam[:, :, 0:3] = np.einsum("nij,njk->nik", np.cross(Pb, dxdP), Jl)
    J_cam[:, :, 3:6] = -J_pt
    return x, J_cam, J_pt, -P[:, 2]


class FrameModel:
    """Frame cameras of a block: fixed intrinsics and reference attitudes, 6 EO unknowns per image.

    Parameters
    ----------
    R0 : (n_img, 3, 3)
        Reference rotations body-fixed -> camera.
    f : (n_img,) or float
        Focal length, pixels.
    k1, k2 : (n_img,) or float
        Radial distortion coefficients (per pixel-normalised radius squared / to the fourth).
    """

    n_params = 6
    param_names: tuple[str, ...] = ("w_x", "w_y", "w_z", "C_x", "C_y", "C_z")

    def __init__(self, R0: NDArray, f, k1=0.0, k2=0.0):
        self.R0 = np.asarray(R0, dtype=float)
        n = self.R0.shape[0]
        self.f = np.broadcast_to(np.asarray(f, dtype=float), (n,)).copy()
        self.k1 = np.broadcast_to(np.asarray(k1, dtype=float), (n,)).copy()
        self.k2 = np.broadcast_to(np.asarray(k2, dtype=float), (n,)).copy()

    @property
    def n_images(self) -> int:
        return self.R0.shape[0]

    @property
    def param_mask(self) -> NDArray[np.bool_]:
        """All six parameters of every image exist."""
        return np.ones((self.n_images, 6), dtype=bool)

    def initial_points(self, params: NDArray, cam_idx: NDArray, pt_idx: NDArray, xy: NDArray, n_pt: int,
                       height: float = 0.0) -> NDArray:
        """Closed-form start values: the points nearest (least squares) to their rays (``height`` unused)."""
        from .intersection import midpoint_intersection

        R = rotvec_to_matrix(params[:, 0:3]) @ self.R0
        f = self.f
        dc = np.column_stack([xy[:, 0] / f[cam_idx], xy[:, 1] / f[cam_idx], -np.ones(xy.shape[0])])
        dirs = np.einsum("nji,nj->ni", R[cam_idx], dc)   # R^T d_cam
        return midpoint_intersection(params[cam_idx, 3:6], dirs, pt_idx, n_pt)

    def project(self, params: NDArray, cam_idx: NDArray, X: NDArray) -> NDArray:
        """Image coordinates (pixels) of the observations ``cam_idx`` of points ``X (n, 3)``."""
        if _frame_kernel is not None:
            return self.project_indexed(params, cam_idx, X, np.arange(X.shape[0]))
        R = (rotvec_to_matrix(params[:, 0:3]) @ self.R0)[cam_idx]
        P = np.einsum("nij,nj->ni", R, X - params[cam_idx, 3:6])
        p = -P[:, :2] / P[:, 2:3]
        r2 = np.sum(p * p, axis=1)
        k1, k2 = self.k1[cam_idx], self.k2[cam_idx]
        return (self.f[cam_idx] * (1.0 + r2 * (k1 + k2 * r2)))[:, None] * p

    def _kernel_args(self, params, cam_idx, X, pt_idx):
        w = np.ascontiguousarray(params[:, 0:3])
        return (np.ascontiguousarray(rotvec_to_matrix(w) @ self.R0), np.ascontiguousarray(left_jacobian(w)),
                np.ascontiguousarray(params[:, 3:6]), self.f, self.k1, self.k2, np.ascontiguousarray(X, float),
                np.ascontiguousarray(cam_idx, np.int64), np.ascontiguousarray(pt_idx, np.int64))

    def project_indexed(self, params: NDArray, cam_idx: NDArray, points: NDArray, pt_idx: NDArray) -> NDArray:
        """Image coordinates (pixels) of observations of images ``cam_idx`` and points ``points[pt_idx]``.

        Avoids gathering an ``(n_obs, 3)`` point array when the compiled kernel is available.
        """
        if _frame_kernel is None:
            return self.project(params, cam_idx, points[pt_idx])
        return _frame_kernel(*self._kernel_args(params, cam_idx, points, pt_idx), False)[0]

    def linearize_indexed(self, params: NDArray, cam_idx: NDArray, points: NDArray, pt_idx: NDArray):
        """``(x, J_cam, J_pt)`` of observations of images ``cam_idx`` and points ``points[pt_idx]``."""
        if _frame_kernel is None:
            return self.linearize(params, cam_idx, points[pt_idx])
        return _frame_kernel(*self._kernel_args(params, cam_idx, points, pt_idx), True)

    def linearize(self, params: NDArray, cam_idx: NDArray, X: NDArray):
        """``(x, J_cam, J_pt)`` for the observations; see :func:`frame_jacobians`."""
        if _frame_kernel is not None:
            return self.linearize_indexed(params, cam_idx, X, np.arange(X.shape[0]))
        x, Jc, Jp, _ = frame_jacobians(params[:, 0:3], self.R0, params[:, 3:6], self.f, self.k1, self.k2, X,
                                       cam_idx=cam_idx)
        return x, Jc, Jp

    def rotation(self, params: NDArray) -> NDArray:
        """Adjusted rotations body-fixed -> camera, ``(n_img, 3, 3)``."""
        return rotvec_to_matrix(params[:, 0:3]) @ self.R0
