"""Vectorised bilinear and cubic-convolution resampling of images at continuous CSM pixel coordinates.

CSM convention: the centre of array element ``[i, j]`` is at ``(line, sample) =
(i + 0.5, j + 0.5)``. Samples outside the pixel-centre hull are NaN, and NaN
pixels propagate, so every window that touches invalid data is flagged by a
NaN instead of silently mixing in fill values.

Every function takes an in-memory array or a windowed image
(:class:`~lunarmap.matching.windowed.WindowedImage`, anything with ``region`` and ``shape``):
the latter is sampled in the regions its stencils need, with the same values.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InvalidInputError

try:  # optional: cubic convolution with gradients in one compiled pass (issue 32)
    import numba
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None

__all__ = ["bilinear", "bicubic", "bicubic_with_gradient"]

Array = NDArray[np.float64]


def _windowed(image: Any) -> bool:
    return not isinstance(image, np.ndarray) and hasattr(image, "region") and hasattr(image, "shape")


def _by_region(fn: Any, image: Any, line: ArrayLike, sample: ArrayLike, before: int, after: int,
               n_out: int) -> Any:
    """``fn`` on the regions of a windowed image that hold the call's stencils (see :mod:`.windowed`).

    Each group of coordinate rows is sampled in its own region, shifted by the region's integer
    origin (exact in floating point), so the values are those ``fn`` gives on the whole image.
    """
    from .windowed import stencil_regions

    y = np.asarray(line, dtype=float)
    x = np.asarray(sample, dtype=float)
    y, x = np.broadcast_arrays(y, x)
    shape = y.shape
    yy, xx = (np.atleast_1d(y), np.atleast_1d(x)) if y.ndim else (y.reshape(1), x.reshape(1))
    outs = [np.full(yy.shape, np.nan) for _ in range(n_out)]
    partial = getattr(image, "fills_on_demand", False)
    for rows, (a0, a1, b0, b1), need in stencil_regions(yy - 0.5, xx - 0.5, image.shape, before, after):
        # an image that computes its pixels on demand (smoothed) is told which ones the stencils read
        reg = image.region(a0, a1, b0, b1, need=need) if partial else image.region(a0, a1, b0, b1)
        res = fn(reg, yy[rows] - a0, xx[rows] - b0)
        for o, r in zip(outs, res if n_out > 1 else (res,)):
            o[rows] = r
    outs = [o.reshape(shape) for o in outs]
    return tuple(outs) if n_out > 1 else outs[0]


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
    if _windowed(image):
        return _by_region(bilinear, image, line, sample, 0, 1, 1)
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


def _keys(t: Array) -> tuple[Array, Array, Array, Array]:
    """Keys (1981) cubic-convolution weights (a = -0.5) of the 4 taps at fractional offset ``t``."""
    t2 = t * t
    t3 = t2 * t
    return (-0.5 * t3 + t2 - 0.5 * t, 1.5 * t3 - 2.5 * t2 + 1.0, -1.5 * t3 + 2.0 * t2 + 0.5 * t,
            0.5 * t3 - 0.5 * t2)


def _dkeys(t: Array) -> tuple[Array, Array, Array, Array]:
    """Derivatives of :func:`_keys` with respect to ``t``, per pixel."""
    t2 = t * t
    return (-1.5 * t2 + 2.0 * t - 0.5, 4.5 * t2 - 5.0 * t, -4.5 * t2 + 4.0 * t + 0.5, 1.5 * t2 - t)


def _cubic_setup(image: NDArray, line: ArrayLike, sample: ArrayLike) -> tuple[
        Array, NDArray[np.intp], Array, Array, NDArray[np.bool_], int, tuple[int, ...] | None]:
    """Flat image, flat index of each 4 x 4 stencil's first tap, fractional offsets, inside mask, width, 0-d shape."""
    img = np.asarray(image, dtype=float)
    if img.ndim != 2:
        raise InvalidInputError(f"cubic resampling needs a 2-D image, got shape {img.shape}")
    y = np.asarray(line, dtype=float) - 0.5
    x = np.asarray(sample, dtype=float) - 0.5
    y, x = np.broadcast_arrays(y, x)
    # Scalars become (1,) and go back to 0-d in the caller (in-place masking needs arrays).
    shape = y.shape if y.ndim == 0 else None
    y, x = np.atleast_1d(y), np.atleast_1d(x)
    h, w = img.shape
    inside = (y >= 1.0) & (y <= h - 2) & (x >= 1.0) & (x <= w - 2)
    yc = np.where(inside, y, 1.0)
    xc = np.where(inside, x, 1.0)
    # Truncation equals floor here (yc, xc >= 1).
    i = np.minimum(yc.astype(np.intp), h - 3)
    j = np.minimum(xc.astype(np.intp), w - 3)
    flat, step = _flat(img)
    base = (i - 1) * step + (j - 1)
    return flat, base, yc - i, xc - j, inside, step, shape


