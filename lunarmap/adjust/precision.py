"""Posterior precision of an adjusted block: covariances of images, points and extra parameters,
redundancy numbers of the image observations.

With the reduced camera system ``S = U - W V^-1 W^T`` at the solution (undamped) and
``Q_cc = S^-1``, the cofactor blocks follow from the Schur complement (the inverse of
the normal matrix of the DLR paper's Eq. 4, block-wise)::

    Q_pp,j    = V_j^-1 + sum_{a,b in track j} F_a^T Q_{c_a c_b} F_b,     F_i = W_i V_j^-1
    Q_c,j     = -sum_{b in track j} Q_{c c_b} F_b

and covariances are ``sigma0^2 Q``.  Only the blocks of ``Q_cc`` on the camera-pair pattern of
``S`` are needed (every pair of images sharing a point).  They are taken from ``S^-1`` computed
column-chunk by column-chunk with the sparse Cholesky factor of the Jacobi-scaled ``S``
(:mod:`.factor`; multi right-hand-side solves, never the dense ``n x n`` inverse in memory for
large blocks): for 2,000 images that is ~2 * nnz(L) * 12,000 * 2 flops, an order of magnitude
below a dense LAPACK ``potrf`` + ``potri`` of the 12,000 x 12,000 matrix.  Point covariances
and redundancy numbers are then one pass over the points (numba when installed).

Datum: a singular or numerically singular ``S`` (undefined datum, unobserved parameter) raises
:class:`~lunarmap.errors.DatumDefectError`: the factorisation fails, or a diagonal element of the
Jacobi-scaled inverse exceeds ``1e13`` (condition number beyond what double precision resolves).

Redundancy numbers (``r_i = 1 - (A Q A^T P)_ii``, for data snooping and variance-component
estimation) are computed per image coordinate with ``redundancy=True``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
from numpy.typing import NDArray

from ..errors import AdjustmentInputError, DatumDefectError
from .factor import Factorizer

try:
    import numba
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None

__all__ = ["Precision", "posterior_precision", "ordered_track_pairs", "reduced_inverse_blocks", "reduced_inverse",
           "ReducedInverse"]

#: largest diagonal element of the Jacobi-scaled inverse accepted as a defined datum
MAX_SCALED_VARIANCE = 1e13
#: smallest/largest eigenvalue ratio of a point's normal block below which the point is undetermined
#: (1e-10: rays within ~0.0006 degrees of parallel; its inverse block is then rounding noise)
UNDETERMINED_POINT_RATIO = 1e-10
#: reduced systems up to this size also keep the dense ``Q_red``
DENSE_Q_LIMIT = 1500


@dataclass
class Precision:
    """Posterior covariances (units of the parameters squared), scaled by ``sigma0**2``.

    Attributes
    ----------
    cam_cov : (n_img, p, p)
    pt_cov : (n_pt, 3, 3)  (zero for fixed points)
    extra_cov : (n_extra, n_extra)
    Q_red : (n_red, n_red) or None
        Dense cofactor matrix of the reduced unknowns (unscaled; zero rows for fixed ones), kept
        only up to ``DENSE_Q_LIMIT`` reduced unknowns.
    redundancy_numbers : (n_obs, 2) or None
    sigma0 : float
    method : str
    undetermined_points : (k,) int
        Points whose normal block is numerically singular (rays nearly parallel); their
        covariance is reported as ``inf`` and they do not constrain the images.
    control_redundancy : (k, 3) or None
        Redundancy numbers of the whitened coordinates of the weighted control points (in the
        order of ``priors.idx[~priors.fixed]``; for a full covariance, of the components of
        ``W (X - xyz)`` with ``W^T W = C^-1``).
    term_redundancy : list of (m_t,) or None
        Redundancy numbers of the whitened rows of every camera-level term (navigation
        observations and their offset/drift pseudo-observations), in the term's row order.
    cam_extra_cov : (n_img * p, n_extra) or None
        Covariances of image parameters with extra parameters (NaN where not computed).
    """

    cam_cov: NDArray
    pt_cov: NDArray
    extra_cov: NDArray
    Q_red: NDArray | None
    redundancy_numbers: NDArray | None
    sigma0: float
    method: str
    undetermined_points: NDArray = field(default_factory=lambda: np.zeros(0, np.int64))
    control_redundancy: NDArray | None = None
    term_redundancy: list | None = None
    cam_extra_cov: NDArray | None = None


def ordered_track_pairs(pt_idx: NDArray, n_pt: int, active=None):
    """All ordered observation pairs ``(a, b)`` of the same point (including ``a == b``)."""
    order = np.argsort(pt_idx, kind="stable")
    s = pt_idx[order]
    starts = np.searchsorted(s, np.arange(n_pt))
    track = np.bincount(pt_idx, minlength=n_pt)
    if active is not None:
        track = np.where(active, track, 0)
    pos = np.arange(pt_idx.size) - starts[s]
    k = track[s]
    A, B = [], []
    for d in range(-int(track.max(initial=1)) + 1, int(track.max(initial=1))):
        ok = (pos + d >= 0) & (pos + d < k)
        i = np.nonzero(ok)[0]
        A.append(order[i])
        B.append(order[i + d])
    return np.concatenate(A), np.concatenate(B)


@dataclass
class ReducedInverse:
    """Entries of ``Q = S^-1`` of the reduced unknowns (cofactors, unscaled; see :func:`reduced_inverse`).

    Attributes
    ----------
    Qblk : (n_blocks, p, p)
        Blocks of the camera pairs asked for.
    Qextra : (n_extra, n_extra)
        The extra parameters' block.
    Qce : (n_cam * p, n_extra)
        Image parameters x extra parameters; NaN where not computed (an image whose parameters
        are not coupled to the extras in ``S``: off the Cholesky pattern of the selected inversion).
    Q : (n_red, n_red) or None
        The dense ``Q`` (small systems only).
    method : str
    """

    Qblk: NDArray
    Qextra: NDArray
    Qce: NDArray
    Q: NDArray | None
    method: str


def reduced_inverse_blocks(S: sp.csr_matrix, free_red: NDArray, block_row: NDArray, block_col: NDArray, p: int,
                           n_cam: int, backend: str = "auto", chunk_columns: int = 1536,
                           keep_dense: bool | None = None, use_band: bool = True, method: str = "auto"):
    """``(Qblk, Qextra, Q)`` of :func:`reduced_inverse` (kept for callers of the tuple form)."""
    r = reduced_inverse(S, free_red, block_row, block_col, p, n_cam, backend, chunk_columns, keep_dense, use_band,
                        method)
    return r.Qblk, r.Qextra, r.Q


def reduced_inverse(S: sp.csr_matrix, free_red: NDArray, block_row: NDArray, block_col: NDArray, p: int,
                    n_cam: int, backend: str = "auto", chunk_columns: int = 1536,
                    keep_dense: bool | None = None, use_band: bool = True, method: str = "auto") -> ReducedInverse:
    """Blocks of ``Q = S^-1`` on a camera-pair pattern, the extra-parameter blocks and (small) the dense ``Q``.

    Parameters
    ----------
    S : (n_free, n_free) sparse
        Undamped reduced normal matrix of the free reduced unknowns.
    free_red : (n_red,) bool
        Which reduced unknowns (``n_cam * p`` image parameters, then extras) are free.
    block_row, block_col : (n_blocks,) int
        Camera-pair blocks wanted (``block_row <= block_col``).

    method : {"auto", "supernodal", "chunks", "dense"}
        ``"supernodal"`` (the default for systems too large for the dense ``Q``): Takahashi's
        selected inversion on a nested-dissection supernodal factor (:mod:`.selinv`), which costs
        about one factorisation. ``"chunks"``: columns of ``S^-1`` solved for in chunks with the
        sparse factor, after a band Cholesky with Takahashi's recursion of the camera blocks when
        the reverse Cuthill-McKee band is narrow (``use_band``) -- the method before issue 11,
        whose cost grows like ``n_cam * nnz(L)`` (kept for comparison). ``"dense"``: the whole
        inverse (also kept as ``Q``).

    Returns
    -------
    ReducedInverse

    Raises
    ------
    DatumDefectError
        ``S`` is singular or numerically singular.
    """
    n_red = free_red.size
    n_cam_red = n_cam * p
    d = S.diagonal()
    if not np.all(np.isfinite(d)) or np.any(d <= 0):
        bad = int(np.nonzero(~(d > 0))[0][0]) if np.any(~(d > 0)) else -1
        raise DatumDefectError(f"free reduced unknown {bad} has no weight in the normal equations (unobserved)")
    s = 1.0 / np.sqrt(d)
    # Jacobi scaling: unit diagonal, so the datum test below is independent of units (radians vs metres)
    Ss = sp.csr_matrix(S.multiply(s[:, None]).multiply(s[None, :]))
    fi = np.nonzero(free_red)[0]
    pos = np.full(n_red, -1)
    pos[fi] = np.arange(fi.size)
    if keep_dense is None:
        keep_dense = n_red <= DENSE_Q_LIMIT and method in ("auto", "dense")
    if method == "auto":
        method = "dense" if keep_dense else "supernodal"
    if method not in ("supernodal", "chunks", "dense"):
        raise ValueError(f"unknown reduced-inverse method {method!r}")
    n_extra = n_red - n_cam_red
    if method == "supernodal":
        return _supernodal_inverse(Ss, s, free_red, pos, block_row, block_col, p, n_cam)
    keep_dense = keep_dense or method == "dense"
    solve = Factorizer(backend)(Ss)
    Q = np.zeros((n_red, n_red)) if keep_dense else None
    Qblk = np.zeros((block_row.size, p, p))
    Qextra = np.zeros((n_extra, n_extra))
    Qce = np.full((n_cam_red, n_extra), np.nan)
    cams_per_chunk = max(1, chunk_columns // p)
    ar = np.arange(p)
    chunks = [(p * b0, p * min(n_cam, b0 + cams_per_chunk)) for b0 in range(0, n_cam, cams_per_chunk)]
    if Q is None and use_band:
        Qb = _banded_blocks(Ss, fi, pos, block_row, block_col, p, n_cam)
        if Qb is not None:
            # the band inverse is Jacobi-scaled; scale back to the reduced unknowns
            sf = np.zeros(n_red)
            sf[fi] = s
            ir = p * block_row[:, None, None] + ar[None, :, None]
            ic = p * block_col[:, None, None] + ar[None, None, :]
            Qblk = Qb * sf[ir] * sf[ic]
            chunks = []  # only the extra-parameter columns are left to solve for
    if n_extra:
        chunks.append((n_cam_red, n_red))
    worst = 0.0
    for c0, c1 in chunks:
        cols = np.arange(c0, c1)
        fc = cols[free_red[c0:c1]]
        if fc.size == 0:
            continue
        B = np.zeros((fi.size, fc.size))
        B[pos[fc], np.arange(fc.size)] = 1.0
        X = solve(B)
        xd = X[pos[fc], np.arange(fc.size)]
        worst = max(worst, float(np.max(xd)) if np.all(xd > 0) else np.inf)
        if not np.all(np.isfinite(xd)) or worst > MAX_SCALED_VARIANCE:
            raise DatumDefectError(
                f"the normal matrix at the solution is numerically singular (Jacobi-scaled inverse diagonal "
                f"{worst:.1e} > {MAX_SCALED_VARIANCE:.0e}): the datum is not defined or a parameter is not "
                f"determined")
        X *= s[:, None]
        X *= s[pos[fc]][None, :]
        Xf = np.zeros((n_red, c1 - c0))
        Xf[np.ix_(fi, fc - c0)] = X
        if Q is not None:
            Q[:, c0:c1] = Xf
        if c0 < n_cam_red:
            sel = np.nonzero((p * block_col >= c0) & (p * block_col < c1))[0]
            rows = p * block_row[sel][:, None, None] + ar[None, :, None]
            cc = p * block_col[sel][:, None, None] - c0 + ar[None, None, :]
            Qblk[sel] = Xf[rows, cc]
        else:
            Qextra[:, :] = Xf[n_cam_red:, :]
            Qce[:, :] = Xf[:n_cam_red, :]
    if Q is not None:
        Qce = Q[:n_cam_red, n_cam_red:].copy()
    return ReducedInverse(Qblk, Qextra, Qce, Q, "dense" if Q is not None else "chunks")


def _supernodal_inverse(Ss: sp.csr_matrix, s: NDArray, free_red: NDArray, pos: NDArray, block_row: NDArray,
                        block_col: NDArray, p: int, n_cam: int) -> ReducedInverse:
    """:func:`reduced_inverse` by selected inversion (:mod:`.selinv`) of the Jacobi-scaled ``Ss``.

    Nodes are the free parameters of each image and, ordered last, all free extra parameters.
    """
    from .selinv import selected_inverse, symbolic_factor

    n_red = free_red.size
    n_cam_red = n_cam * p
    n_extra = n_red - n_cam_red
    per_cam = free_red[:n_cam_red].reshape(n_cam, p).sum(axis=1)
    n_ex_free = int(free_red[n_cam_red:].sum())
    sizes = np.concatenate([per_cam[per_cam > 0], [n_ex_free] if n_ex_free else []]).astype(np.int64)
    node_ptr = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    last = np.array([sizes.size - 1]) if n_ex_free else None
    sym = symbolic_factor(Ss, node_ptr, last_nodes=last)
    ar = np.arange(p)
    # wanted: every camera-pair block, the extras' block, and images x extras where S couples them
    shape = (block_row.size, p, p)
    r = np.broadcast_to(p * block_row[:, None, None] + ar[None, :, None], shape)
    c = np.broadcast_to(p * block_col[:, None, None] + ar[None, None, :], shape)
    fr, fc = pos[r], pos[c]
    ok = (fr >= 0) & (fc >= 0)
    ex_free = np.arange(n_cam_red, n_red)[free_red[n_cam_red:]]
    want_r, want_c = [fr[ok]], [fc[ok]]
    rows_red = np.zeros(0, np.int64)
    if ex_free.size:
        ee_r, ee_c = np.meshgrid(pos[ex_free], pos[ex_free], indexing="ij")
        want_r.append(ee_r.ravel())
        want_c.append(ee_c.ravel())
        # images with a parameter coupled to an extra parameter in S: all their free parameters are
        # on the factor's (node-level) pattern
        hit = np.unique(Ss[:, pos[ex_free]].nonzero()[0])
        cams = np.unique(np.nonzero(free_red[:n_cam_red])[0][hit[hit < pos[ex_free].min()]] // p)
        rows_red = (p * cams[:, None] + ar[None, :]).ravel()
        rows_red = rows_red[free_red[rows_red]]
        cr, cc = np.meshgrid(pos[rows_red], pos[ex_free], indexing="ij")
        want_r.append(cr.ravel())
        want_c.append(cc.ravel())
    vals = selected_inverse(Ss, sym, np.concatenate(want_r), np.concatenate(want_c),
                            max_scaled_variance=MAX_SCALED_VARIANCE)
    sf = np.zeros(n_red)
    sf[free_red] = s
    k = int(ok.sum())
    Qblk = np.zeros(shape)
    Qblk[ok] = vals[:k]
    Qblk *= sf[r] * sf[c]
    Qextra = np.zeros((n_extra, n_extra))
    Qce = np.full((n_cam_red, n_extra), np.nan)
    Qce[~free_red[:n_cam_red]] = 0.0               # fixed image parameters: no cofactors
    if ex_free.size:
        m = ex_free.size
        je = ex_free - n_cam_red
        Qextra[np.ix_(je, je)] = vals[k:k + m * m].reshape(m, m) * np.outer(sf[ex_free], sf[ex_free])
        Qce[rows_red] = 0.0                         # fixed extras stay 0
        Qce[np.ix_(rows_red, je)] = vals[k + m * m:].reshape(rows_red.size, m) * np.outer(sf[rows_red], sf[ex_free])
    return ReducedInverse(Qblk, Qextra, Qce, None, "supernodal")


def _band_selected_inverse_py(Ab, b):
    """Cholesky ``A = L L^T`` of a band matrix, then Takahashi's recursion for ``Z = A^-1`` inside the band.

    ``Ab[i, t] = A[i, i - b + t]`` (row-band storage of the lower triangle, ``t = b`` the diagonal).
    Entries of the inverse inside the band depend only on entries inside the band:
    ``Z[i, j] = (delta_ij / l_ii - sum_{k > i} l_ki Z[k, j]) / l_ii`` for ``j >= i``, from the last row up.
    Returns ``(Z, bad)`` with ``bad = -1``, or the row where the matrix is not positive definite.
    """
    n = Ab.shape[0]
    L = Ab.copy()
    for i in range(n):
        k0 = max(0, i - b)
        for j in range(k0, i + 1):
            sm = L[i, j - i + b]
            for k in range(k0, j):
                sm -= L[i, k - i + b] * L[j, k - j + b]
            if j < i:
                L[i, j - i + b] = sm / L[j, b]
            elif sm > 0.0:
                L[i, b] = np.sqrt(sm)
            else:
                return L, i
    Z = np.zeros_like(L)
    col = np.empty(b + 1)
    for i in range(n - 1, -1, -1):
        m = min(b, n - 1 - i)
        lii = L[i, b]
        for t in range(m):
            col[t] = L[i + 1 + t, b - 1 - t]  # l_ki, k = i + 1 + t
        for jj in range(m):
            j = i + 1 + jj
            sm = 0.0
            for t in range(jj + 1):  # k <= j: Z[j, k] in row j
                sm += Z[j, t - jj + b] * col[t]
            for t in range(jj + 1, m):  # k > j: Z[k, j] in row k
                sm += Z[i + 1 + t, jj - t + b] * col[t]
            Z[j, b - 1 - jj] = -sm / lii
        sm = 0.0
        for t in range(m):
            sm += col[t] * Z[i + 1 + t, b - 1 - t]
        Z[i, b] = 1.0 / (lii * lii) - sm / lii
    return Z, -1


_band_selected_inverse = numba.njit(cache=True)(_band_selected_inverse_py) if numba is not None else None


def _banded_blocks(Ss: sp.csr_matrix, fi: NDArray, pos: NDArray, block_row, block_col, p: int, n_cam: int):
    """``Qblk`` (Jacobi-scaled) by band Cholesky + Takahashi after a reverse Cuthill-McKee ordering of the images.

    Returns ``None`` when the band is too wide for this to beat the column-chunk solves.
    """
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    if _band_selected_inverse is None:
        return None
    n = Ss.shape[0]
    G = sp.csr_matrix((np.ones(block_row.size), (block_row, block_col)), shape=(n_cam, n_cam))
    cam_perm = reverse_cuthill_mckee((G + G.T).tocsr(), symmetric_mode=True)
    full = (p * cam_perm[:, None] + np.arange(p)[None, :]).ravel()
    full = full[pos[full] >= 0]
    perm = np.concatenate([pos[full], np.setdiff1d(np.arange(n), pos[full])])  # extras last
    iperm = np.empty(n, np.int64)
    iperm[perm] = np.arange(n)
    P = Ss[perm][:, perm].tocoo()
    lo = P.row >= P.col
    b = int(np.max(P.row[lo] - P.col[lo])) if lo.any() else 0
    if (b + 1) * b * n > 2e10 or b > n // 2:
        return None
    Ab = np.zeros((n, b + 1))
    Ab[P.row[lo], P.col[lo] - P.row[lo] + b] = P.data[lo]
    Z, bad = _band_selected_inverse(Ab, b)
    if bad >= 0:
        raise DatumDefectError(f"the normal matrix at the solution is not positive definite (pivot {bad} of {n}); "
                               f"the datum is not defined or a parameter is not determined")
    zd = Z[:, b]
    if not np.all(np.isfinite(zd)) or zd.max() > MAX_SCALED_VARIANCE:
        raise DatumDefectError(
            f"the normal matrix at the solution is numerically singular (Jacobi-scaled inverse diagonal "
            f"{zd.max():.1e} > {MAX_SCALED_VARIANCE:.0e}): the datum is not defined or a parameter is not determined")
    ar = np.arange(p)
    r = p * block_row[:, None, None] + ar[None, :, None]        # reduced (full) indices
    c = p * block_col[:, None, None] + ar[None, None, :]
    pr, pc = pos[r], pos[c]
    ok = (pr >= 0) & (pc >= 0)
    qr = np.where(ok, iperm[np.maximum(pr, 0)], 0)
    qc = np.where(ok, iperm[np.maximum(pc, 0)], 0)
    hi, lo_ = np.maximum(qr, qc), np.minimum(qr, qc)
    inband = ok & (hi - lo_ <= b)
    Qblk = np.where(inband, Z[hi, np.clip(lo_ - hi + b, 0, b)], 0.0)
    return Qblk


def _point_cov_py(Qblk, Vinv, Ac, Ap, cam_idx, pt_order, pt_start, pair_start, pair_blk, active, diag_block,
                  max_track, want_red):
    n_pt = Vinv.shape[0]
    p = Ac.shape[2]
    Cpp = np.zeros((n_pt, 3, 3))
    red = np.zeros((Ac.shape[0] if want_red else 0, 2))
    F = np.empty((max_track, p, 3))
    G = np.empty((max_track, p, 3))
    for j in range(n_pt):
        s = pt_start[j]
        k = pt_start[j + 1] - s
        if not active[j]:
            # fixed point: only the image parameters vary
            if want_red:
                for t in range(k):
                    i = pt_order[s + t]
                    Qd = Qblk[diag_block[cam_idx[i]]]
                    for kk in range(2):
                        v = 0.0
                        for x in range(p):
                            for y in range(p):
                                v += Ac[i, kk, x] * Qd[x, y] * Ac[i, kk, y]
                        red[i, kk] = 1.0 - v
            continue
        Vi = Vinv[j]
        for t in range(k):
            i = pt_order[s + t]
            for x in range(p):
                # W_i = Ac_i^T Ap_i
                w0 = Ac[i, 0, x] * Ap[i, 0, 0] + Ac[i, 1, x] * Ap[i, 1, 0]
                w1 = Ac[i, 0, x] * Ap[i, 0, 1] + Ac[i, 1, x] * Ap[i, 1, 1]
                w2 = Ac[i, 0, x] * Ap[i, 0, 2] + Ac[i, 1, x] * Ap[i, 1, 2]
                for m in range(3):
                    F[t, x, m] = w0 * Vi[0, m] + w1 * Vi[1, m] + w2 * Vi[2, m]
        base = pair_start[j]
        # G_t = sum_u Q_{c_t c_u} F_u
        for t in range(k):
            ct = cam_idx[pt_order[s + t]]
            for x in range(p):
                for m in range(3):
                    G[t, x, m] = 0.0
            for u in range(k):
                cu = cam_idx[pt_order[s + u]]
                a = min(t, u)
                b = max(t, u)
                Bq = Qblk[pair_blk[base + a * k - a * (a - 1) // 2 + (b - a)]]
                if ct <= cu:
                    for x in range(p):
                        for y in range(p):
                            q = Bq[x, y]
                            G[t, x, 0] += q * F[u, y, 0]
                            G[t, x, 1] += q * F[u, y, 1]
                            G[t, x, 2] += q * F[u, y, 2]
                else:
                    for x in range(p):
                        for y in range(p):
                            q = Bq[y, x]
                            G[t, x, 0] += q * F[u, y, 0]
                            G[t, x, 1] += q * F[u, y, 1]
                            G[t, x, 2] += q * F[u, y, 2]
        C = Cpp[j]
        for m in range(3):
            for n in range(3):
                v = Vi[m, n]
                for t in range(k):
                    for x in range(p):
                        v += F[t, x, m] * G[t, x, n]
                C[m, n] = v
        if want_red:
            for t in range(k):
                i = pt_order[s + t]
                Qd = Qblk[diag_block[cam_idx[i]]]
                for kk in range(2):
                    v = 0.0
                    for x in range(p):
                        ax = Ac[i, kk, x]
                        for y in range(p):
                            v += ax * Qd[x, y] * Ac[i, kk, y]
                        # cross term with Q_c,j = -G_t
                        for m in range(3):
                            v -= 2.0 * ax * G[t, x, m] * Ap[i, kk, m]
                    for m in range(3):
                        for n in range(3):
                            v += Ap[i, kk, m] * C[m, n] * Ap[i, kk, n]
                    red[i, kk] = 1.0 - v
    return Cpp, red


_point_cov_kernel = numba.njit(cache=True)(_point_cov_py) if numba is not None else None


def posterior_precision(result, method: str = "auto", redundancy: bool = False,
                        scale_by_sigma0: bool = True, backend: str = "auto", inverse_method: str = "auto",
                        undetermined_ratio: float = UNDETERMINED_POINT_RATIO) -> Precision:
    """Covariances of all adjusted parameters of ``result`` (an ``AdjustmentResult``).

    Parameters
    ----------
    method : {"auto", "sparse", "dense"}
        ``"sparse"``: blocks of ``S^-1`` on the camera-pair pattern from the sparse factor, point
        covariances in one compiled pass (needs numba; the default when available);
        ``"dense"``: LAPACK ``potrf`` + ``potri`` of the whole reduced system (small blocks).
    redundancy : bool
        Also compute the redundancy numbers of every observation: image coordinates, control
        point coordinates, navigation observations (rows of the camera-level terms).
    scale_by_sigma0 : bool
        Scale cofactors by the a-posteriori ``sigma0**2`` (else by 1, a-priori).
    backend : str
        Factorisation backend of the sparse method (:class:`lunarmap.adjust.factor.Factorizer`).
    inverse_method : str
        How the sparse method gets the blocks of ``S^-1`` (:func:`reduced_inverse`).
    undetermined_ratio : float
        Points whose normal block's smallest/largest eigenvalue ratio is below this are treated as
        undetermined (infinite covariance; their null direction does not weigh on the images).

    Raises
    ------
    DatumDefectError
        If the normal equations at the solution are singular.
    """
    from .normal import Terms, reduced_system

    pb = result.problem
    st = result.structure
    if Terms(pb).coupled:
        # rows coupling several points (laser altimetry): the whole normal matrix, inverted densely
        return _coupled_precision(result, redundancy, scale_by_sigma0)
    if method == "auto":
        method = "sparse" if (_point_cov_kernel is not None and getattr(st, "compiled", False)) else "dense"
    if method == "dense":
        return _dense_precision(result, redundancy, scale_by_sigma0)
    if method != "sparse":
        raise ValueError(f"unknown precision method {method!r}")
    if not getattr(st, "compiled", False):
        raise ValueError("the sparse precision method needs the compiled Schur structure (numba)")
    p = st.p
    terms, fixed_pt, lin = _linearized(result)
    undetermined = _regularize_undetermined_points(lin.V, ~fixed_pt, undetermined_ratio)
    S, _, Vinv, _ = reduced_system(lin, st, terms, 0.0, result.free_red)
    inv = reduced_inverse(S, result.free_red, st.block_row, st.block_col, p, st.n_cam, backend=backend,
                          method=inverse_method)
    Qblk, Qextra, Q = inv.Qblk, inv.Qextra, inv.Q
    kern = _point_cov_kernel
    assert kern is not None         # compiled structure: numba is there
    Cpp, red = kern(Qblk, Vinv, np.ascontiguousarray(lin.Ac), np.ascontiguousarray(lin.Ap), st.cam_idx,
                    st.pt_order, st.pt_start, st.pair_start, st.pair_blk, st.active, st.diag_block, st.max_track,
                    bool(redundancy))
    s2 = result.sigma0 ** 2 if scale_by_sigma0 else 1.0
    Cpp[fixed_pt] = 0.0
    Cpp[undetermined] = np.inf
    ctl_red = term_red = None
    if redundancy:
        ctl_red = _control_redundancy(pb, result.state.points, Cpp)
        lookup = _SparseCofactors(Qblk, st, Qextra, inv.Qce, p, terms.n_cam_red)
        term_red = _term_redundancy(pb, lin, terms, lookup, Cpp)
    return Precision(Qblk[st.diag_block] * s2, Cpp * s2, Qextra * s2, Q, red if redundancy else None,
                     result.sigma0, f"sparse-{inv.method}", undetermined, ctl_red, term_red, inv.Qce * s2)


def _control_redundancy(pb, points: NDArray, Qpp: NDArray) -> NDArray | None:
    """``1 - diag(W Q_pp W^T)`` of every weighted control point (``W`` its whitening, ``Q_pp`` its cofactors)."""
    from .normal import prior_terms

    pt = prior_terms(pb, points)
    if pt is None:
        return None
    idx, _, W = pt
    return 1.0 - np.einsum("kij,kjl,kil->ki", W, Qpp[idx], W)


class _SparseCofactors:
    """Cofactors ``Q[a, b]`` of reduced unknowns from the selected blocks (image pairs, image x extra, extras)."""

    def __init__(self, Qblk, st, Qextra, Qce, p, n_cam_red):
        self.Qblk, self.Qextra, self.Qce, self.p, self.ncr = Qblk, Qextra, Qce, p, n_cam_red
        self.n_cam = st.n_cam
        self.key = st.block_row.astype(np.int64) * st.n_cam + st.block_col
        self.order = np.argsort(self.key)
        self.sorted = self.key[self.order]

    def __call__(self, a: NDArray, b: NDArray) -> NDArray:
        p, ncr = self.p, self.ncr
        out = np.full(a.size, np.nan)
        cc = (a < ncr) & (b < ncr)
        if cc.any():
            ca, cb = a[cc] // p, b[cc] // p
            lo, hi = np.minimum(ca, cb), np.maximum(ca, cb)
            k = np.searchsorted(self.sorted, lo * self.n_cam + hi)
            k = np.minimum(k, self.sorted.size - 1)
            found = self.sorted[k] == lo * self.n_cam + hi
            blk = self.order[k]
            ia, ib = a[cc] % p, b[cc] % p
            swap = ca > cb           # blocks are stored (row <= col)
            r = np.where(swap, ib, ia)
            c = np.where(swap, ia, ib)
            out[np.flatnonzero(cc)] = np.where(found, self.Qblk[blk, r, c], np.nan)
        ce = (a < ncr) != (b < ncr)
        if ce.any():
            cam = np.where(a[ce] < ncr, a[ce], b[ce])
            ex = np.where(a[ce] < ncr, b[ce], a[ce]) - ncr
            out[ce] = self.Qce[cam, ex]
        ee = (a >= ncr) & (b >= ncr)
        if ee.any():
            out[ee] = self.Qextra[a[ee] - ncr, b[ee] - ncr]
        return out


def _term_redundancy(pb, lin, terms, lookup, Qpp: NDArray | None = None) -> list | None:
    """``1 - a_i^T Q a_i`` of every whitened row ``a_i`` of the terms (each row sees few unknowns); rows of
    point-observing terms (reference DTM heights) see one point only: ``a_i^T Q_pp a_i`` with ``Q_pp`` its
    cofactors."""
    if lin.Jx is None:
        return None
    J = sp.csr_matrix(lin.Jx)
    J.sum_duplicates()
    cnt = np.diff(J.indptr)
    quad = np.zeros(J.shape[0])
    top = int(cnt.max(initial=0))
    for u in range(top):                 # entries u and v of every row that has them
        for v in range(top):
            rows = np.flatnonzero(cnt > max(u, v))
            iu, iv = J.indptr[rows] + u, J.indptr[rows] + v
            q = lookup(J.indices[iu].astype(np.int64), J.indices[iv].astype(np.int64))
            quad[rows] += J.data[iu] * J.data[iv] * q
    if lin.xp_rows is not None and lin.xp_idx is not None and lin.xp_J is not None and Qpp is not None:
        # the rows observe only their point: no cross cofactors with the images are needed
        assert not np.any(cnt[lin.xp_rows]), "a point-observing term row with image-parameter partials"
        a = lin.xp_J
        with np.errstate(invalid="ignore"):
            quad[lin.xp_rows] += np.einsum("ki,kij,kj->k", a, Qpp[lin.xp_idx], a)
    red = 1.0 - quad
    out, s0 = [], 0
    for t in pb.terms:
        out.append(red[s0:s0 + t.n_obs_scalar])
        s0 += t.n_obs_scalar
    return out


def _regularize_undetermined_points(V: NDArray, active: NDArray, ratio: float = UNDETERMINED_POINT_RATIO) -> NDArray:
    """Indices of points whose normal block is numerically singular; their ``V`` is made regular in place.

    A point whose rays have become (nearly) parallel, e.g. one that drifted far along its rays
    during the adjustment, is not determined in one direction ``e``: ``V e ~ 0`` and so
    ``W e ~ 0``.  Its inverse block would be rounding noise and corrupt ``S = U - W V^-1 W^T``.
    Replacing the null eigenvalue by the largest one changes nothing that ``W`` can see (the
    pseudo-inverse limit) and keeps the images' covariances defined; the point's own covariance
    is reported as infinite.
    """
    idx = np.nonzero(active)[0]
    if idx.size == 0:
        return idx
    ev = np.linalg.eigvalsh(V[idx])
    bad = idx[~(ev[:, 0] > ratio * ev[:, 2])]
    if bad.size:
        lam, E = np.linalg.eigh(V[bad])
        top = np.maximum(lam[:, 2:3], 1e-300)
        lam = np.where(lam > ratio * top, lam, top)
        V[bad] = np.einsum("nij,nj,nkj->nik", E, lam, E)
    return bad


def _dense_spd_inverse(N: NDArray) -> NDArray:
    """Inverse of a dense symmetric positive-definite matrix (overwritten), by LAPACK Cholesky.

    Jacobi scaling first keeps the factorisation well conditioned (metres vs radians).

    Raises
    ------
    DatumDefectError
        The matrix is not positive definite.
    """
    d = 1.0 / np.sqrt(np.diag(N))
    N *= d[:, None]
    N *= d[None, :]
    c, info = sla.lapack.dpotrf(N, lower=True, overwrite_a=True, clean=False)
    if info != 0:
        raise DatumDefectError(f"the normal matrix at the solution is not positive definite (LAPACK info {info})")
    Q, info = sla.lapack.dpotri(c, lower=True, overwrite_c=True)
    if info != 0:
        raise DatumDefectError(f"inverting the normal matrix failed (LAPACK info {info})")
    il = np.tril_indices_from(Q, -1)
    Q[il[::-1]] = Q[il]  # mirror lower -> upper
    Q *= d[:, None]
    Q *= d[None, :]
    return Q


def _linearized(result) -> tuple:
    """The adjustment's terms, fixed-point mask and its linearisation at the solution (every precision method
    starts from them)."""
    from .normal import Terms, linearize

    pb = result.problem
    terms = Terms(pb)
    fixed_pt = pb.point_fixed()
    return terms, fixed_pt, linearize(pb, result.state, result.structure, terms, fixed_pt)


def _dense_precision(result, redundancy: bool, scale_by_sigma0: bool) -> Precision:
    """Reference implementation: dense LAPACK inverse of the whole reduced system."""
    from .normal import reduced_system

    pb = result.problem
    st = result.structure
    p = st.p
    terms, fixed_pt, lin = _linearized(result)
    S, _, Vinv, _ = reduced_system(lin, st, terms, 0.0, result.free_red)
    W = lin.W if lin.W is not None else np.einsum("nki,nkj->nij", lin.Ac, lin.Ap)
    F = np.matmul(W, Vinv[pb.obs.pt_idx])
    Qs = _dense_spd_inverse(S.toarray())
    n_red = result.free_red.size
    Q = np.zeros((n_red, n_red))
    fi = np.nonzero(result.free_red)[0]
    if fi.size == n_red:
        Q = Qs
    else:
        Q[np.ix_(fi, fi)] = Qs
    s2 = result.sigma0 ** 2 if scale_by_sigma0 else 1.0
    n_cam_red = terms.n_cam_red
    idx = np.arange(n_cam_red).reshape(-1, p)
    cam_cov = Q[idx[:, :, None], idx[:, None, :]] * s2
    extra_cov = Q[n_cam_red:, n_cam_red:] * s2

    o = pb.obs
    a, b = ordered_track_pairs(o.pt_idx, pb.n_points, active=~fixed_pt)
    ca, cb = o.cam_idx[a], o.cam_idx[b]
    ia = idx[ca]
    ib = idx[cb]
    Qab = Q[ia[:, :, None], ib[:, None, :]]                       # (P, p, p)
    QFb = np.matmul(Qab, F[b])                                     # Q_{ca cb} F_b, (P, p, 3)
    FtQF = np.matmul(F[a].transpose(0, 2, 1), QFb)                 # (P, 3, 3)
    pt_q = Vinv.copy()
    np.add.at(pt_q, o.pt_idx[a], FtQF)
    pt_q[fixed_pt] = 0.0
    pt_cov = pt_q * s2
    red = None
    if redundancy:
        # Q_c,j for each observation a: -sum_b Q_{ca cb} F_b
        Qcp = np.zeros((o.n, p, 3))
        np.add.at(Qcp, a, -QFb)
        Qcc_i = Q[idx[o.cam_idx][:, :, None], idx[o.cam_idx][:, None, :]]
        Ac, Ap = lin.Ac, lin.Ap
        var = (np.einsum("nki,nij,nkj->nk", Ac, Qcc_i, Ac)
               + 2.0 * np.einsum("nki,nij,nkj->nk", Ac, Qcp, Ap)
               + np.einsum("nki,nij,nkj->nk", Ap, pt_q[o.pt_idx], Ap))
        red = 1.0 - var  # A is whitened, so (A Q A^T P)_ii = var
    ctl_red = term_red = None
    if redundancy:
        ctl_red = _control_redundancy(pb, result.state.points, pt_q)
        term_red = _term_redundancy(pb, lin, terms, lambda a, b: Q[a, b], pt_q)
    return Precision(cam_cov, pt_cov, extra_cov, Q, red, result.sigma0, "dense-lapack", np.zeros(0, np.int64),
                     ctl_red, term_red, Q[:n_cam_red, n_cam_red:] * s2)


#: rows of the design whose quadratic forms ``a^T Q a`` are formed at once (memory: rows x unknowns doubles)
_COUPLED_CHUNK_ROWS = 4096
#: largest number of free unknowns whose dense normal matrix the coupled precision inverts (1.2 GB of doubles)
COUPLED_DENSE_LIMIT = 12000


def _coupled_precision(result, redundancy: bool, scale_by_sigma0: bool) -> Precision:
    """Precision of a problem with point-coupling terms (:attr:`~lunarmap.adjust.normal.Terms.coupled`): the
    dense inverse of the whole normal matrix ``A^T A`` (reduced unknowns and points; Jacobi-scaled Cholesky),
    redundancy numbers ``1 - a_i^T Q a_i`` of every row from the sparse design in chunks."""
    from .normal import full_design, prior_terms

    pb = result.problem
    st = result.structure
    p = st.p
    terms, fixed_pt, lin = _linearized(result)
    A, _ = full_design(lin, pb, terms, fixed_pt)
    n_red = result.free_red.size
    free = np.concatenate([result.free_red, np.repeat(~fixed_pt, 3)])
    fi = np.flatnonzero(free)
    if fi.size > COUPLED_DENSE_LIMIT:
        raise AdjustmentInputError(
            f"the block's precision with point-coupling observations (laser altimetry) is the dense inverse of its "
            f"{fi.size} unknowns: more than {COUPLED_DENSE_LIMIT}; adjust a smaller block (fewer tie points)")
    Af = A[:, fi].tocsc()
    Nd = (Af.T @ Af).toarray()
    dg = np.diag(Nd).copy()
    if np.any(dg <= 0) or not np.all(np.isfinite(dg)):
        raise DatumDefectError(f"{int(np.sum(~(dg > 0)))} unknown(s) have no weight in the normal equations")
    Qs = _dense_spd_inverse(Nd)
    if np.max(np.diag(Qs) * dg) > MAX_SCALED_VARIANCE:
        raise DatumDefectError("the normal matrix at the solution is numerically singular: the datum is not defined")
    s2 = result.sigma0 ** 2 if scale_by_sigma0 else 1.0
    n_all = free.size
    pos = -np.ones(n_all, np.int64)
    pos[fi] = np.arange(fi.size)

    def block(ix: NDArray) -> NDArray:
        """Cofactors of the (free) unknowns ``ix (..., k)`` as ``(..., k, k)``; zero where fixed."""
        q = pos[ix]
        out = Qs[np.maximum(q, 0)[..., :, None], np.maximum(q, 0)[..., None, :]]
        return np.where((q[..., :, None] >= 0) & (q[..., None, :] >= 0), out, 0.0)

    n_cam_red = terms.n_cam_red
    cam_cov = block(np.arange(n_cam_red).reshape(-1, p)) * s2
    pt_q = block(n_red + np.arange(3 * pb.n_points).reshape(-1, 3))
    extra_cov = block(np.arange(n_cam_red, n_red)) * s2
    Q = block(np.arange(n_red)) if n_red <= DENSE_Q_LIMIT else None
    ce = Qs[np.maximum(pos[:n_cam_red], 0)][:, np.maximum(pos[n_cam_red:n_red], 0)] if n_red > n_cam_red else \
        np.zeros((n_cam_red, 0))
    ce = np.where((pos[:n_cam_red, None] >= 0) & (pos[None, n_cam_red:n_red] >= 0), ce, 0.0)
    red = ctl_red = term_red = None
    if redundancy:
        A = Af.tocsr()
        quad = np.zeros(A.shape[0])
        for r0 in range(0, A.shape[0], _COUPLED_CHUNK_ROWS):
            Ak = A[r0:r0 + _COUPLED_CHUNK_ROWS]
            D = Ak @ Qs                                                   # (rows, n_free) dense
            row_of = np.repeat(np.arange(Ak.shape[0]), np.diff(Ak.indptr))
            quad[r0:r0 + Ak.shape[0]] = np.bincount(row_of, weights=Ak.data * D[row_of, Ak.indices],
                                                    minlength=Ak.shape[0])
        rr = 1.0 - quad
        o = pb.obs
        red = rr[:2 * o.n].reshape(o.n, 2)
        m_t = lin.rx.size
        term_red, s0 = [], 2 * o.n
        for t in pb.terms:
            term_red.append(rr[s0:s0 + t.n_obs_scalar])
            s0 += t.n_obs_scalar
        assert s0 == 2 * o.n + m_t
        if prior_terms(pb, result.state.points) is not None:
            ctl_red = rr[s0:].reshape(-1, 3)
    return Precision(cam_cov, pt_q * s2, extra_cov, Q, red, result.sigma0, "dense-coupled", np.zeros(0, np.int64),
                     ctl_red, term_red, ce * s2)
