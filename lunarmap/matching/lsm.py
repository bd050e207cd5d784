"""Least-squares matching with 6 affine and 2 radiometric parameters, vectorised over matches.

The model is Eq. (14) of the LROC multi-image study (seeds/001):

    g1(x, y) + n1(x, y) = h0 + h1 g2(a0 + a1 x + a2 y, b0 + b1 x + b2 y) + n2(x, y)

with ``(x, y)`` = (line, sample) offsets of the template pixel from the
template centre in image 1, ``(a0, b0)`` the conjugate of the centre in image
2 (line, sample), ``a1, a2, b1, b2`` the local affine geometry and
``h0, h1`` the radiometric offset and gain.

Relief terms (issue 11). The affine map is exact only for a plane. Terrain that is not a
plane inside the window displaces image 2 along the epipolar line (the direction ``e`` in
which a height change moves a conjugate, known from the sensors) by its parallax, and an
affine fit then returns the conjugate of the window's average plane, not of its centre: on
simulated pairs the error along ``e`` grew to 0.21 px at 30 degrees convergence (0.04 px
across). Given ``epipolar``, the image-2 position carries a quadratic displacement along ``e``,
``e (q0 x^2 + q1 x y + q2 y^2)`` (3 more parameters, pixels per pixel^2), which the centre
does not see: 0.09 px at 30 degrees, at the price of more noise at small convergence. It is solved by Gauss-Newton;
each iteration samples ``g2`` and its exact derivatives by cubic convolution
(a C1 interpolant, so the iteration does not bounce on the kinks of bilinear
interpolation at pixel edges and the gradients belong to the fitted surface),
forms every match's 8 x 8 normal equations (with numba: accumulated in one compiled loop per
match, without the ``(k, npx, P)`` design matrix; else one batched matrix product) and
solves them all with one batched ``numpy.linalg.solve``. Matches leave the
batch as soon as their shift update is below ``tol``.

Both images are smoothed by a Gaussian of ``presmooth`` pixels first. Without it the
estimate locks onto sub-pixel positions: the cost contains the resampled noise of image 2,
whose variance under cubic convolution is lowest half-way between pixels (41 % of the
pixel noise at (0.5, 0.5)), so the minimum is pulled there -- on an unwarped texture with
noise sigma 3 the mean error was 0.11 px towards the half pixel and the scatter 4x the
reported sigma. Smoothed noise interpolates with nearly constant variance.

Precision (issue 11: calibrated so that error / sigma has unit RMS). The noise of both
smoothed images is correlated with the Gaussian autocorrelation
``kappa(d) = exp(-|d|^2 / (4 presmooth^2))`` (pixels ``d`` apart), so the residuals are not
white and ``sigma0^2 N^-1`` would be 2-3x too small. The covariance is the sandwich form for
correlated observations::

    M = J^T K J = sum_d kappa(d) sum_k J_k J_{k+d}^T,    C = s^2 N^-1 M N^-1,
    s^2 = v'v / (n - tr(N^-1 M))

(``K`` the correlation matrix of the window's pixels; ``E[v'v] = s^2 tr((I - H) K)`` gives
the degrees of freedom). ``presmooth = 0`` gives the classical ``v'v / (n - 8) N^-1``.
The standard deviations of ``a0`` and ``b0`` are those of the matched position. ``v`` and
``N`` are those of the last iteration, i.e. less than ``tol`` pixels from the solution.
This covers the image noise; a non-planar surface inside the window (relief parallax)
displaces the match along the epipolar line by a model error the fit cannot see.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter

from ..errors import InvalidInputError
from .ncc import window_offsets
from .resample import _windowed, bicubic_with_gradient, bilinear

try:  # optional: the normal equations in one compiled pass (issue 32, item 5)
    import numba
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None

__all__ = ["LsmResult", "lsm_match"]

Array = NDArray[np.float64]
# Matches per vectorised block: 128 x 225 float64 temporaries (230 kB) stay in the L2 cache. Blocks of
# 2048 spilled to memory: the cubic resampler ran 3x and the whole LSM 1.3-2x slower per match,
# although they call numpy 16x less often.
_BATCH = 128
#: default Gaussian pre-smoothing of both images (pixels), against sub-pixel locking
PRESMOOTH = 1.0
#: correlations below this are left out of the covariance's sum over pixel lags
_MIN_KAPPA = 0.01


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
    relief : ndarray (n, 3)
        ``q0, q1, q2`` of the relief terms, pixels per pixel^2 (0 without ``epipolar``).
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
    relief: Array | None = None


def lsm_match(image1: NDArray, image2: NDArray, line1: Array, sample1: Array, line2: Array, sample2: Array,
              affine: Array, half: int = 7, max_iter: int = 20, tol: float = 1e-3,
              max_shift: float = 3.0, presmooth: float = PRESMOOTH, epipolar: Array | None = None,
              compiled: bool | None = None) -> LsmResult:
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
    presmooth : float
        Standard deviation (pixels) of the Gaussian that smooths both images before matching
        (module docstring); 0 matches the raw pixels.
    epipolar : ndarray (n, 2), optional
        Image-2 displacement per unit of height (line, sample), e.g.
        :attr:`~lunarmap.matching.predict.Prediction.epipolar`: adds the relief terms along its
        direction (module docstring); rows of zeros get none.
    compiled : bool, optional
        Normal equations and residuals by the compiled kernel (:func:`_normals_py`; the same values to
        rounding, ~1e-13 px in the matches); default: when numba is installed. ``False`` builds them with
        numpy from the design matrix.

    Returns
    -------
    LsmResult
    """
    if half < 2:
        raise InvalidInputError(f"LSM needs a window half-size >= 2 (got {half})")
    if not (np.isfinite(presmooth) and presmooth >= 0.0):
        raise InvalidInputError(f"LSM presmooth must be a finite sigma >= 0 pixels (got {presmooth})")
    if compiled is None:
        compiled = _normals_kernel is not None
    elif compiled and _normals_kernel is None:
        raise InvalidInputError("compiled least-squares matching needs numba")
    image1, image2 = _prepared(image1, presmooth), _prepared(image2, presmooth)
    line1, sample1, line2, sample2 = (np.asarray(x, dtype=float).ravel() for x in (line1, sample1, line2, sample2))
    n = line1.size
    affine = np.asarray(affine, dtype=float).reshape(n, 2, 2)
    if epipolar is None:
        direction = None
    else:
        epipolar = np.asarray(epipolar, dtype=float).reshape(n, 2)
        norm = np.hypot(epipolar[:, 0], epipolar[:, 1])
        good = np.isfinite(norm) & (norm > 0.0)
        direction = np.where(good[:, None], epipolar / np.where(good, norm, 1.0)[:, None], 0.0)
    nan = [np.full(n, np.nan) for _ in range(5)]
    out = LsmResult(nan[0], nan[1], nan[2], nan[3], nan[4], params=np.full((n, 8), np.nan),
                    iterations=np.zeros(n, dtype=np.int64), converged=np.zeros(n, dtype=bool),
                    relief=np.full((n, 3), np.nan))
    for b0 in range(0, n, _BATCH):
        sl = slice(b0, min(b0 + _BATCH, n))
        _lsm_batch(image1, image2, line1[sl], sample1[sl], line2[sl], sample2[sl], affine[sl], half, max_iter, tol,
                   max_shift, presmooth, None if direction is None else direction[sl], out, sl, compiled)
    return out


