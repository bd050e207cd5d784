"""Block-sparse normal equations and their Schur complement (reduced camera system).

The normal equations of a bundle block (DLR paper, ``seeds/004``, Eq. 4, the
least-squares solution of the linearised Eqs. 1-3) have the arrow structure

    [ U   W ] [dc]   [-g_c]
    [ W^T V ] [dp] = [-g_p]

with 6x6 (or p x p) camera blocks ``U``, 3x3 point blocks ``V`` and one
p x 3 block ``W_i = A_c,i^T A_p,i`` per image observation.  Eliminating the
points gives the reduced camera system (the classical Schur complement)

    S dc = -g_c + W V^-1 g_p,    S = U - W V^-1 W^T,
    dp   = V^-1 (-g_p - W^T dc).

Everything here is built once from index arrays (:class:`SchurStructure`) and
then filled per iteration.  With numba (the default install) the normal blocks
and the Schur complement are each one compiled pass over the observations /
points: numpy would need ``(n_obs, p, p)`` and ``(n_pairs, p, p)`` temporaries
(0.3 GB and 0.7 GB for a million observations) whose memory traffic dominated the
iteration.  Without numba, per-observation products are summed into camera /
point / camera-pair blocks through constant sparse aggregation matrices.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

try:
    import numba
    from numba import prange
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None
    prange = range

__all__ = ["SchurStructure", "inv_sym3", "aggregation_matrix", "normal_blocks", "whiten", "HAVE_COMPILED"]

HAVE_COMPILED = numba is not None


def _jit(parallel=False):
    def wrap(fn):
        return numba.njit(parallel=parallel, cache=True)(fn) if numba is not None else fn
    return wrap


@_jit()
def _whiten_kernel(x, xy, ws, Jc, Jp, cam_free, pt_fixed, cam_idx, pt_idx):
    # r = (x - xy) * ws and the Jacobians whitened in place; fixed image parameters / points get no column
    n = x.shape[0]
    p = Jc.shape[2]
    r = np.empty((n, 2))
    cost = 0.0
    for i in range(n):
        c = cam_idx[i]
        fixed = pt_fixed[pt_idx[i]]
        for k in range(2):
            w = ws[i, k]
            rk = (x[i, k] - xy[i, k]) * w
            r[i, k] = rk
            cost += rk * rk
            for a in range(p):
                Jc[i, k, a] = Jc[i, k, a] * w if cam_free[c, a] else 0.0
            for a in range(3):
                Jp[i, k, a] = 0.0 if fixed else Jp[i, k, a] * w
    return r, cost


def whiten(x: NDArray, xy: NDArray, ws: NDArray, Jc: NDArray, Jp: NDArray, cam_free: NDArray, pt_fixed: NDArray,
           cam_idx: NDArray, pt_idx: NDArray):
    """Whitened residuals ``(x - xy) * ws`` ``(n, 2)`` and their sum of squares; ``Jc``, ``Jp`` whitened in place.

    Columns of fixed image parameters (``cam_free`` false) and rows of fixed points are zeroed.
    """
    if numba is not None:
        return _whiten_kernel(x, xy, ws, Jc, Jp, cam_free, pt_fixed, cam_idx, pt_idx)
    r = (x - xy) * ws
    Jc *= ws[:, :, None]
    Jp *= ws[:, :, None]
    if not cam_free.all():
        Jc *= cam_free[cam_idx][:, None, :]
    if pt_fixed.any():
        Jp[pt_fixed[pt_idx]] = 0.0
    return r, float(np.sum(r * r))


@_jit()
def _back_substitute_kernel(Ac, Ap, Vinv, gp, dc, cam_idx, pt_order, pt_start, active):
    n_pt = Vinv.shape[0]
    p = Ac.shape[2]
    dp = np.zeros((n_pt, 3))
    for j in range(n_pt):
        if not active[j]:
            continue
        t0 = -gp[j, 0]
        t1 = -gp[j, 1]
        t2 = -gp[j, 2]
        for q in range(pt_start[j], pt_start[j + 1]):
            i = pt_order[q]
            c = cam_idx[i]
            # W_i^T dc = Ap_i^T (Ac_i dc)
            e0 = 0.0
            e1 = 0.0
            for a in range(p):
                e0 += Ac[i, 0, a] * dc[c, a]
                e1 += Ac[i, 1, a] * dc[c, a]
            t0 -= Ap[i, 0, 0] * e0 + Ap[i, 1, 0] * e1
            t1 -= Ap[i, 0, 1] * e0 + Ap[i, 1, 1] * e1
            t2 -= Ap[i, 0, 2] * e0 + Ap[i, 1, 2] * e1
        for m in range(3):
            dp[j, m] = Vinv[j, m, 0] * t0 + Vinv[j, m, 1] * t1 + Vinv[j, m, 2] * t2
    return dp


@_jit()
def _normal_blocks_kernel(Ac, Ap, r, cam_idx, pt_idx, n_cam, n_pt, want_W):
    # serial: the scatter-adds into U / V would race across threads
    n = Ac.shape[0]
    p = Ac.shape[2]
    U = np.zeros((n_cam, p, p))
    V = np.zeros((n_pt, 3, 3))
    W = np.empty((n if want_W else 0, p, 3))
    gc = np.zeros((n_cam, p))
    gp = np.zeros((n_pt, 3))
    for i in range(n):
        c = cam_idx[i]
        j = pt_idx[i]
        r0 = r[i, 0]
        r1 = r[i, 1]
        for a in range(p):
            a0 = Ac[i, 0, a]
            a1 = Ac[i, 1, a]
            gc[c, a] += a0 * r0 + a1 * r1
            for b in range(a, p):
                U[c, a, b] += a0 * Ac[i, 0, b] + a1 * Ac[i, 1, b]
            if want_W:
                for b in range(3):
                    W[i, a, b] = a0 * Ap[i, 0, b] + a1 * Ap[i, 1, b]
        for a in range(3):
            a0 = Ap[i, 0, a]
            a1 = Ap[i, 1, a]
            gp[j, a] += a0 * r0 + a1 * r1
            for b in range(a, 3):
                V[j, a, b] += a0 * Ap[i, 0, b] + a1 * Ap[i, 1, b]
    for c in range(n_cam):
        for a in range(p):
            for b in range(a):
                U[c, a, b] = U[c, b, a]
    for j in range(n_pt):
        V[j, 1, 0] = V[j, 0, 1]
        V[j, 2, 0] = V[j, 0, 2]
        V[j, 2, 1] = V[j, 1, 2]
    return U, V, W, gc, gp


def normal_blocks(Ac: NDArray, Ap: NDArray, r: NDArray, cam_idx: NDArray, pt_idx: NDArray, n_cam: int, n_pt: int,
                  want_W: bool = True):
    """Camera blocks ``U (n_cam, p, p)``, point blocks ``V (n_pt, 3, 3)``, cross blocks ``W (n_obs, p, 3)``
    and gradients ``g_c (n_cam, p)``, ``g_p (n_pt, 3)`` of whitened Jacobians ``Ac (n, 2, p)``, ``Ap (n, 2, 3)``
    and residuals ``r (n, 2)``.

    ``want_W=False`` returns ``W = None``: the compiled kernels form ``W_i = Ac_i^T Ap_i`` on the fly, which
    reads as many numbers as a stored ``W`` would and saves its ``18 n_obs`` doubles.
    """
    if numba is not None:
        U, V, W, gc, gp = _normal_blocks_kernel(np.ascontiguousarray(Ac), np.ascontiguousarray(Ap),
                                                np.ascontiguousarray(r), cam_idx, pt_idx, n_cam, n_pt, want_W)
        return U, V, (W if want_W else None), gc, gp
    n, _, p = Ac.shape
    UU = np.einsum("nki,nkj->nij", Ac, Ac).reshape(n, p * p)
    VV = np.einsum("nki,nkj->nij", Ap, Ap).reshape(n, 9)
    W = np.einsum("nki,nkj->nij", Ac, Ap)
    cam_agg = aggregation_matrix(cam_idx, n_cam)
    pt_agg = aggregation_matrix(pt_idx, n_pt)
    return ((cam_agg @ UU).reshape(-1, p, p), (pt_agg @ VV).reshape(-1, 3, 3), W,
            cam_agg @ np.einsum("nki,nk->ni", Ac, r), pt_agg @ np.einsum("nki,nk->ni", Ap, r))


@_jit()
def _pair_keys_kernel(cam_idx, pt_order, pt_start, active, n_cam, n_pairs):
    # camera-pair key (upper triangle) of every observation pair (t <= u) of a point, in the
    # order the Schur kernel visits them
    keys = np.empty(n_pairs, np.int64)
    q = 0
    for j in range(pt_start.size - 1):
        if not active[j]:
            continue
        s = pt_start[j]
        k = pt_start[j + 1] - s
        for t in range(k):
            ca = cam_idx[pt_order[s + t]]
            for u in range(t, k):
                cb = cam_idx[pt_order[s + u]]
                keys[q] = min(ca, cb) * n_cam + max(ca, cb)
                q += 1
    return keys


@_jit()
def _schur_kernel(U, V, Ac, Ap, gp, mu, cam_idx, pt_order, pt_start, pair_start, pair_blk, active, diag_block,
                  n_blocks, max_track, n_chunks):
    n_cam = U.shape[0]
    p = U.shape[1]
    n_pt = V.shape[0]
    acc = np.zeros((n_chunks, n_blocks, p, p))
    racc = np.zeros((n_chunks, n_cam, p))
    Vinv = np.empty((n_pt, 3, 3))
    for ch in prange(n_chunks):
        F = np.empty((max_track, p, 3))
        Wl = np.empty((max_track, p, 3))
        Vi = np.empty((3, 3))
        M = np.empty((p, p))
        A = acc[ch]
        R = racc[ch]
        for j in range(ch * n_pt // n_chunks, (ch + 1) * n_pt // n_chunks):
            # damped point block V + mu diag(V) (Marquardt; diagonal clipped like Ceres)
            a = V[j, 0, 0]
            d = V[j, 1, 1]
            f = V[j, 2, 2]
            a += mu * min(max(a, 1e-6), 1e32)
            d += mu * min(max(d, 1e-6), 1e32)
            f += mu * min(max(f, 1e-6), 1e32)
            b = V[j, 0, 1]
            c = V[j, 0, 2]
            e = V[j, 1, 2]
            c00 = d * f - e * e
            c01 = c * e - b * f
            c02 = b * e - c * d
            c11 = a * f - c * c
            c12 = b * c - a * e
            c22 = a * d - b * b
            inv = 1.0 / (a * c00 + b * c01 + c * c02)
            Vi[0, 0] = c00 * inv
            Vi[0, 1] = Vi[1, 0] = c01 * inv
            Vi[0, 2] = Vi[2, 0] = c02 * inv
            Vi[1, 1] = c11 * inv
            Vi[1, 2] = Vi[2, 1] = c12 * inv
            Vi[2, 2] = c22 * inv
            Vinv[j] = Vi
            if not active[j]:
                continue
            s = pt_start[j]
            k = pt_start[j + 1] - s
            g0 = gp[j, 0]
            g1 = gp[j, 1]
            g2 = gp[j, 2]
            for t in range(k):
                i = pt_order[s + t]
                ci = cam_idx[i]
                for x in range(p):
                    # W_i = Ac_i^T Ap_i, formed here instead of stored
                    a0 = Ac[i, 0, x]
                    a1 = Ac[i, 1, x]
                    w0 = a0 * Ap[i, 0, 0] + a1 * Ap[i, 1, 0]
                    w1 = a0 * Ap[i, 0, 1] + a1 * Ap[i, 1, 1]
                    w2 = a0 * Ap[i, 0, 2] + a1 * Ap[i, 1, 2]
                    Wl[t, x, 0] = w0
                    Wl[t, x, 1] = w1
                    Wl[t, x, 2] = w2
                    f0 = w0 * Vi[0, 0] + w1 * Vi[1, 0] + w2 * Vi[2, 0]
                    f1 = w0 * Vi[0, 1] + w1 * Vi[1, 1] + w2 * Vi[2, 1]
                    f2 = w0 * Vi[0, 2] + w1 * Vi[1, 2] + w2 * Vi[2, 2]
                    F[t, x, 0] = f0
                    F[t, x, 1] = f1
                    F[t, x, 2] = f2
                    R[ci, x] += f0 * g0 + f1 * g1 + f2 * g2
            q = pair_start[j]
            for t in range(k):
                ca = cam_idx[pt_order[s + t]]
                for u in range(t, k):
                    cb = cam_idx[pt_order[s + u]]
                    Ab = A[pair_blk[q]]
                    q += 1
                    for x in range(p):
                        f0 = F[t, x, 0]
                        f1 = F[t, x, 1]
                        f2 = F[t, x, 2]
                        for y in range(p):
                            M[x, y] = f0 * Wl[u, y, 0] + f1 * Wl[u, y, 1] + f2 * Wl[u, y, 2]
                    if ca < cb or (ca == cb and t == u):
                        for x in range(p):
                            for y in range(p):
                                Ab[x, y] -= M[x, y]
                    elif ca > cb:
                        for x in range(p):
                            for y in range(p):
                                Ab[y, x] -= M[x, y]
                    else:  # two observations of one point in one image: both orders
                        for x in range(p):
                            for y in range(p):
                                Ab[x, y] -= M[x, y] + M[y, x]
    blocks = acc[0]
    for ch in range(1, n_chunks):
        blocks += acc[ch]
    rhs = racc[0]
    for ch in range(1, n_chunks):
        rhs += racc[ch]
    for c in range(n_cam):
        blocks[diag_block[c]] += U[c]
    return blocks, rhs, Vinv


def aggregation_matrix(groups: NDArray[np.int64], n_groups: int, weights=None) -> sp.csr_matrix:
    """Sparse ``(n_groups, n_items)`` matrix summing items into their group (``M @ values``)."""
    n = groups.size
    data = np.ones(n) if weights is None else weights
    return sp.csr_matrix((data, (groups, np.arange(n))), shape=(n_groups, n))


def inv_sym3(A: NDArray[np.float64]) -> NDArray[np.float64]:
    """Inverse of symmetric 3x3 matrices, ``(n, 3, 3)``, by cofactors (vectorised, no LAPACK loop)."""
    a, b, c = A[:, 0, 0], A[:, 0, 1], A[:, 0, 2]
    d, e, f = A[:, 1, 1], A[:, 1, 2], A[:, 2, 2]
    c00 = d * f - e * e
    c01 = c * e - b * f
    c02 = b * e - c * d
    c11 = a * f - c * c
    c12 = b * c - a * e
    c22 = a * d - b * b
    det = a * c00 + b * c01 + c * c02
    out = np.empty_like(A)
    inv = 1.0 / det
    out[:, 0, 0] = c00 * inv
    out[:, 0, 1] = out[:, 1, 0] = c01 * inv
    out[:, 0, 2] = out[:, 2, 0] = c02 * inv
    out[:, 1, 1] = c11 * inv
    out[:, 1, 2] = out[:, 2, 1] = c12 * inv
    out[:, 2, 2] = c22 * inv
    return out


class SchurStructure:
    """Index structures of one block: which observation pairs feed which camera-pair block.

    Parameters
    ----------
    cam_idx, pt_idx : (n_obs,) int
        Image and point of every image observation.
    n_cam, n_pt : int
        Number of images and points.
    p : int
        Unknowns per image.
    active_pt : (n_pt,) bool, optional
        Points that are unknowns (fixed points do not couple images).
    """

    def __init__(self, cam_idx, pt_idx, n_cam: int, n_pt: int, p: int, active_pt=None, compiled: bool | None = None):
        self.n_cam, self.n_pt, self.p = n_cam, n_pt, p
        cam_idx = np.asarray(cam_idx, dtype=np.int64)
        pt_idx = np.asarray(pt_idx, dtype=np.int64)
        n_obs = cam_idx.size
        self.n_obs = n_obs
        self.cam_idx, self.pt_idx = cam_idx, pt_idx
        self.pt_of_obs = pt_idx
        self.compiled = HAVE_COMPILED if compiled is None else (compiled and HAVE_COMPILED)
        if self.compiled:
            self._init_compiled(active_pt)
            self._build_csr()
            return
        self.cam_agg = aggregation_matrix(cam_idx, n_cam)
        self.pt_agg = aggregation_matrix(pt_idx, n_pt)
        # observations ordered by point: pairs (a, b) of one point are a run of that order
        order = np.argsort(pt_idx, kind="stable")
        sp_pt = pt_idx[order]
        starts = np.searchsorted(sp_pt, np.arange(n_pt))
        ends = np.searchsorted(sp_pt, np.arange(n_pt), side="right")
        track = ends - starts
        if active_pt is not None:
            track = np.where(active_pt, track, 0)
        pos = np.arange(n_obs) - starts[sp_pt]            # position of each sorted obs in its track
        pa_list, pb_list = [], []
        for d in range(int(track.max(initial=0))):
            ok = pos + d < track[sp_pt]
            i = np.nonzero(ok)[0]
            pa_list.append(order[i])
            pb_list.append(order[i + d])
        pa = np.concatenate(pa_list) if pa_list else np.zeros(0, np.int64)
        pb = np.concatenate(pb_list) if pb_list else np.zeros(0, np.int64)
        ca, cb = cam_idx[pa], cam_idx[pb]
        # keep blocks in the upper triangle: W_a V^-1 W_b^T transposes when a and b swap
        swap = ca > cb
        pa, pb = np.where(swap, pb, pa), np.where(swap, pa, pb)
        ca, cb = cam_idx[pa], cam_idx[pb]
        # two different observations of one point in the same image feed both orders of the diagonal block
        twice = (ca == cb) & (pa != pb)
        pa = np.concatenate([pa, pb[twice]])
        pb = np.concatenate([pb, pa[: twice.size][twice]])
        ca, cb = cam_idx[pa], cam_idx[pb]
        key = ca * n_cam + cb
        diag_keys = np.arange(n_cam, dtype=np.int64) * (n_cam + 1)
        bkeys, inv = np.unique(np.concatenate([key, diag_keys]), return_inverse=True)
        self.pair_a, self.pair_b = pa, pb
        self.n_pairs = pa.size
        # pairs in chunks, each with its own aggregation matrix, so per-iteration work streams through memory
        chunk = 300_000
        self._chunks = []
        inv_pairs = inv[: pa.size]
        for s in range(0, pa.size, chunk):
            sl = slice(s, s + chunk)
            self._chunks.append((pa[sl], pb[sl], aggregation_matrix(inv_pairs[sl], bkeys.size)))
        self.diag_block = inv[pa.size:]
        self.block_row = bkeys // n_cam
        self.block_col = bkeys % n_cam
        self.n_blocks = bkeys.size
        self._build_csr()

    def _init_compiled(self, active_pt):
        n_cam, n_pt = self.n_cam, self.n_pt
        # BAL files and most matchers list observations point by point: then no sort is needed
        order = (np.arange(self.n_obs) if np.all(self.pt_idx[1:] >= self.pt_idx[:-1])
                 else np.argsort(self.pt_idx, kind="stable"))
        track = np.bincount(self.pt_idx, minlength=n_pt)
        active = np.ones(n_pt, bool) if active_pt is None else np.asarray(active_pt, bool)
        k = np.where(active, track, 0)
        n_pair_pt = k * (k + 1) // 2
        self.pt_order = order.astype(np.int64)
        self.pt_start = np.concatenate([[0], np.cumsum(track)]).astype(np.int64)
        self.pair_start = np.concatenate([[0], np.cumsum(n_pair_pt)]).astype(np.int64)
        self.active = active
        self.max_track = int(track.max(initial=1))
        n_pairs = int(self.pair_start[-1])
        keys = _pair_keys_kernel(self.cam_idx, self.pt_order, self.pt_start, active, n_cam, n_pairs)
        diag_keys = np.arange(n_cam, dtype=np.int64) * (n_cam + 1)
        if n_cam * n_cam <= 50_000_000:
            # dense key table instead of sorting millions of pair keys
            present = np.zeros(n_cam * n_cam, bool)
            present[keys] = True
            present[diag_keys] = True
            bkeys = np.flatnonzero(present)
            rank = np.cumsum(present) - 1
            self.pair_blk = rank[keys]
            self.diag_block = rank[diag_keys]
            del present, rank
        else:
            bkeys, inv = np.unique(np.concatenate([keys, diag_keys]), return_inverse=True)
            self.pair_blk = inv[:n_pairs].astype(np.int64)
            self.diag_block = inv[n_pairs:].astype(np.int64)
        self.n_pairs = n_pairs
        self.block_row = bkeys // n_cam
        self.block_col = bkeys % n_cam
        self.n_blocks = bkeys.size

    def schur(self, U: NDArray, V: NDArray, Ac: NDArray, Ap: NDArray, gp: NDArray, mu: float):
        """Damped Schur complement by the compiled kernel.

        Returns the upper camera-pair blocks of ``U - W (V + mu diag V)^-1 W^T`` ``(n_blocks, p, p)``
        (the camera damping is *not* included), ``sum_i F_i g_p,j (n_cam, p)`` with
        ``F_i = W_i (V_j + mu diag V_j)^-1``, and the damped point inverses ``(n_pt, 3, 3)``.
        """
        # one chunk: on a shared 2-core machine numba's thread pool was slower than a serial pass
        n_chunks = 1
        return _schur_kernel(np.ascontiguousarray(U), np.ascontiguousarray(V), Ac, Ap,
                             np.ascontiguousarray(gp), float(mu), self.cam_idx, self.pt_order, self.pt_start,
                             self.pair_start, self.pair_blk, self.active, self.diag_block, self.n_blocks,
                             self.max_track, n_chunks)

    def back_substitute(self, Ac: NDArray, Ap: NDArray, Vinv: NDArray, gp: NDArray, dc: NDArray) -> NDArray:
        """Point corrections ``dp_j = Vinv_j (-g_p,j - sum_i W_i^T dc_cam(i))`` ``(n_pt, 3)`` (zero for fixed points)."""
        return _back_substitute_kernel(Ac, Ap, Vinv, gp, np.ascontiguousarray(dc), self.cam_idx, self.pt_order,
                                       self.pt_start, self.active)

    def _build_csr(self):
        p = self.p
        r, c = self.block_row, self.block_col
        nb = self.n_blocks
        ii, jj = np.meshgrid(np.arange(p), np.arange(p), indexing="ij")
        rows_u = (p * r[:, None] + ii.ravel()[None, :]).ravel()
        cols_u = (p * c[:, None] + jj.ravel()[None, :]).ravel()
        src_u = np.arange(nb * p * p)
        off = r != c
        # lower triangle = transposed upper blocks; source index into the transposed block array
        rows_l = (p * c[off][:, None] + ii.ravel()[None, :]).ravel()
        cols_l = (p * r[off][:, None] + jj.ravel()[None, :]).ravel()
        src_l = (np.nonzero(off)[0][:, None] * p * p + (jj * p + ii).ravel()[None, :]).ravel()
        rows = np.concatenate([rows_u, rows_l])
        cols = np.concatenate([cols_u, cols_l])
        src = np.concatenate([src_u, src_l])
        order = np.lexsort((cols, rows))
        n = p * self.n_cam
        self.csr_indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=n))]).astype(np.int64)
        self.csr_indices = cols[order].astype(np.int32)
        self.csr_src = src[order]
        self.n_reduced = n
        # upper triangle in CSR order = lower triangle in CSC order (what CHOLMOD factorises)
        rs, cs = rows[order], cols[order]
        up = cs >= rs
        self.low_csc_indptr = np.concatenate([[0], np.cumsum(np.bincount(rs[up], minlength=n))]).astype(np.int32)
        self.low_csc_indices = rs[up].astype(np.int32)
        self.low_csc_cols = cs[up].astype(np.int32)
        self.low_csc_src = self.csr_src[up]

    def assemble(self, blocks: NDArray[np.float64]) -> sp.csr_matrix:
        """Full symmetric CSR matrix from the upper camera-pair blocks ``(n_blocks, p, p)``."""
        flat = blocks.reshape(-1)
        S = sp.csr_matrix((flat[self.csr_src], self.csr_indices, self.csr_indptr),
                          shape=(self.n_reduced, self.n_reduced))
        # the same matrix's lower triangle in CSC form (row indices, column of each entry, values), with
        # pattern arrays owned by this structure, so a factoriser can skip tril() and re-analysis
        S.lower_csc = (self.low_csc_indptr, self.low_csc_cols, self.low_csc_indices, flat[self.low_csc_src])
        return S

    def pair_blocks(self, F: NDArray, W: NDArray) -> NDArray:
        """Sum of ``F_a W_b^T`` over observation pairs into camera-pair blocks, ``(n_blocks, p, p)``.

        ``F_i = W_i V_j^-1``; done in chunks so the temporary stays small.
        """
        p = self.p
        out = np.zeros((self.n_blocks, p * p))
        Wt = np.ascontiguousarray(W.transpose(0, 2, 1))
        for a, b, agg in self._chunks:
            prod = np.matmul(F[a], Wt[b])
            out += agg @ prod.reshape(-1, p * p)
        return out.reshape(-1, p, p)
