"""Normalised cross-correlation through an image pyramid, in the geometry predicted by the sensors.

Image 2 is resampled into image 1's geometry through the predicted local
affine map ``A`` before correlating (``x2 = p2 + A (u + v)`` for template
offset ``u`` and search offset ``v``, both in image-1 pixels), so large scale,
rotation and shear differences do not decorrelate the windows. The search
starts on the coarsest pyramid level that brings the search radius down to a
few pixels and is refined level by level with a +/-2 pixel search; the peak is
located to sub-pixel precision by a parabola through its neighbours.
Everything is vectorised over matches.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..errors import InvalidInputError
from . import ncc_compiled
from .resample import bilinear

try:  # optional: the shift loop of the correlation in one compiled pass
    import numba
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None

__all__ = ["NccResult", "ncc_match", "window_offsets"]

Array = NDArray[np.float64]
_BATCH = 512  # matches per vectorised block
#: Most search-window pixels per vectorised block: about ten float64 arrays of this many elements live at
#: once (the windows, their validity, three integral images, the correlations), so a block stays near
#: 300 MB however wide the search (a 256-px search on level 0 is 527^2 pixels per point: 64 points would
#: need 1.4 GB in one block).
_BATCH_PIXELS = 1 << 22


def window_offsets(half: int) -> tuple[Array, Array]:
    """Integer (line, sample) offsets of a ``(2 half + 1)^2`` window, each of shape (t, t)."""
    r = np.arange(-half, half + 1, dtype=float)
    return np.meshgrid(r, r, indexing="ij")


@dataclass
class NccResult:
    """Outcome of :func:`ncc_match`.

    Attributes
    ----------
    line, sample : ndarray (n,)
        Image-2 positions of the NCC peak, pixels (NaN where matching failed).
    correlation : ndarray (n,)
        Peak correlation coefficient on level 0 (NaN where failed).
    """

    line: Array
    sample: Array
    correlation: Array


def _cross_py(s0: Array, tm: Array) -> Array:
    """``cross[b, p, q] = sum_ij s0[b, p + i, q + j] tm[b, i, j]`` (compiled with numba when available)."""
    b_n, m, _ = s0.shape
    t = tm.shape[1]
    k = m - t + 1
    cross = np.zeros((b_n, k, k))
    for b in range(b_n):
        for p in range(k):
            for q in range(k):
                acc = 0.0
                for i in range(t):
                    for j in range(t):
                        acc += s0[b, p + i, q + j] * tm[b, i, j]
                cross[b, p, q] = acc
    return cross


_cross_kernel = numba.njit(cache=True)(_cross_py) if numba is not None else None


def _cross_numpy(s0: Array, tm: Array) -> Array:
    # the python loop over shifts costs more in call overhead than it computes (measured: 830,000
    # einsum calls, 36 % of a 12-s tie-point run of 4 images)
    cross = (_cross_kernel(np.ascontiguousarray(s0), np.ascontiguousarray(tm)) if _cross_kernel is not None
             else _cross_numpy(s0, tm))
    return cross


def _ncc_surface(tmpl: Array, search: Array) -> Array:
    """Correlation of templates (b, t, t) at every shift inside search windows (b, m, m).

    Shifts whose window holds a NaN (outside the image, invalid pixels) get NaN.
    """
    t = tmpl.shape[-1]
    n = float(t * t)
    valid = np.isfinite(search)
    s0 = np.where(valid, search, 0.0)
    tm = tmpl - tmpl.mean(axis=(1, 2), keepdims=True)
    tn = np.sqrt(np.sum(tm * tm, axis=(1, 2)))
    # the python loop over shifts costs more in call overhead than it computes (measured: 830,000
    # einsum calls, 36 % of a 12-s tie-point run of 4 images)
    cross = (_cross_kernel(np.ascontiguousarray(s0), np.ascontiguousarray(tm)) if _cross_kernel is not None
             else _cross_numpy(s0, tm))

    def box(a: Array) -> Array:  # window sums from an integral image: O(1) per shift
        c = np.pad(a, ((0, 0), (1, 0), (1, 0))).cumsum(1).cumsum(2)
        return c[:, t:, t:] - c[:, :-t, t:] - c[:, t:, :-t] + c[:, :-t, :-t]

    s1 = box(s0)
    s2 = box(s0 * s0)
    count = box(valid.astype(float))
    var = np.maximum(s2 - s1 * s1 / n, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = cross / (tn[:, None, None] * np.sqrt(var))
    return np.where(np.isfinite(rho) & (count > n - 0.5), rho, np.nan)


def _peak(rho: Array) -> tuple[Array, Array, Array]:
    """Sub-pixel peak (offsets from the surface centre) and peak value, per surface (b, k, k)."""
    b, k, _ = rho.shape
    c = (k - 1) // 2
    filled = np.where(np.isnan(rho), -np.inf, rho)
    flat = filled.reshape(b, -1).argmax(axis=1)
    i, j = np.divmod(flat, k)
    idx = np.arange(b)
    best = rho[idx, i, j]

    def para(m: Array, z: Array, p: Array) -> Array:
        den = m - 2.0 * z + p
        with np.errstate(invalid="ignore", divide="ignore"):
            d = 0.5 * (m - p) / den
        return np.where(np.isfinite(d) & (den < 0) & (np.abs(d) <= 1.0), d, 0.0)

    inner_i = (i > 0) & (i < k - 1)
    inner_j = (j > 0) & (j < k - 1)
    ii, jj = np.clip(i, 1, k - 2), np.clip(j, 1, k - 2)
    di = np.where(inner_i, para(rho[idx, ii - 1, j], best, rho[idx, ii + 1, j]), 0.0)
    dj = np.where(inner_j, para(rho[idx, i, jj - 1], best, rho[idx, i, jj + 1]), 0.0)
    # A peak on the rim of the search area is not a peak: the true one lies outside.
    on_rim = ~(inner_i & inner_j)
    best = np.where(on_rim, np.nan, best)
    return i - c + di, j - c + dj, best


def ncc_match(pyr1: list[Array], pyr2: list[Array], line1: Array, sample1: Array, line2: Array,
              sample2: Array, affine: Array, half: int = 7, search: float = 16.0, refine: int = 2,
              top_radius: int = 4, coarse_min: float = 0.6, compiled: bool | None = None) -> NccResult:
    """Match points of image 1 into image 2 by pyramid NCC around predicted positions.

    Parameters
    ----------
    pyr1, pyr2 : list of ndarray
        Pyramids of both images (:func:`~lunarmap.matching.pyramid.build_pyramid`).
    line1, sample1 : ndarray (n,)
        Template centres in image 1, pixels (CSM).
    line2, sample2 : ndarray (n,)
        Predicted conjugates in image 2, pixels.
    affine : ndarray (n, 2, 2)
        Local affine maps image 1 -> image 2 (pixels per pixel).
    half : int
        Template half-size: windows are ``2 half + 1`` pixels square.
    search : float
        Search radius around the prediction, image-1 pixels on level 0.
    refine : int
        Search radius on the finer levels, pixels.
    top_radius : int
        Largest search radius wanted on the top level, pixels; fixes how many
        pyramid levels are used.
    coarse_min : float
        On levels above 0 a peak below this correlation is not trusted: the
        point keeps its estimate and searches a wider area on the next level.
    compiled : bool, optional
        Search windows and correlation surfaces by the compiled kernels of
        :mod:`~lunarmap.matching.ncc_compiled` (the same values to rounding); default: when numba is
        installed. ``False`` runs the vectorised numpy path.

    Returns
    -------
    NccResult
    """
    if half < 1 or search < 0 or refine < 1:
        raise InvalidInputError("half >= 1, search >= 0 and refine >= 1 are required")
    if compiled is None:
        compiled = ncc_compiled.AVAILABLE
    n = line1.size
    top = 0
    while search / 2 ** top > top_radius and top + 1 < min(len(pyr1), len(pyr2)):
        top += 1
    tl, ts = window_offsets(half)
    # Current estimate of the conjugate, image-2 level-0 pixels.
    cl = np.asarray(line2, dtype=float).copy()
    cs = np.asarray(sample2, dtype=float).copy()
    corr = np.full(n, np.nan)
    alive = np.isfinite(cl) & np.isfinite(cs) & np.all(np.isfinite(affine), axis=(1, 2))
    # Per-point search radius on the current level: points whose windows do not
    # fit on a coarse level (near image edges) or whose peak lies on the rim
    # skip that level and search a correspondingly wider area on the next.
    radius = np.full(n, int(np.ceil(search / 2 ** top)) + 1)
    for level in range(top, -1, -1):
        f = 2.0 ** level
        found = np.zeros(n, dtype=bool)
        for r in np.unique(radius[alive]):
            sel = np.flatnonzero(alive & (radius == r))
            ol, os_ = window_offsets(half + int(r))
            batch = max(1, min(_BATCH, _BATCH_PIXELS // ol.size))
            for b0 in range(0, sel.size, batch):
                act = sel[b0:b0 + batch]
                a = affine[act]
                if compiled:
                    # the templates by the same kernel, under the identity (the same values as bilinear's)
                    t = ncc_compiled.affine_windows(pyr1[level], line1[act] / f, sample1[act] / f,
                                                    np.broadcast_to(np.eye(2), (act.size, 2, 2)), half)
                    # issue 32: the same windows and surface, compiled (no m x m coordinate temporaries)
                    s = ncc_compiled.affine_windows(pyr2[level], cl[act] / f, cs[act] / f, a, half + int(r))
                    rho = ncc_compiled.ncc_surface(t, s)
                else:
                    t = bilinear(pyr1[level], line1[act, None, None] / f + tl, sample1[act, None, None] / f + ts)
                    # image-2 positions of the search window, laid out in image-1 geometry
                    gl = cl[act, None, None] / f + a[:, 0, 0, None, None] * ol + a[:, 0, 1, None, None] * os_
                    gs = cs[act, None, None] / f + a[:, 1, 0, None, None] * ol + a[:, 1, 1, None, None] * os_
                    s = bilinear(pyr2[level], gl, gs)
                    rho = _ncc_surface(t, s)
                vl, vs, best = _peak(rho)
                ok = np.isfinite(best) & ((level == 0) | (best >= coarse_min))
                # Shift found in image-1 pixels of this level -> image-2 level-0 pixels.
                cl[act[ok]] += f * (a[ok, 0, 0] * vl[ok] + a[ok, 0, 1] * vs[ok])
                cs[act[ok]] += f * (a[ok, 1, 0] * vl[ok] + a[ok, 1, 1] * vs[ok])
                found[act[ok]] = True
                corr[act] = best
        if level == 0:
            alive &= found
        else:
            radius = np.where(found, refine, 2 * radius + 1)
    corr[~alive] = np.nan
    return NccResult(line=np.where(alive, cl, np.nan), sample=np.where(alive, cs, np.nan), correlation=corr)
