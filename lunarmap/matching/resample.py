"""Vectorised bilinear resampling of images at continuous CSM pixel coordinates.

CSM convention: the centre of array element ``[i, j]`` is at ``(line, sample) =
(i + 0.5, j + 0.5)``. Samples outside the pixel-centre hull are NaN, and NaN
pixels propagate, so every window that touches invalid data is flagged by a
NaN instead of silently mixing in fill values.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["bilinear", "bicubic_with_gradient"]

Array = NDArray[np.float64]


def bilinear(image: NDArray, line: ArrayLike, sample: ArrayLike) -> Array:
    """Bilinear values of ``image`` at CSM coordinates.

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, C)
        Pixel values; a trailing channel axis is interpolated alongside (one
        index computation serves the image and, e.g., its gradients).
    line, sample : array_like
        Continuous pixel coordinates (CSM), broadcast together.

    Returns
    -------
    ndarray, shape (...,) or (..., C)
        Interpolated values, NaN outside ``[0.5, H - 0.5] x [0.5, W - 0.5]``.
    """
    y = np.asarray(line, dtype=float) - 0.5
    x = np.asarray(sample, dtype=float) - 0.5
    y, x = np.broadcast_arrays(y, x)
    h, w = image.shape[:2]
    inside = (y >= 0.0) & (y <= h - 1) & (x >= 0.0) & (x <= w - 1)
    yc = np.where(inside, y, 0.0)
    xc = np.where(inside, x, 0.0)
    i = np.minimum(yc.astype(np.intp), h - 2)
    j = np.minimum(xc.astype(np.intp), w - 2)
    fy = yc - i
    fx = xc - j
    if image.ndim == 3:
        fy = fy[..., None]
        fx = fx[..., None]
        mask = inside[..., None]
    else:
        mask = inside
    # Flat indices: one gather per corner instead of 2-D fancy indexing.
    flat = image.reshape(h * w, *image.shape[2:])
    k = i * w + j
    v00 = flat[k]
    v01 = flat[k + 1]
    v10 = flat[k + w]
    v11 = flat[k + w + 1]
    out = (1.0 - fy) * ((1.0 - fx) * v00 + fx * v01) + fy * ((1.0 - fx) * v10 + fx * v11)
    return np.where(mask, out, np.nan)


def _keys(t: Array) -> tuple[Array, Array]:
    """Keys (1981) cubic-convolution weights (a = -0.5) of the 4 taps and their derivatives."""
    t2 = t * t
    t3 = t2 * t
    w = np.stack([-0.5 * t3 + t2 - 0.5 * t, 1.5 * t3 - 2.5 * t2 + 1.0,
                  -1.5 * t3 + 2.0 * t2 + 0.5 * t, 0.5 * t3 - 0.5 * t2], axis=-1)
    dw = np.stack([-1.5 * t2 + 2.0 * t - 0.5, 4.5 * t2 - 5.0 * t,
                   -4.5 * t2 + 4.0 * t + 0.5, 1.5 * t2 - t], axis=-1)
    return w, dw


def bicubic_with_gradient(image: NDArray, line: ArrayLike, sample: ArrayLike) -> tuple[Array, Array, Array]:
    """Cubic-convolution values and their exact line and sample derivatives at CSM coordinates.

    The interpolant is C1-continuous, so Gauss-Newton iterations on it (least-
    squares matching) converge smoothly, and its derivatives are those of the
    very surface being fitted. NaN outside ``[1.5, H - 1.5] x [1.5, W - 1.5]``
    (all 16 taps must exist) and next to NaN pixels.

    Returns
    -------
    value, d_line, d_sample : ndarray
        Grey levels and grey levels per pixel.
    """
    img = np.asarray(image, dtype=float)
    y = np.asarray(line, dtype=float) - 0.5
    x = np.asarray(sample, dtype=float) - 0.5
    y, x = np.broadcast_arrays(y, x)
    h, w = img.shape
    inside = (y >= 1.0) & (y <= h - 2) & (x >= 1.0) & (x <= w - 2)
    yc = np.where(inside, y, 1.0)
    xc = np.where(inside, x, 1.0)
    i = np.minimum(np.floor(yc).astype(np.intp), h - 3)
    j = np.minimum(np.floor(xc).astype(np.intp), w - 3)
    wy, dwy = _keys(yc - i)
    wx, dwx = _keys(xc - j)
    offs = (np.arange(4)[:, None] * w + np.arange(4)[None, :]).ravel()
    k = ((i - 1) * w + (j - 1))[..., None] + offs
    v = img.ravel()[k]
    # Separable: interpolate the 4 tap rows along samples, then along lines
    # (explicit 4-term sums of small arrays beat einsum and outer products here).
    rows = v[..., 0::4] * wx[..., 0:1] + v[..., 1::4] * wx[..., 1:2] + v[..., 2::4] * wx[..., 2:3] \
        + v[..., 3::4] * wx[..., 3:4]
    drows = v[..., 0::4] * dwx[..., 0:1] + v[..., 1::4] * dwx[..., 1:2] + v[..., 2::4] * dwx[..., 2:3] \
        + v[..., 3::4] * dwx[..., 3:4]
    val = np.sum(rows * wy, axis=-1)
    d_line = np.sum(rows * dwy, axis=-1)
    d_sample = np.sum(drows * wy, axis=-1)
    bad = ~inside
    return (np.where(bad, np.nan, val), np.where(bad, np.nan, d_line), np.where(bad, np.nan, d_sample))
