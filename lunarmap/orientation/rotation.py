"""Vectorised rotation helpers in SPICE's quaternion convention.

Quaternions are ``(w, x, y, z)`` with the scalar first, as returned by
``spiceypy.m2q``; :func:`quat_to_matrix` equals ``spiceypy.q2m`` so that
``v_to = quat_to_matrix(q) @ v_from``.

Rotation vectors (angle-axis, radians) for small corrections: ``R(w) = exp([w]x)``
(Rodrigues); the left Jacobian satisfies ``R(w + d) ~= exp([J_l(w) d]x) R(w)`` to first order.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["quat_to_matrix", "matrix_to_quat", "align_quaternion_signs", "normalize_quat",
           "skew", "rotvec_to_matrix", "matrix_to_rotvec", "rotate", "left_jacobian"]


def quat_to_matrix(q: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrices from unit quaternions.

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Quaternions ``(w, x, y, z)``; they are normalised first.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        The matrices that ``spiceypy.q2m`` returns.
    """
    q = normalize_quat(q)
    w, x, y, z = np.moveaxis(q, -1, 0)
    m = np.empty(q.shape[:-1] + (3, 3))
    m[..., 0, 0] = 1.0 - 2.0 * (y * y + z * z)
    m[..., 0, 1] = 2.0 * (x * y - w * z)
    m[..., 0, 2] = 2.0 * (x * z + w * y)
    m[..., 1, 0] = 2.0 * (x * y + w * z)
    m[..., 1, 1] = 1.0 - 2.0 * (x * x + z * z)
    m[..., 1, 2] = 2.0 * (y * z - w * x)
    m[..., 2, 0] = 2.0 * (x * z - w * y)
    m[..., 2, 1] = 2.0 * (y * z + w * x)
    m[..., 2, 2] = 1.0 - 2.0 * (x * x + y * y)
    return m


def matrix_to_quat(m: ArrayLike) -> NDArray[np.float64]:
    """Unit quaternions ``(w, x, y, z)`` from rotation matrices, with ``w >= 0``.

    Uses Shepperd's method (largest-diagonal pivot) so that precision does
    not degrade near 180-degree rotations. Equals ``spiceypy.m2q`` up to sign.
    """
    m = np.asarray(m, dtype=float)
    shape = m.shape[:-2]
    m = m.reshape(-1, 3, 3)
    tr = np.trace(m, axis1=1, axis2=2)
    diag = np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1)
    pivot = np.argmax(diag, axis=1)
    q = np.empty((m.shape[0], 4))
    for k in range(4):
        sel = pivot == k
        if not np.any(sel):
            continue
        a = m[sel]
        if k == 0:
            s = 2.0 * np.sqrt(1.0 + tr[sel])
            q[sel] = np.stack([0.25 * s, (a[:, 2, 1] - a[:, 1, 2]) / s,
                               (a[:, 0, 2] - a[:, 2, 0]) / s, (a[:, 1, 0] - a[:, 0, 1]) / s], axis=1)
        elif k == 1:
            s = 2.0 * np.sqrt(1.0 + a[:, 0, 0] - a[:, 1, 1] - a[:, 2, 2])
            q[sel] = np.stack([(a[:, 2, 1] - a[:, 1, 2]) / s, 0.25 * s,
                               (a[:, 0, 1] + a[:, 1, 0]) / s, (a[:, 0, 2] + a[:, 2, 0]) / s], axis=1)
        elif k == 2:
            s = 2.0 * np.sqrt(1.0 - a[:, 0, 0] + a[:, 1, 1] - a[:, 2, 2])
            q[sel] = np.stack([(a[:, 0, 2] - a[:, 2, 0]) / s, (a[:, 0, 1] + a[:, 1, 0]) / s,
                               0.25 * s, (a[:, 1, 2] + a[:, 2, 1]) / s], axis=1)
        else:
            s = 2.0 * np.sqrt(1.0 - a[:, 0, 0] - a[:, 1, 1] + a[:, 2, 2])
            q[sel] = np.stack([(a[:, 1, 0] - a[:, 0, 1]) / s, (a[:, 0, 2] + a[:, 2, 0]) / s,
                               (a[:, 1, 2] + a[:, 2, 1]) / s, 0.25 * s], axis=1)
    q *= np.where(q[:, :1] < 0.0, -1.0, 1.0)
    return normalize_quat(q).reshape(shape + (4,))


def normalize_quat(q: ArrayLike) -> NDArray[np.float64]:
    """Quaternions scaled to unit norm along the last axis."""
    q = np.asarray(q, dtype=float)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def align_quaternion_signs(q: ArrayLike) -> NDArray[np.float64]:
    """Flip signs along axis 0 so consecutive quaternions lie in the same hemisphere.

    ``q`` and ``-q`` are the same rotation; interpolating components is only
    meaningful once neighbours agree in sign.
    """
    q = np.array(q, dtype=float, copy=True)
    if q.shape[0] < 2:
        return q
    flips = np.einsum("ij,ij->i", q[1:], q[:-1]) < 0.0
    sign = np.concatenate([[1.0], np.where(np.cumsum(flips) % 2 == 1, -1.0, 1.0)])
    return q * sign[:, None]


def skew(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Cross-product matrices, ``(..., 3) -> (..., 3, 3)``."""
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def _coeffs(theta: NDArray[np.float64]):
    # sin(t)/t, (1-cos t)/t^2, (t - sin t)/t^3 with Taylor series near zero (no 0/0)
    small = theta < 1e-4
    t = np.where(small, 1.0, theta)
    t2 = theta * theta
    a = np.where(small, 1.0 - t2 / 6.0, np.sin(t) / t)
    b = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(t)) / (t * t))
    c = np.where(small, 1.0 / 6.0 - t2 / 120.0, (t - np.sin(t)) / (t * t * t))
    return a, b, c


def rotvec_to_matrix(w: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation vectors (radians) to matrices, ``(..., 3) -> (..., 3, 3)``."""
    w = np.asarray(w, dtype=float)
    a, b, _ = _coeffs(np.linalg.norm(w, axis=-1))
    K = skew(w)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)


def matrix_to_rotvec(R: NDArray[np.float64]) -> NDArray[np.float64]:
    """Inverse of :func:`rotvec_to_matrix` for rotation angles below ``pi - 1e-6`` (radians)."""
    R = np.asarray(R, dtype=float)
    tr = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(tr)
    v = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    a, _, _ = _coeffs(theta)
    return v / (2.0 * a[..., None])


def rotate(w: NDArray[np.float64], X: NDArray[np.float64]) -> NDArray[np.float64]:
    """``R(w) @ X`` for paired rows ``w (n, 3)`` and ``X (n, 3)``."""
    a, b, _ = _coeffs(np.linalg.norm(w, axis=1))
    wx = np.cross(w, X)
    return X + a[:, None] * wx + b[:, None] * np.cross(w, wx)


def left_jacobian(w: NDArray[np.float64]) -> NDArray[np.float64]:
    """SO(3) left Jacobian ``J_l(w)``, ``(n, 3) -> (n, 3, 3)``."""
    _, b, c = _coeffs(np.linalg.norm(w, axis=1))
    K = skew(w)
    return np.eye(3) + b[:, None, None] * K + c[:, None, None] * (K @ K)