def _prepared(image: Any, presmooth: float) -> Any:
    """An image as least-squares matching samples it: float64 (converted once: the resamplers would
    otherwise copy a float32 image on every call), smoothed by ``presmooth``. A windowed image
    (:mod:`.windowed`) smooths each region it reads with the filter's reach around it: the values of
    the smoothed whole image."""
    if _windowed(image):
        return image.smoothed(presmooth)
    image = np.ascontiguousarray(image, dtype=float)
    return _smooth(image, presmooth) if presmooth > 0.0 else image


def _smooth(image: Array, sigma: float) -> Array:
    """Gaussian smoothing that ignores NaN pixels (normalised convolution) and keeps them NaN.

    Invalid pixels do not spread: windows touching them fail exactly as without smoothing.
    """
    bad = ~np.isfinite(image)
    if not bad.any():
        return gaussian_filter(image, sigma, mode="nearest")
    valid = (~bad).astype(float)
    num = gaussian_filter(np.where(bad, 0.0, image), sigma, mode="nearest")
    den = gaussian_filter(valid, sigma, mode="nearest")
    with np.errstate(invalid="ignore", divide="ignore"):
        out = num / den
    out[bad] = np.nan
    return out


@functools.lru_cache(maxsize=8)
def _lag_matrix(t: int, presmooth: float) -> Array:
    """``K - I`` of a ``t x t`` window in row-major pixel order: ``kappa(d)`` between pixels ``d`` apart,
    0 on the diagonal and where ``kappa < _MIN_KAPPA`` or a lag reaches past ``reach`` pixels."""
    reach = min(int(np.ceil(presmooth * np.sqrt(-4.0 * np.log(_MIN_KAPPA)))), t - 1)
    li, si = np.divmod(np.arange(t * t), t)
    dl = li[:, None] - li[None, :]
    ds = si[:, None] - si[None, :]
    kap = np.exp(-(dl * dl + ds * ds) / (4.0 * presmooth * presmooth))
    kap[(kap < _MIN_KAPPA) | (np.abs(dl) > reach) | (np.abs(ds) > reach) | ((dl == 0) & (ds == 0))] = 0.0
    kap.setflags(write=False)
    return kap


