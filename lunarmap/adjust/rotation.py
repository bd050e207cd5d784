"""Batched rotation-vector (angle-axis) helpers used by the adjustment's Jacobians.

Conventions: ``R(w) = exp([w]x)`` (Rodrigues); the left Jacobian satisfies
``R(w + d) ~= exp([J_l(w) d]x) R(w)`` to first order.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["skew", "rotvec_to_matrix", "matrix_to_rotvec", "rotate", "left_jacobian"]


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