def _flat(img: Array) -> tuple[Array, int]:
    """The pixels as one flat array and its step from one line to the next (elements).

    A view with contiguous lines (a window of a cached region or of an image in memory) is read in
    place, its lines ``step`` apart in the array it views: no copy of the region (issue 32, item 5).
    """
    h, w = img.shape
    s0, s1 = img.strides
    if img.flags.c_contiguous or h == 1 or s1 != img.itemsize or s0 % img.itemsize or s0 < w * img.itemsize:
        return img.ravel(), w
    step = s0 // img.itemsize
    flat = np.lib.stride_tricks.as_strided(img, shape=((h - 1) * step + w,), strides=(img.itemsize,),
                                           writeable=False)
    return flat, step


def bicubic(image: NDArray, line: ArrayLike, sample: ArrayLike) -> Array:
    """Cubic-convolution values at CSM coordinates (the values of :func:`bicubic_with_gradient`, alone).

    Parameters
    ----------
    image : ndarray (H, W)
        Pixel values, grey levels.
    line, sample : array_like
        Continuous pixel coordinates (CSM), broadcast together.

    Returns
    -------
    ndarray
        Grey levels; NaN outside ``[1.5, H - 1.5] x [1.5, W - 1.5]`` and next to NaN pixels.
    """
    if _windowed(image):
        return _by_region(bicubic, image, line, sample, 1, 2, 1)
    flat, base, fy, fx, inside, w, shape = _cubic_setup(image, line, sample)
    wx = _keys(fx)
    wy = _keys(fy)
    # Separable, one stencil row at a time: four gathers of (n,) arrays per row keep every
    # temporary the size of the output (a (n, 16) gather and its index array cost more than the sums).
    out = None
    for a in range(4):
        b = base + a * w if a else base
        row = flat[b] * wx[0]
        row += flat[b + 1] * wx[1]
        row += flat[b + 2] * wx[2]
        row += flat[b + 3] * wx[3]
        row *= wy[a]
        out = row if out is None else np.add(out, row, out=out)
    assert out is not None          # four stencil rows
    out[~inside] = np.nan
    return out.reshape(inside.shape if shape is None else shape)