def _covariance(jac: Array, r: Array, nmat: Array, t: int, presmooth: float, held: Array) -> Array:
    """Covariance ``(k, P, P)`` of the parameters of ``k`` converged matches (module docstring).

    ``jac (k, t*t, P)`` and ``r (k, t*t)`` are the window's Jacobian and residuals in row-major
    pixel order, ``nmat = J^T J`` (plus 1 on the diagonal of the ``held (k,)`` parameters that
    have zero columns: relief terms without an epipolar direction).
    """
    k, npx = r.shape
    P = jac.shape[2]
    ninv = np.linalg.inv(nmat)
    vv = np.sum(r * r, axis=1)
    if presmooth <= 0.0:
        return ninv * (vv / (npx - P + held))[:, None, None]
    # M = J^T K J: the lags' sum as one product with the window's pixel-correlation matrix (its diagonal,
    # lag 0, is nmat's); one batched GEMM instead of a pair of them per lag (issue 32)
    M = nmat + jac.transpose(0, 2, 1) @ (_lag_matrix(t, presmooth) @ jac)
    dof = npx - np.trace(ninv @ M, axis1=1, axis2=2) + held
    return (ninv @ M @ ninv) * (vv / dof)[:, None, None]


def _jacobian(hdl: Array, hds: Array, g2: Array, u: Array, w: Array, direction: Array | None) -> Array:
    """Columns of Eq. (14) linearised: d/d(a0, a1, a2, b0, b1, b2, h0, h1[, q0, q1, q2]), filled in place."""
    jac = np.empty(g2.shape + (8 if direction is None else 11,))
    jac[..., 0] = hdl
    np.multiply(hdl, u, out=jac[..., 1])
    np.multiply(hdl, w, out=jac[..., 2])
    jac[..., 3] = hds
    np.multiply(hds, u, out=jac[..., 4])
    np.multiply(hds, w, out=jac[..., 5])
    jac[..., 6] = 1.0
    jac[..., 7] = g2
    if direction is not None:
        je = hdl * direction[:, 0:1] + hds * direction[:, 1:2]   # gradient along the epipolar line
        np.multiply(je, u * u, out=jac[..., 8])
        np.multiply(je, u * w, out=jac[..., 9])
        np.multiply(je, w * w, out=jac[..., 10])
    return jac


def _normals_py(g1: Array, g2: Array, dl: Array, ds: Array, h0: Array, h1: Array, u: Array, w: Array,
                direction: Array, relief: bool, bad: NDArray[np.bool_], nmat: Array, rhs: Array, r: Array) -> None:
    """Normal equations ``nmat = J^T J``, ``rhs = J^T r`` and residuals ``r`` of ``k`` matches, one match at a
    time: its Jacobian (the columns of :func:`_jacobian`, the same products) in a ``(P, npx)`` scratch array
    that stays in the L1 cache, then every product as one dot over the window's pixels. No ``(k, npx, P)``
    design matrix or batched product: 5x faster than numpy for 128 matches of 15 x 15 pixels (the dots
    are vectorised, their sums reassociated: ~1e-16 relative). Matches with ``bad[b]`` (a NaN sample) get
    zeros, as the numpy path's zeroed rows give."""
    k, npx = g2.shape
    P = nmat.shape[1]
    jac = np.empty((P, npx))
    for b in range(k):
        if bad[b]:
            nmat[b] = 0.0
            rhs[b] = 0.0
            r[b] = 0.0
            continue
        gain = h1[b]
        off = h0[b]
        d0 = direction[b, 0]
        d1 = direction[b, 1]
        for i in range(npx):
            hl = gain * dl[b, i]
            hs = gain * ds[b, i]
            ui = u[i]
            wi = w[i]
            jac[0, i] = hl
            jac[1, i] = hl * ui
            jac[2, i] = hl * wi
            jac[3, i] = hs
            jac[4, i] = hs * ui
            jac[5, i] = hs * wi
            jac[6, i] = 1.0
            jac[7, i] = g2[b, i]
            if relief:
                je = hl * d0 + hs * d1
                jac[8, i] = je * (ui * ui)
                jac[9, i] = je * (ui * wi)
                jac[10, i] = je * (wi * wi)
            r[b, i] = g1[b, i] - (off + gain * g2[b, i])
        for p in range(P):
            acc = 0.0
            for i in range(npx):
                acc += jac[p, i] * r[b, i]
            rhs[b, p] = acc
            for q in range(p, P):
                acc = 0.0
                for i in range(npx):
                    acc += jac[p, i] * jac[q, i]
                nmat[b, p, q] = acc
                nmat[b, q, p] = acc


