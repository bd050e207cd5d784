"""Compiled kernels of the pyramid NCC search (numba): search windows resampled in image-1 geometry and
the correlation surface, without the large temporaries of the vectorised numpy path.

Issue 32: on the example's pairs the NCC search was 81 % of matching a pair, split between bilinear
resampling of the search windows through numpy temporaries (41 %) and the correlation surface (37 %:
direct cross products and integral images by ``cumsum``). Here

* :func:`affine_windows` samples the ``m x m`` search window of every point straight from the image
  (region) by bilinear interpolation, with the same arithmetic as
  :func:`~lunarmap.matching.resample.bilinear` on the coordinates ``ncc_match`` forms;
* :func:`ncc_surface` forms the window sums by integral images per point (values offset by the window's
  mean, which leaves the correlation unchanged and the variance better conditioned) and the cross
  products either directly, only at shifts whose window is wholly valid (the others are NaN anyway),
  or by FFT (:func:`scipy.fft.rfft2`) for large windows, where it is cheaper; both only over the bounding
  box of the window's valid pixels (issue 32, item 5: a wide search on a coarse level of the example
  reaches past the image, about half of every such window is NaN, and the FFT of the whole padded window
  was the largest single cost of matching a pair).

Results equal those of the numpy path to rounding (~1e-12 in the correlation).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy import fft as sp_fft

try:  # optional: without numba, ncc_match keeps its numpy path
    import numba
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None

__all__ = ["AVAILABLE", "affine_windows", "ncc_surface"]

Array = NDArray[np.float64]
AVAILABLE = numba is not None
#: Cost per multiply-add of the direct cross products and per ``n log2 n`` unit of one FFT of ``n`` points
#: (seconds; measured on wholly valid windows and a 15 x 15 template: 0.61 ms direct against 0.23 ms by FFT
#: per 93-px window, the FFT 0.4x as fast at 19 px and 1.7x faster at 33 px). Only their ratio matters:
#: a batch goes by FFT when its direct products (on the valid pixels' share of the shifts) would cost more.
DIRECT_COST, FFT_COST = 0.44e-9, 0.64e-9


def _affine_bilinear_py(img: Array, cl: Array, cs: Array, a: Array, r: int, y_off: float, x_off: float,
                        out: Array) -> None:
    """``out[b, p, q]`` = bilinear value of ``img`` at line ``cl[b] + a00 u + a01 v``, sample
    ``cs[b] + a10 u + a11 v`` (``u = p - r``, ``v = q - r``), shifted by ``y_off``, ``x_off`` (the region's
    origin plus the CSM half pixel); NaN outside the pixel-centre hull, as ``resample.bilinear``."""
    h, w = img.shape
    m = 2 * r + 1
    for b in range(cl.shape[0]):
        a00, a01, a10, a11 = a[b, 0, 0], a[b, 0, 1], a[b, 1, 0], a[b, 1, 1]
        for p in range(m):
            u = float(p - r)
            for q in range(m):
                v = float(q - r)
                y = ((cl[b] + a00 * u) + a01 * v) - y_off
                x = ((cs[b] + a10 * u) + a11 * v) - x_off
                if not (y >= 0.0 and y <= h - 1 and x >= 0.0 and x <= w - 1):
                    out[b, p, q] = np.nan
                    continue
                i = min(int(y), h - 2)
                j = min(int(x), w - 2)
                fy = y - i
                fx = x - j
                out[b, p, q] = ((1.0 - fy) * ((1.0 - fx) * img[i, j] + fx * img[i, j + 1])
                                + fy * ((1.0 - fx) * img[i + 1, j] + fx * img[i + 1, j + 1]))


def _surface_py(tm: Array, tn: Array, search: Array, mean: Array, cross: Array, have_cross: NDArray[np.bool_],
                rho: Array) -> None:
    """Correlation surface of mean-free templates ``tm`` (b, t, t) (norms ``tn``) in windows ``search``
    (b, m, m, NaN invalid) whose valid pixels' mean is ``mean`` (:func:`_boxes_py`); ``cross[b]`` the cross
    products of the windows with ``have_cross[b]`` (the others' are computed here, directly)."""
    bn, m, _ = search.shape
    t = tm.shape[1]
    k = m - t + 1
    n = float(t * t)
    s1 = np.zeros((m + 1, m + 1))
    s2 = np.zeros((m + 1, m + 1))
    cnt = np.zeros((m + 1, m + 1), dtype=np.int64)
    for b in range(bn):
        # offset: the mean of the valid pixels (correlation unchanged, variance without cancellation)
        c = mean[b]
        for i in range(m):
            r1 = 0.0
            r2 = 0.0
            rc = 0
            for j in range(m):
                g = search[b, i, j]
                if np.isfinite(g):
                    g -= c
                    r1 += g
                    r2 += g * g
                    rc += 1
                s1[i + 1, j + 1] = s1[i, j + 1] + r1
                s2[i + 1, j + 1] = s2[i, j + 1] + r2
                cnt[i + 1, j + 1] = cnt[i, j + 1] + rc
        full = t * t
        for p in range(k):
            for q in range(k):
                nn = cnt[p + t, q + t] - cnt[p, q + t] - cnt[p + t, q] + cnt[p, q]
                if nn != full:
                    rho[b, p, q] = np.nan
                    continue
                a1 = s1[p + t, q + t] - s1[p, q + t] - s1[p + t, q] + s1[p, q]
                a2 = s2[p + t, q + t] - s2[p, q + t] - s2[p + t, q] + s2[p, q]
                var = max(a2 - a1 * a1 / n, 0.0)
                if have_cross[b]:
                    x = cross[b, p, q]
                else:
                    x = 0.0
                    for i in range(t):
                        for j in range(t):
                            x += search[b, p + i, q + j] * tm[b, i, j]
                den = tn[b] * np.sqrt(var)
                val = x / den if den > 0.0 else np.nan
                rho[b, p, q] = val if np.isfinite(val) else np.nan


def _boxes_py(search: Array, box: NDArray[np.int64], mean: Array) -> None:
    """Per window ``b``: the bounding box ``box[b] = (l0, l1, s0, s1)`` of its valid (finite) pixels (all 0
    when there are none) and their mean ``mean[b]`` (0 when none)."""
    bn, m, _ = search.shape
    for b in range(bn):
        l0 = m
        l1 = -1
        s0 = m
        s1 = -1
        tot = 0.0
        nv = 0
        for i in range(m):
            for j in range(m):
                g = search[b, i, j]
                if np.isfinite(g):
                    tot += g
                    nv += 1
                    l0 = min(l0, i)
                    l1 = max(l1, i)
                    s0 = min(s0, j)
                    s1 = max(s1, j)
        if nv:
            box[b, 0], box[b, 1], box[b, 2], box[b, 3] = l0, l1 + 1, s0, s1 + 1
            mean[b] = tot / nv
        else:
            box[b, 0] = box[b, 1] = box[b, 2] = box[b, 3] = 0
            mean[b] = 0.0


def _crop_py(search: Array, rows: NDArray[np.intp], box: NDArray[np.int64], mean: Array, out: Array) -> None:
    """``out[g, :h, :w]`` = window ``rows[g]``'s valid box less its mean, invalid pixels 0 (the rest of
    ``out``, zero padding, is left as it is)."""
    for g in range(rows.size):
        b = rows[g]
        l0, l1, s0, s1 = box[b, 0], box[b, 1], box[b, 2], box[b, 3]
        c = mean[b]
        for i in range(l1 - l0):
            for j in range(s1 - s0):
                v = search[b, l0 + i, s0 + j]
                out[g, i, j] = v - c if np.isfinite(v) else 0.0


def _place_py(corr: Array, rows: NDArray[np.intp], box: NDArray[np.int64], t: int, cross: Array) -> None:
    """``cross[rows[g]]`` at the shifts of its valid box from the box's correlation ``corr[g]``."""
    for g in range(rows.size):
        b = rows[g]
        l0, l1, s0, s1 = box[b, 0], box[b, 1], box[b, 2], box[b, 3]
        for i in range(l1 - l0 - t + 1):
            for j in range(s1 - s0 - t + 1):
                cross[b, l0 + i, s0 + j] = corr[g, i, j]


if numba is not None:
    _affine_kernel: Any = numba.njit(cache=True, nogil=True)(_affine_bilinear_py)
    _surface_kernel: Any = numba.njit(cache=True, nogil=True)(_surface_py)
    _boxes_kernel: Any = numba.njit(cache=True, nogil=True)(_boxes_py)
    _crop_kernel: Any = numba.njit(cache=True, nogil=True)(_crop_py)
    _place_kernel: Any = numba.njit(cache=True, nogil=True)(_place_py)
else:  # pragma: no cover - without numba
    _affine_kernel = _surface_kernel = _boxes_kernel = _crop_kernel = _place_kernel = None


def affine_windows(image: Any, cl: Array, cs: Array, a: Array, r: int) -> Array:
    """Search windows (b, m, m), ``m = 2 r + 1``: bilinear values of ``image`` (array or windowed image) at
    ``(cl, cs) + A (u, v)`` for integer offsets ``u, v`` in ``[-r, r]`` (CSM, this level's pixels).

    A windowed image is read in the regions holding each group of windows (the extremes of an affine
    map over a square lie on its corners; one pixel more on every side against rounding).
    """
    from .resample import _windowed
    from .windowed import region_groups

    b = cl.size
    m = 2 * r + 1
    cl = np.ascontiguousarray(cl, dtype=float)
    cs = np.ascontiguousarray(cs, dtype=float)
    a = np.ascontiguousarray(a, dtype=float)
    out = np.full((b, m, m), np.nan)
    if not _windowed(image):
        _affine_kernel(np.ascontiguousarray(image, dtype=float), cl, cs, a, r, 0.5, 0.5, out)
        return out
    u = np.array([-r, -r, r, r], dtype=float)
    v = np.array([-r, r, -r, r], dtype=float)
    yl = cl[:, None] + a[:, 0, 0, None] * u + a[:, 0, 1, None] * v
    xs = cs[:, None] + a[:, 1, 0, None] * u + a[:, 1, 1, None] * v
    for rows, (a0, a1, b0, b1) in region_groups(yl - 0.5, xs - 0.5, image.shape, 1, 2):
        reg = np.ascontiguousarray(image.region(a0, a1, b0, b1), dtype=float)
        sub = np.empty((rows.size, m, m))
        _affine_kernel(reg, cl[rows], cs[rows], a[rows], r, a0 + 0.5, b0 + 0.5, sub)
        out[rows] = sub
    return out


def _fast_lengths(n: NDArray[np.int64], real: bool) -> NDArray[np.int64]:
    """:func:`scipy.fft.next_fast_len` of every element (once per distinct length)."""
    vals, inv = np.unique(n, return_inverse=True)
    return np.array([sp_fft.next_fast_len(int(v), real=real) for v in vals], dtype=np.int64)[inv.ravel()]


def ncc_surface(tmpl: Array, search: Array) -> Array:
    """Correlation of templates (b, t, t) at every shift inside search windows (b, m, m); NaN at shifts
    whose window holds a NaN (as ``ncc._ncc_surface``).

    Only shifts whose template window is wholly valid have a value, and they all lie in the bounding box
    of the window's valid pixels: the cross products are formed over that box alone, directly or (for
    large boxes, where it is cheaper) by FFT of the box, windows with boxes of the same FFT shape in
    one batch. Search windows that reach past the image edge (on the example's coarse levels about
    half of a wide search window) then cost only their valid part.
    """
    bn, m, _ = search.shape
    t = tmpl.shape[-1]
    k = m - t + 1
    tm = tmpl - tmpl.mean(axis=(1, 2), keepdims=True)
    tn = np.sqrt(np.sum(tm * tm, axis=(1, 2)))
    tm = np.ascontiguousarray(tm)
    search = np.ascontiguousarray(search, dtype=float)
    rho = np.empty((bn, k, k))
    box = np.zeros((bn, 4), dtype=np.int64)
    mean = np.zeros(bn)
    _boxes_kernel(search, box, mean)
    bh, bw = box[:, 1] - box[:, 0], box[:, 3] - box[:, 2]
    kh, kw = np.maximum(bh - t + 1, 0), np.maximum(bw - t + 1, 0)
    fits = (kh > 0) & (kw > 0)
    fh, fw = _fast_lengths(np.where(fits, bh, 1), False), _fast_lengths(np.where(fits, bw, 1), True)
    # direct products at most at every shift of the box; the FFT's three transforms of the padded box
    direct = DIRECT_COST * (kh * kw * t * t)
    by_fft = fits & (direct > FFT_COST * 3.0 * fh * fw * np.log2(np.maximum(fh * fw, 2)))
    cross = np.zeros((bn, k, k)) if by_fft.any() else np.empty((1, 1, 1))
    for h, w in sorted(set(zip(fh[by_fft].tolist(), fw[by_fft].tolist()))):
        rows = np.flatnonzero(by_fft & (fh == h) & (fw == w))
        # a constant offset of the valid pixels leaves a mean-free template's cross products unchanged
        # wherever the window is wholly valid (the only shifts kept): the FFT then rounds less
        s0 = np.zeros((rows.size, h, w))
        _crop_kernel(search, rows, box, mean, s0)
        f = sp_fft.rfft2(s0, axes=(1, 2))
        # the template's transform in two passes: its t rows first, then the padded columns (a third of
        # the work of one 2-D transform of the zero-padded template)
        g = sp_fft.fft(sp_fft.rfft(tm[rows], n=w, axis=2), n=h, axis=1)
        f *= np.conj(g)
        corr = sp_fft.irfft2(f, s=(h, w), axes=(1, 2))
        _place_kernel(corr, rows, box, t, cross)
    _surface_kernel(tm, tn, search, mean, cross, by_fft, rho)
    return rho
