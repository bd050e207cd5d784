"""Vectorised rotation helpers in SPICE's quaternion convention.

Quaternions are ``(w, x, y, z)`` with the scalar first, as returned by
``spiceypy.m2q``; :func:`quat_to_matrix` equals ``spiceypy.q2m`` so that
``v_to = quat_to_matrix(q) @ v_from``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["quat_to_matrix", "matrix_to_quat", "align_quaternion_signs", "normalize_quat"]


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
