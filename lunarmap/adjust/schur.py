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
then filled with numpy per iteration: per-observation products are summed
into camera / point / camera-pair blocks through constant sparse aggregation
matrices, never through Python loops over observations.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

__all__ = ["SchurStructure", "inv_sym3", "aggregation_matrix"]


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

    def __init__(self, cam_idx, pt_idx, n_cam: int, n_pt: int, p: int, active_pt=None):
        self.n_cam, self.n_pt, self.p = n_cam, n_pt, p
        cam_idx = np.asarray(cam_idx, dtype=np.int64)
        pt_idx = np.asarray(pt_idx, dtype=np.int64)
        n_obs = cam_idx.size
        self.n_obs = n_obs
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

    def assemble(self, blocks: NDArray[np.float64]) -> sp.csr_matrix:
        """Full symmetric CSR matrix from the upper camera-pair blocks ``(n_blocks, p, p)``."""
        data = blocks.reshape(-1)[self.csr_src]
        return sp.csr_matrix((data, self.csr_indices, self.csr_indptr), shape=(self.n_reduced, self.n_reduced))

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