def _cubic_grad_py(flat: Array, base: NDArray[np.intp], fy: Array, fx: Array, w: int, val: Array, d_line: Array,
                   d_sample: Array) -> None:
    """The loop of :func:`bicubic_with_gradient` per output value, with its arithmetic in the same order
    (:func:`_keys`, :func:`_dkeys`, four stencil rows summed left to right): the same values."""
    for n in range(base.size):
        tx = fx[n]
        tx2 = tx * tx
        tx3 = tx2 * tx
        wx0 = -0.5 * tx3 + tx2 - 0.5 * tx
        wx1 = 1.5 * tx3 - 2.5 * tx2 + 1.0
        wx2 = -1.5 * tx3 + 2.0 * tx2 + 0.5 * tx
        wx3 = 0.5 * tx3 - 0.5 * tx2
        dx0 = -1.5 * tx2 + 2.0 * tx - 0.5
        dx1 = 4.5 * tx2 - 5.0 * tx
        dx2 = -4.5 * tx2 + 4.0 * tx + 0.5
        dx3 = 1.5 * tx2 - tx
        ty = fy[n]
        ty2 = ty * ty
        ty3 = ty2 * ty
        wy = (-0.5 * ty3 + ty2 - 0.5 * ty, 1.5 * ty3 - 2.5 * ty2 + 1.0, -1.5 * ty3 + 2.0 * ty2 + 0.5 * ty,
              0.5 * ty3 - 0.5 * ty2)
        dy = (-1.5 * ty2 + 2.0 * ty - 0.5, 4.5 * ty2 - 5.0 * ty, -4.5 * ty2 + 4.0 * ty + 0.5, 1.5 * ty2 - ty)
        v = 0.0
        gl = 0.0
        gs = 0.0
        for a in range(4):
            b = base[n] + a * w
            v0, v1, v2, v3 = flat[b], flat[b + 1], flat[b + 2], flat[b + 3]
            row = v0 * wx0 + v1 * wx1 + v2 * wx2 + v3 * wx3
            drow = v0 * dx0 + v1 * dx1 + v2 * dx2 + v3 * dx3
            if a == 0:
                v, gl, gs = row * wy[0], row * dy[0], drow * wy[0]
            else:
                v += row * wy[a]
                gl += row * dy[a]
                gs += drow * wy[a]
        val[n] = v
        d_line[n] = gl
        d_sample[n] = gs


_cubic_grad_kernel: Any = numba.njit(cache=True, nogil=True)(_cubic_grad_py) if numba is not None else None


def bicubic_with_gradient(image: NDArray, line: ArrayLike, sample: ArrayLike) -> tuple[Array, Array, Array]:
    """Cubic-convolution values and their exact line and sample derivatives at CSM coordinates.

    The interpolant is C1-continuous, so Gauss-Newton iterations on it (least-
    squares matching) converge smoothly, and its derivatives are those of the
    very surface being fitted. NaN outside ``[1.5, H - 1.5] x [1.5, W - 1.5]``
    (all 16 taps must exist) and next to NaN pixels.

    Parameters
    ----------
    image : ndarray (H, W)
        Pixel values, grey levels.
    line, sample : array_like
        Continuous pixel coordinates (CSM), broadcast together.

    Returns
    -------
    value, d_line, d_sample : ndarray
        Grey levels and grey levels per pixel.
    """
    if _windowed(image):
        return _by_region(bicubic_with_gradient, image, line, sample, 1, 2, 3)
    flat, base, fy, fx, inside, w, shape = _cubic_setup(image, line, sample)
    if _cubic_grad_kernel is not None:
        out = [np.empty(base.shape) for _ in range(3)]
        _cubic_grad_kernel(flat, base.ravel(), fy.ravel(), fx.ravel(), w, *(o.reshape(-1) for o in out))
        for o in out:
            o[~inside] = np.nan
        if shape is not None:
            return out[0].reshape(shape), out[1].reshape(shape), out[2].reshape(shape)
        return out[0], out[1], out[2]
    wx, dwx = _keys(fx), _dkeys(fx)
    wy, dwy = _keys(fy), _dkeys(fy)
    val = d_line = d_sample = None
    for a in range(4):
        b = base + a * w if a else base
        v0, v1, v2, v3 = flat[b], flat[b + 1], flat[b + 2], flat[b + 3]
        row = v0 * wx[0] + v1 * wx[1] + v2 * wx[2] + v3 * wx[3]
        drow = v0 * dwx[0] + v1 * dwx[1] + v2 * dwx[2] + v3 * dwx[3]
        if val is None or d_line is None or d_sample is None:      # the first row sets all three
            val, d_line, d_sample = row * wy[a], row * dwy[a], drow * wy[a]
        else:
            val += row * wy[a]
            d_line += row * dwy[a]
            d_sample += drow * wy[a]
    assert val is not None and d_line is not None and d_sample is not None     # four stencil rows
    bad = ~inside
    val[bad] = np.nan
    d_line[bad] = np.nan
    d_sample[bad] = np.nan
    if shape is not None:
        return val.reshape(shape), d_line.reshape(shape), d_sample.reshape(shape)
    return val, d_line, d_sample
