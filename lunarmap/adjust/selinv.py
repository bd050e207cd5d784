"""Selected inversion of the reduced camera system: the entries of ``S^-1`` on the pattern of its Cholesky factor.

The posterior precision of a block needs the blocks of ``Q = S^-1`` for every pair of images that
share a point (and for the images with the navigation offsets/drifts), never the whole inverse.
Solving for the columns of ``S^-1`` with the sparse factor costs ``2 nnz(L)`` flops per column, so
``n * 2 nnz(L)`` in all: for a 4,000-image block that was ~10x the whole adjustment. Takahashi's
equations give the entries of ``Z = S^-1`` on the pattern of ``L`` for about the cost of the
factorisation itself (Erisman and Tinney 1975; the supernodal, multifrontal form as in
Amestoy et al. and Lin et al.'s SelInv):

for a supernode of columns ``J`` with the rows ``R`` below it in ``L`` (``S = L L^T``)::

    Z_RJ = -Z_RR L_RJ L_JJ^-1
    Z_JJ = L_JJ^-T (L_JJ^-1 - L_RJ^T Z_RJ)

and ``R`` of a supernode lies in the columns and rows of its parent in the elimination tree, so
``Z_RR`` is a sub-matrix of the parent's dense "frontal" inverse ``Z[J_p + R_p, J_p + R_p]``: the
tree is walked from the root down, each front kept until its children have taken their ``Z_RR``.

The unknowns are grouped into nodes (the parameters of one image; the extra parameters), the
ordering is a nested dissection of the node graph computed here (level-structure bisection: for the
2-D-like graphs of image blocks the fronts stay near ``sqrt(n)`` images wide, so the factorisation
and the inversion grow like ``n^1.5``, not like the ``n^2`` of a band or of column solves), and the
factorisation is multifrontal with dense BLAS-3 kernels on each front. Extra parameters that couple
many images (per-orbit offsets and drifts) form one node ordered last.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import breadth_first_order, connected_components, reverse_cuthill_mckee

from ..errors import DatumDefectError

__all__ = ["SymbolicFactor", "symbolic_factor", "nested_dissection", "selected_inverse"]

#: nested dissection stops splitting subgraphs of at most this many nodes
ND_LEAF = 24
#: supernodes are merged with their parent while both together have at most this many scalar columns
#: and the explicit zeros this adds stay below ``AMALGAMATE_ZEROS`` of the merged front's columns
AMALGAMATE_COLUMNS = 48
AMALGAMATE_ZEROS = 0.5


def _bfs_levels(G: sp.csr_matrix, start: int) -> NDArray[np.int64]:
    """Breadth-first distances (edges) from ``start`` in the connected graph ``G``."""
    order, pred = breadth_first_order(G, start, directed=False, return_predecessors=True)
    level = np.full(G.shape[0], -1, np.int64)
    level[start] = 0
    for v in order[1:]:              # BFS order: a node's predecessor is levelled before it
        level[v] = level[pred[v]] + 1
    return level


def nested_dissection(G: sp.csr_matrix, leaf: int = ND_LEAF) -> NDArray[np.int64]:
    """Fill-reducing order of the nodes of the symmetric graph ``G`` (nested dissection).

    Each connected subgraph larger than ``leaf`` is split at the middle level of a breadth-first
    level structure rooted at a pseudo-peripheral node (George and Liu's automatic nested
    dissection); the separator is ordered after both halves. Leaves are ordered by reverse
    Cuthill-McKee. Returns ``order`` (new position -> node).
    """
    G = sp.csr_matrix(G)
    G.setdiag(0)
    G.eliminate_zeros()
    out: list[NDArray[np.int64]] = []
    stack: list[tuple[NDArray[np.int64], bool]] = [(np.arange(G.shape[0]), False)]
    # iterative: (nodes, is_separator); separators are emitted after the parts they split, so the
    # stack holds [separator, part B, part A] with A popped first
    while stack:
        nodes, emit = stack.pop()
        if emit or nodes.size == 0:
            out.append(nodes)
            continue
        sub = G[nodes][:, nodes]
        if nodes.size <= leaf:
            out.append(nodes[reverse_cuthill_mckee(sub, symmetric_mode=True)])
            continue
        ncomp, lab = connected_components(sub, directed=False)
        if ncomp > 1:
            for c in range(ncomp - 1, -1, -1):
                stack.append((nodes[lab == c], False))
            continue
        lev = _bfs_levels(sub, 0)
        lev = _bfs_levels(sub, int(np.argmax(lev)))         # pseudo-peripheral start
        lev = _bfs_levels(sub, int(np.argmax(lev)))
        counts = np.bincount(lev)
        if counts.size < 3:                                  # too dense to split: order it as a leaf
            out.append(nodes[reverse_cuthill_mckee(sub, symmetric_mode=True)])
            continue
        cum = np.cumsum(counts)
        m = int(np.clip(np.searchsorted(cum, nodes.size / 2.0), 1, counts.size - 2))
        stack.append((nodes[lev == m], True))
        stack.append((nodes[lev > m], False))
        stack.append((nodes[lev < m], False))
    return np.concatenate(out).astype(np.int64)


def _etree(A: sp.csr_matrix) -> NDArray[np.int64]:
    """Elimination tree of the symmetric pattern ``A`` (Liu's algorithm with path compression)."""
    n = A.shape[0]
    parent = np.full(n, -1, np.int64)
    ancestor = np.full(n, -1, np.int64)
    indptr, indices = A.indptr, A.indices
    for j in range(n):
        for i in indices[indptr[j]:indptr[j + 1]]:
            # walk from i < j up to its root, compressing the path to j
            while i != -1 and i < j:
                nxt = ancestor[i]
                ancestor[i] = j
                if nxt == -1:
                    parent[i] = j
                i = nxt
    return parent


def _postorder(parent: NDArray[np.int64]) -> NDArray[np.int64]:
    n = parent.size
    children: list[list[int]] = [[] for _ in range(n)]
    roots: list[int] = []
    for v in range(n):
        (children[parent[v]] if parent[v] >= 0 else roots).append(v)
    order = []
    for r in roots:
        stack = [(r, 0)]
        while stack:
            v, k = stack.pop()
            if k < len(children[v]):
                stack.append((v, k + 1))
                stack.append((children[v][k], 0))
            else:
                order.append(v)
    return np.array(order, np.int64)


@dataclass
class SymbolicFactor:
    """Ordering and supernodal structure of a symmetric matrix whose unknowns are grouped into nodes.

    Attributes
    ----------
    perm : (n,) int
        Scalar permutation, new position -> original index.
    node_perm : (n_nodes,) int
        Node permutation, new position -> original node.
    node_ptr : (n_nodes + 1,) int
        Scalar ranges of the original nodes.
    sn_nodes : list of (n_nodes_in_sn,) int
        Nodes (new positions, contiguous) of each supernode.
    sn_cols : list of (2,) int
        Scalar column range ``[c0, c1)`` (new positions) of each supernode.
    sn_rows : list of (k,) int
        Sorted scalar rows below the supernode (new positions, all ``>= c1``).
    sn_parent : (n_sn,) int
        Parent supernode (-1 for roots).
    """

    perm: NDArray[np.int64]
    node_perm: NDArray[np.int64]
    node_ptr: NDArray[np.int64]
    sn_nodes: list
    sn_cols: list
    sn_rows: list
    sn_parent: NDArray[np.int64]

    @property
    def n(self) -> int:
        return int(self.perm.size)

    def nnz_factor(self) -> int:
        """Entries of the supernodal ``L`` (explicit zeros of amalgamated supernodes included)."""
        return int(sum((c[1] - c[0]) * (c[1] - c[0] + 1) // 2 + (c[1] - c[0]) * r.size
                       for c, r in zip(self.sn_cols, self.sn_rows)))


def symbolic_factor(S: sp.spmatrix, node_ptr: NDArray[np.int64], last_nodes: NDArray[np.int64] | None = None,
                    leaf: int = ND_LEAF) -> SymbolicFactor:
    """Nested-dissection ordering, elimination tree and supernodes of ``S`` on its node graph.

    Parameters
    ----------
    S : (n, n) sparse, symmetric
    node_ptr : (n_nodes + 1,) int
        Scalar range of every node (consecutive unknowns, e.g. one image's parameters).
    last_nodes : int array, optional
        Nodes ordered last, in this order (dense couplings such as per-orbit offsets).
    """
    node_ptr = np.asarray(node_ptr, np.int64)
    n_nodes = node_ptr.size - 1
    n = S.shape[0]
    sizes = np.diff(node_ptr)
    node_of = np.repeat(np.arange(n_nodes), sizes)
    C = sp.coo_matrix(S)
    G = sp.csr_matrix((np.ones(C.nnz), (node_of[C.row], node_of[C.col])), shape=(n_nodes, n_nodes))
    G = ((G + G.T) != 0).astype(np.int8).tocsr()
    last = np.zeros(0, np.int64) if last_nodes is None else np.asarray(last_nodes, np.int64)
    rest = np.setdiff1d(np.arange(n_nodes), last)
    sub_order = nested_dissection(G[rest][:, rest], leaf)
    node_order = np.concatenate([rest[sub_order], last])
    # elimination tree of the permuted node graph, then a postorder so that supernodes are contiguous
    inv = np.empty(n_nodes, np.int64)
    inv[node_order] = np.arange(n_nodes)
    Gp = sp.csr_matrix(G[node_order][:, node_order])
    parent = _etree(sp.tril(Gp, format="csr"))
    post = _postorder(parent)
    node_order = node_order[post]
    inv[node_order] = np.arange(n_nodes)
    Gp = sp.csr_matrix(G[node_order][:, node_order])
    parent = _etree(sp.tril(Gp, format="csr"))
    # node column structures: struct(j) = higher neighbours of j + structs of its children, minus j
    children: list[list[int]] = [[] for _ in range(n_nodes)]
    for v in range(n_nodes):
        if parent[v] >= 0:
            children[parent[v]].append(v)
    up = sp.triu(Gp, k=1, format="csr")
    struct: list[NDArray[np.int64] | None] = [None] * n_nodes
    for j in range(n_nodes):
        parts = [up.indices[up.indptr[j]:up.indptr[j + 1]].astype(np.int64)]
        for c in children[j]:
            sc = struct[c]          # children come first in the postorder
            assert sc is not None
            parts.append(sc[sc > j])
        struct[j] = np.unique(np.concatenate(parts)) if len(parts) > 1 else np.sort(parts[0])
    # fundamental supernodes: j joins j + 1 when j + 1 is its parent and struct(j) = {j + 1} + struct(j + 1)
    psizes = sizes[node_order]
    sn_of = np.zeros(n_nodes, np.int64)
    starts = [0]
    for j in range(1, n_nodes):
        prev = j - 1
        if not (parent[prev] == j and struct[prev].size == struct[j].size + 1   # type: ignore[union-attr]
                and len(children[j]) == 1):
            starts.append(j)
    starts.append(n_nodes)
    sn = [(starts[k], starts[k + 1]) for k in range(len(starts) - 1)]
    # relaxed amalgamation: merge a supernode into its parent supernode when the parent starts right
    # after it (its last child) and the merged front stays small; explicit zeros are cheap, Python calls are not
    node_start = np.concatenate([[0], np.cumsum(psizes)])
    merged: list[tuple[int, int]] = []
    rows_nodes: list[NDArray[np.int64]] = []
    for a, b in sn:
        r = struct[b - 1]
        assert r is not None
        if merged:
            pa, pb = merged[-1]
            pr = rows_nodes[-1]
            # previous supernode [pa, pb) is a child of this one if its last node's parent is in [a, b)
            if pb == a and a <= parent[pb - 1] < b:
                cols = node_start[b] - node_start[pa]
                true_nz = (node_start[pb] - node_start[pa]) * (node_start[pb] - node_start[pa] + 1) // 2 + \
                    (node_start[pb] - node_start[pa]) * int(psizes[pr].sum()) + \
                    (node_start[b] - node_start[a]) * (node_start[b] - node_start[a] + 1) // 2 + \
                    (node_start[b] - node_start[a]) * int(psizes[r].sum())
                new_nz = cols * (cols + 1) // 2 + cols * int(psizes[r].sum())
                if cols <= AMALGAMATE_COLUMNS and new_nz - true_nz <= AMALGAMATE_ZEROS * new_nz:
                    merged[-1] = (pa, b)
                    rows_nodes[-1] = r
                    continue
        merged.append((a, b))
        rows_nodes.append(r)
    for k, (a, b) in enumerate(merged):
        sn_of[a:b] = k
    sn_parent = np.full(len(merged), -1, np.int64)
    for k, (_a, b) in enumerate(merged):
        p = parent[b - 1]
        sn_parent[k] = sn_of[p] if p >= 0 else -1
    perm = np.concatenate([np.arange(node_ptr[v], node_ptr[v + 1]) for v in node_order]).astype(np.int64) \
        if n_nodes else np.zeros(0, np.int64)
    sn_nodes = [np.arange(a, b) for a, b in merged]
    sn_cols = [np.array([node_start[a], node_start[b]]) for a, b in merged]
    sn_rows = [np.concatenate([np.arange(node_start[v], node_start[v + 1]) for v in r]).astype(np.int64)
               if r.size else np.zeros(0, np.int64) for r in rows_nodes]
    assert perm.size == n
    return SymbolicFactor(perm, node_order, node_ptr, sn_nodes, sn_cols, sn_rows, sn_parent)


def selected_inverse(S: sp.spmatrix, sym: SymbolicFactor, want_rows: NDArray[np.int64],
                     want_cols: NDArray[np.int64], max_scaled_variance: float = np.inf) -> NDArray[np.float64]:
    """Entries ``Z[want_rows, want_cols]`` of ``Z = S^-1`` (original indices); each must lie on the factor's pattern.

    ``S`` is factorised (multifrontal, on ``sym``'s supernodes) and Takahashi's equations are
    walked from the root down (module docstring). Pass a Jacobi-scaled ``S`` (unit diagonal) with
    ``max_scaled_variance`` to test the datum: a diagonal entry of ``Z`` above it means ``S`` is
    numerically singular.

    Raises
    ------
    DatumDefectError
        ``S`` is not positive definite, or numerically singular.
    ValueError
        A wanted entry is not on the factor's pattern.
    """
    n = sym.n
    perm = sym.perm
    iperm = np.empty(n, np.int64)
    iperm[perm] = np.arange(n)
    Sp = sp.csc_matrix(sp.csr_matrix(S)[perm][:, perm])
    Sp = sp.tril(Sp, format="csc")
    Sp.sort_indices()
    n_sn = len(sym.sn_cols)
    fronts = [np.concatenate([np.arange(c[0], c[1]), r]) for c, r in zip(sym.sn_cols, sym.sn_rows)]
    fpos = np.full(n, -1, np.int64)
    L_JJ: list = [None] * n_sn
    L_RJ: list = [None] * n_sn
    updates: dict[int, NDArray] = {}
    children: list[list[int]] = [[] for _ in range(n_sn)]
    for k in range(n_sn):
        if sym.sn_parent[k] >= 0:
            children[sym.sn_parent[k]].append(k)
    # --- multifrontal Cholesky, supernodes in (post)order ----------------------------------------------
    for k in range(n_sn):
        c0, c1 = int(sym.sn_cols[k][0]), int(sym.sn_cols[k][1])
        front = fronts[k]
        m, nj = front.size, c1 - c0
        fpos[front] = np.arange(m)
        F = np.zeros((m, m))
        lo, hi = Sp.indptr[c0], Sp.indptr[c1]
        rows = Sp.indices[lo:hi]
        cols = np.repeat(np.arange(c0, c1), np.diff(Sp.indptr[c0:c1 + 1]))
        fr = fpos[rows]
        if np.any(fr < 0):   # the symbolic structure must hold every entry of S
            raise RuntimeError(f"selected inverse: an entry of S lies outside supernode {k}'s front")
        F[fr, fpos[cols]] = Sp.data[lo:hi]
        for c in children[k]:
            U = updates.pop(c)
            pos = fpos[sym.sn_rows[c]]
            F[np.ix_(pos, pos)] += U
        fpos[front] = -1
        try:
            Ljj = sla.cholesky(F[:nj, :nj], lower=True, check_finite=False)
        except np.linalg.LinAlgError:
            raise DatumDefectError(f"the normal matrix at the solution is not positive definite (supernode {k} of "
                                   f"{n_sn}, columns {c0}-{c1} of {n}); the datum is not defined or a parameter is "
                                   f"not determined") from None
        if not np.all(np.isfinite(np.diag(Ljj))) or np.any(np.diag(Ljj) <= 0.0):
            raise DatumDefectError(f"the normal matrix at the solution is not positive definite (supernode {k})")
        L_JJ[k] = Ljj
        if m > nj:
            # L_RJ = F_RJ L_JJ^-T, the update of the rows below: F_RR - L_RJ L_RJ^T
            Lrj = sla.solve_triangular(Ljj, F[nj:, :nj].T, lower=True, check_finite=False).T
            L_RJ[k] = Lrj
            if sym.sn_parent[k] >= 0:
                # a copy of the update block, not a view: the front (m x m) is freed now, not when the
                # parent is assembled (the pending fronts were most of the peak memory)
                U = F[nj:, nj:] - Lrj @ Lrj.T
                updates[k] = U
        else:
            L_RJ[k] = np.zeros((0, nj))
        del F
    # --- wanted entries, grouped by the supernode of the lower-numbered (new) index --------------------
    wr = iperm[np.asarray(want_rows, np.int64)]
    wc = iperm[np.asarray(want_cols, np.int64)]
    lo_idx, hi_idx = np.minimum(wr, wc), np.maximum(wr, wc)
    col_sn = np.empty(n, np.int64)
    for k, c in enumerate(sym.sn_cols):
        col_sn[c[0]:c[1]] = k
    owner = col_sn[lo_idx]
    order = np.argsort(owner, kind="stable")
    bounds = np.searchsorted(owner[order], np.arange(n_sn + 1))
    out = np.empty(wr.size)
    # --- Takahashi's equations from the root down --------------------------------------------------------
    Zf: dict[int, NDArray] = {}
    pending = np.array([len(ch) for ch in children])
    worst = 0.0
    for k in range(n_sn - 1, -1, -1):
        Ljj, Lrj = L_JJ[k], L_RJ[k]
        L_JJ[k] = L_RJ[k] = None                 # the factor is freed as the walk goes down
        nj = Ljj.shape[0]
        front = fronts[k]
        Linv = sla.solve_triangular(Ljj, np.eye(nj), lower=True, check_finite=False)
        if Lrj.shape[0]:
            p = sym.sn_parent[k]
            pf = fronts[p]
            pos = np.searchsorted(pf, sym.sn_rows[k])
            Zrr = Zf[p][np.ix_(pos, pos)]
            Zrj = -(Zrr @ Lrj) @ Linv
            Zjj = Linv.T @ (Linv - Lrj.T @ Zrj)
            pending[p] -= 1
            if pending[p] == 0:
                del Zf[p]
            Z = np.empty((front.size, front.size))
            Z[nj:, nj:] = Zrr
            Z[nj:, :nj] = Zrj
            Z[:nj, nj:] = Zrj.T
        else:
            Zjj = Linv.T @ Linv
            Z = np.empty((nj, nj))
        Zjj = 0.5 * (Zjj + Zjj.T)
        Z[:nj, :nj] = Zjj
        dz = np.diag(Zjj)
        worst = max(worst, float(dz.max())) if np.all(np.isfinite(dz)) else np.inf
        if not (worst <= max_scaled_variance):
            raise DatumDefectError(
                f"the normal matrix at the solution is numerically singular (Jacobi-scaled inverse diagonal "
                f"{worst:.1e} > {max_scaled_variance:.0e}): the datum is not defined or a parameter is not determined")
        sel = order[bounds[k]:bounds[k + 1]]
        if sel.size:
            c0 = int(sym.sn_cols[k][0])
            pi = np.searchsorted(front, hi_idx[sel])
            if np.any(pi >= front.size) or np.any(front[np.minimum(pi, front.size - 1)] != hi_idx[sel]):
                raise ValueError("a wanted entry of the inverse is not on the pattern of the Cholesky factor")
            out[sel] = Z[pi, lo_idx[sel] - c0]
        if pending[k] > 0:
            Zf[k] = Z
    return out