# reassociation lets the dots run in SIMD lanes (no NaN/inf assumptions: bad rows never reach them)
_normals_kernel: Any = (numba.njit(cache=True, nogil=True, fastmath={"reassoc", "contract"})(_normals_py)
                        if numba is not None else None)


def _lsm_batch(image1: NDArray, image2: Array, l1: Array, s1: Array, l2: Array, s2: Array, aff: Array,
               half: int, max_iter: int, tol: float, max_shift: float, presmooth: float,
               direction: Array | None, out: LsmResult, idx: slice, compiled: bool = False) -> None:
    u, w = window_offsets(half)
    u = u.ravel()
    w = w.ravel()
    b = l1.size
    # Forward-additive Gauss-Newton on Eq. (14) itself. An inverse-compositional variant (template
    # Jacobian and Hessian formed once, image 2 resampled without gradients) was tried: each
    # iteration cost half as much, but with noisy templates it converged only linearly (9
    # iterations on average instead of 5.3, a fifth of the matches unconverged after 20).
    if compiled:
        # the template by the NCC search's compiled kernel under the identity: bilinear's values (issue 32)
        from .ncc_compiled import affine_windows

        g1 = affine_windows(image1, l1, s1, np.broadcast_to(np.eye(2), (b, 2, 2)), half).reshape(b, -1)
    else:
        g1 = bilinear(image1, l1[:, None] + u, s1[:, None] + w)  # (b, npx)
    P = 8 if direction is None else 11
    # relief terms of matches without an epipolar direction have zero columns: held at 0 by a unit diagonal
    held = np.zeros(b) if direction is None else 3.0 * ~np.any(direction != 0.0, axis=1)
    p = np.zeros((b, P))
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
        if direction is not None:
            quad = pa[:, 8:9] * (u * u) + pa[:, 9:10] * (u * w) + pa[:, 10:11] * (w * w)
            gl2 = gl2 + direction[a, 0:1] * quad
            gs2 = gs2 + direction[a, 1:2] * quad
        g2, dl, ds = bicubic_with_gradient(image2, gl2, gs2)  # (k, npx) each
        bad = ~np.all(np.isfinite(g2), axis=1)
        h0, h1 = pa[:, 6:7], pa[:, 7:8]
        if compiled:
            nmat = np.empty((a.size, P, P))
            rhs = np.empty((a.size, P))
            r = np.empty(g2.shape)
            _normals_kernel(g1[a], g2, dl, ds, pa[:, 6], pa[:, 7], u, w,
                            direction[a] if direction is not None else np.zeros((a.size, 2)), direction is not None,
                            bad, nmat, rhs, r)
        else:
            r = g1[a] - (h0 + h1 * g2)
            jac = _jacobian(h1 * dl, h1 * ds, g2, u, w, None if direction is None else direction[a])  # (k, npx, P)
            jac[bad] = 0.0
            r[bad] = 0.0
            jt = jac.transpose(0, 2, 1)
            nmat = jt @ jac  # batched GEMM: much faster than einsum for (k, 8, npx) x (k, npx, 8)
            rhs = (jt @ r[..., None])[..., 0]
        if direction is not None and held[a].any():
            hz = held[a] > 0
            nmat[hz, 8:, 8:] += np.eye(3)
        # Guard singular systems (flat windows): they are dropped below.
        cond_ok = np.linalg.det(nmat) > 0
        nmat[~cond_ok] = np.eye(P)
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
            with np.errstate(invalid="ignore"):
                # the compiled path keeps no design matrix: the converged matches' rows formed again
                jd = (_jacobian(h1[d] * dl[d], h1[d] * ds[d], g2[d], u, w, None if direction is None else direction[k])
                      if compiled else jac[d])
                cov = _covariance(jd, r[d], nmat[d], 2 * half + 1, presmooth, held[k])
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
    out.params[idx] = np.where(ok[:, None], p[:, :8], np.nan)
    if out.relief is not None:
        out.relief[idx] = np.where(ok[:, None], p[:, 8:], np.nan) if P == 11 else np.where(ok[:, None], 0.0, np.nan)
    out.iterations[idx] = iters
    out.converged[idx] = ok
