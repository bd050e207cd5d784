"""Least-squares matching with 6 affine and 2 radiometric parameters, vectorised over matches.

The model is Eq. (14) of the LROC multi-image study (seeds/001):

    g1(x, y) + n1(x, y) = h0 + h1 g2(a0 + a1 x + a2 y, b0 + b1 x + b2 y) + n2(x, y)

with ``(x, y)`` = (line, sample) offsets of the template pixel from the
template centre in image 1, ``(a0, b0)`` the conjugate of the centre in image
2 (line, sample), ``a1, a2, b1, b2`` the local affine geometry and
``h0, h1`` the radiometric offset and gain. It is solved by Gauss-Newton;
each iteration samples ``g2`` and its exact derivatives by cubic convolution
(a C1 interpolant, so the iteration does not bounce on the kinks of bilinear
interpolation at pixel edges and the gradients belong to the fitted surface),
forms every match's 8 x 8 normal equations with one batched matrix product and
solves them all with one batched ``numpy.linalg.solve``. Matches leave the
batch as soon as their shift update is below ``tol``.

Precision: ``sigma0^2 = v'v / (n - 8)`` and ``C = sigma0^2 N^-1``; the standard
deviations of ``a0`` and ``b0`` are those of the matched position. ``v`` and
``N`` are those of the last iteration, i.e. less than ``tol`` pixels from the
solution.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..errors import InvalidInputError
from .ncc import window_offsets
from .resample import bicubic_with_gradient, bilinear

__all__ = ["LsmResult", "lsm_match"]

Array = NDArray[np.float64]
# Matches per vectorised block: 128 x 225 float64 temporaries (230 kB) stay in the L2 cache. Blocks of
# 2048 spilled to memory: the cubic resampler ran 3x and the whole LSM 1.3-2x slower per match,
# although they call numpy 16x less often.
_BATCH = 128


@dataclass
class LsmResult:
    """Outcome of :func:`lsm_match` (NaN in every field where matching failed).

    Attributes
    ----------
    line, sample : ndarray (n,)
        Matched image-2 position of the template centre, pixels.
    sigma_line, sigma_sample : ndarray (n,)
        Their standard deviations, pixels.
    correlation : ndarray (n,)
        Correlation coefficient of the template and the resampled window.
    params : ndarray (n, 8)
        ``a0, a1, a2, b0, b1, b2, h0, h1``.
    iterations : ndarray (n,)
        Gauss-Newton iterations used.
    converged : ndarray (n,) of bool
    """

    line: Array
    sample: Array
    sigma_line: Array
    sigma_sample: Array
    correlation: Array
    params: Array
    iterations: NDArray[np.int64]
    converged: NDArray[np.bool_]


def lsm_match(image1: NDArray, image2: NDArray, line1: Array, sample1: Array, line2: Array, sample2: Array,
              affine: Array, half: int = 7, max_iter: int = 20, tol: float = 1e-3,
              max_shift: float = 3.0) -> LsmResult:
    """Refine conjugates by least-squares matching (Eq. 14 of seeds/001).

    Parameters
    ----------
    image1 : ndarray (H1, W1)
        Image 1, grey levels (NaN invalid).
    image2 : ndarray (H2, W2)
        Image 2, grey levels (NaN invalid).
    line1, sample1 : ndarray (n,)
        Template centres in image 1, pixels (CSM).
    line2, sample2 : ndarray (n,)
        Initial conjugates in image 2 (e.g. from NCC), pixels.
    affine : ndarray (n, 2, 2)
        Initial affine parameters ``[[a1, a2], [b1, b2]]`` (from the sensor models).
    half : int
        Window half-size (window ``2 half + 1`` pixels square).
    max_iter : int
        Gauss-Newton iteration limit.
    tol : float
        Convergence: shift update below ``tol`` pixels.
    max_shift : float
        Matches that drift further than this from their start (pixels) fail.

    Returns
    -------
    LsmResult
    """
    if half < 2:
        raise InvalidInputError(f"LSM needs a window half-size >= 2 (got {half})")
    # Convert once: the resamplers would otherwise copy a float32 image on every call.
    image1 = np.ascontiguousarray(image1, dtype=float)
    image2 = np.ascontiguousarray(image2, dtype=float)
    line1, sample1, line2, sample2 = (np.asarray(x, dtype=float).ravel() for x in (line1, sample1, line2, sample2))
    n = line1.size
    affine = np.asarray(affine, dtype=float).reshape(n, 2, 2)
    out = LsmResult(*(np.full(n, np.nan) for _ in range(5)), params=np.full((n, 8), np.nan),
                    iterations=np.zeros(n, dtype=np.int64), converged=np.zeros(n, dtype=bool))
    for b0 in range(0, n, _BATCH):
        sl = slice(b0, min(b0 + _BATCH, n))
        _lsm_batch(image1, image2, line1[sl], sample1[sl], line2[sl], sample2[sl], affine[sl], half, max_iter, tol,
                   max_shift, out, sl)
    return out


def _jacobian(hdl: Array, hds: Array, g2: Array, u: Array, w: Array) -> Array:
    """Columns of Eq. (14) linearised: d/d(a0, a1, a2, b0, b1, b2, h0, h1), filled in place."""
    jac = np.empty(g2.shape + (8,))
    jac[..., 0] = hdl
    np.multiply(hdl, u, out=jac[..., 1])
    np.multiply(hdl, w, out=jac[..., 2])
    jac[..., 3] = hds
    np.multiply(hds, u, out=jac[..., 4])
    np.multiply(hds, w, out=jac[..., 5])
    jac[..., 6] = 1.0
    jac[..., 7] = g2
    return jac


def _lsm_batch(image1: NDArray, image2: Array, l1: Array, s1: Array, l2: Array, s2: Array, aff: Array,
               half: int, max_iter: int, tol: float, max_shift: float, out: LsmResult,
               idx: slice) -> None:
    u, w = window_offsets(half)
    u = u.ravel()
    w = w.ravel()
    npx = u.size
    b = l1.size
    # Forward-additive Gauss-Newton on Eq. (14) itself. An inverse-compositional variant (template
    # Jacobian and Hessian formed once, image 2 resampled without gradients) was tried: each
    # iteration cost half as much, but with noisy templates it converged only linearly (9
    # iterations on average instead of 5.3, a fifth of the matches unconverged after 20).
    g1 = bilinear(image1, l1[:, None] + u, s1[:, None] + w)  # (b, npx)
    p = np.zeros((b, 8))
    p[:, 0], p[:, 1], p[:, 2] = l2, aff[:, 0, 0], aff[:, 0, 1]
    p[:, 3], p[:, 4], p[:, 5] = s2, aff[:, 1, 0], aff[:, 1, 1]
    p[:, 6], p[:, 7] = 0.0, 1.0
    start = p[:, [0, 3]].copy()
    active = np.all(np.isfinite(g1), axis=1) & np.all(np.isfinite(p), axis=1)
    ok = np.zeros(b, dtype=bool)
    iters = np.zeros(b, dtype=np.int64)
    sig_l = np.full(b, np.nan)
    sig_s = np.full(b, np.nan)
    rho = np.full(b, np.nan)
    for _ in range(max_iter):
        a = np.flatnonzero(active)
        if a.size == 0:
            break
        pa = p[a]
        gl2 = pa[:, 0:1] + pa[:, 1:2] * u + pa[:, 2:3] * w
        gs2 = pa[:, 3:4] + pa[:, 4:5] * u + pa[:, 5:6] * w
        g2, dl, ds = bicubic_with_gradient(image2, gl2, gs2)  # (k, npx) each
        bad = ~np.all(np.isfinite(g2), axis=1)
        h0, h1 = pa[:, 6:7], pa[:, 7:8]
        r = g1[a] - (h0 + h1 * g2)
        jac = _jacobian(h1 * dl, h1 * ds, g2, u, w)  # (k, npx, 8)
        jac[bad] = 0.0
        r[bad] = 0.0
        jt = jac.transpose(0, 2, 1)
        nmat = jt @ jac  # batched GEMM: much faster than einsum for (k, 8, npx) x (k, npx, 8)
        rhs = (jt @ r[..., None])[..., 0]
        # Guard singular systems (flat windows): they are dropped below.
        cond_ok = np.linalg.det(nmat) > 0
        nmat[~cond_ok] = np.eye(8)
        dp = np.linalg.solve(nmat, rhs[..., None])[..., 0]
        p[a] = pa + dp
        iters[a] += 1
        step = np.hypot(dp[:, 0], dp[:, 3])
        drift = np.hypot(p[a, 0] - start[a, 0], p[a, 3] - start[a, 1])
        fail = bad | ~cond_ok | ~np.isfinite(step) | (drift > max_shift)
        done = (step < tol) & ~fail
        active[a[fail | done]] = False
        if done.any():
            # Precision and correlation of the converged matches from this iteration's normals
            # and residuals: they were evaluated less than ``tol`` pixels from the solution, and
            # reusing them saves a whole resampling pass per match.
            d = np.flatnonzero(done)
            k = a[d]
            s0sq = np.sum(r[d] * r[d], axis=1) / (npx - 8)
            with np.errstate(invalid="ignore"):
                cov = np.linalg.inv(nmat[d]) * s0sq[:, None, None]
                sig_l[k] = np.sqrt(cov[:, 0, 0])
                sig_s[k] = np.sqrt(cov[:, 3, 3])
                c1 = g1[k] - g1[k].mean(axis=1, keepdims=True)
                c2 = g2[d] - g2[d].mean(axis=1, keepdims=True)
                rho[k] = np.sum(c1 * c2, axis=1) / np.sqrt(np.sum(c1 * c1, axis=1) * np.sum(c2 * c2, axis=1))
            ok[k] = np.isfinite(sig_l[k]) & np.isfinite(rho[k])
    out.line[idx] = np.where(ok, p[:, 0], np.nan)
    out.sample[idx] = np.where(ok, p[:, 3], np.nan)
    out.sigma_line[idx] = np.where(ok, sig_l, np.nan)
    out.sigma_sample[idx] = np.where(ok, sig_s, np.nan)
    out.correlation[idx] = np.where(ok, rho, np.nan)
    out.params[idx] = np.where(ok[:, None], p, np.nan)
    out.iterations[idx] = iters
    out.converged[idx] = ok
