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

from .rotation import left_jacobian, rotate, rotvec_to_matrix, skew

__all__ = ["FrameModel", "project_frame", "frame_jacobians"]


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
    param_names = ("w_x", "w_y", "w_z", "C_x", "C_y", "C_z")

    def __init__(self, R0: NDArray, f, k1=0.0, k2=0.0):
        self.R0 = np.asarray(R0, dtype=float)
        n = self.R0.shape[0]
        self.f = np.broadcast_to(np.asarray(f, dtype=float), (n,)).copy()
        self.k1 = np.broadcast_to(np.asarray(k1, dtype=float), (n,)).copy()
        self.k2 = np.broadcast_to(np.asarray(k2, dtype=float), (n,)).copy()

    @property
    def n_images(self) -> int:
        return self.R0.shape[0]

    def project(self, params: NDArray, cam_idx: NDArray, X: NDArray) -> NDArray:
        """Image coordinates (pixels) of the observations ``cam_idx`` of points ``X (n, 3)``."""
        R = (rotvec_to_matrix(params[:, 0:3]) @ self.R0)[cam_idx]
        P = np.einsum("nij,nj->ni", R, X - params[cam_idx, 3:6])
        p = -P[:, :2] / P[:, 2:3]
        r2 = np.sum(p * p, axis=1)
        k1, k2 = self.k1[cam_idx], self.k2[cam_idx]
        return (self.f[cam_idx] * (1.0 + r2 * (k1 + k2 * r2)))[:, None] * p

    def linearize(self, params: NDArray, cam_idx: NDArray, X: NDArray):
        """``(x, J_cam, J_pt)`` for the observations; see :func:`frame_jacobians`."""
        x, Jc, Jp, _ = frame_jacobians(params[:, 0:3], self.R0, params[:, 3:6], self.f, self.k1, self.k2, X,
                                       cam_idx=cam_idx)
        return x, Jc, Jp

    def rotation(self, params: NDArray) -> NDArray:
        """Adjusted rotations body-fixed -> camera, ``(n_img, 3, 3)``."""
        return rotvec_to_matrix(params[:, 0:3]) @ self.R0
