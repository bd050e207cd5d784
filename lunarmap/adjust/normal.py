"""Normal equations of the bundle adjustment: residuals, Jacobians, Schur-reduced system, back-substitution.

Shared by the solver (:mod:`.solver`), the posterior precision (:mod:`.precision`) and the result
(:mod:`.result`), so that none of them imports another's internals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from .problem import BundleProblem
from .schur import SchurStructure, inv_sym3, normal_blocks, whiten
from .timing import phase

__all__ = ["AdjustmentState", "Linearization", "Terms", "linearize", "reduced_system", "back_substitute",
           "evaluate_cost", "image_residuals", "prior_terms", "split_extra", "term_linearize", "term_residuals",
           "full_design", "full_system"]


@dataclass
class AdjustmentState:
    """Current unknowns (image parameters, points, extra parameters) and weights."""

    cam_params: NDArray[np.float64]
    points: NDArray[np.float64]
    extra: NDArray[np.float64]
    obs_weight: NDArray[np.float64]
    iteration: int = 0
    cost: float = np.nan


@dataclass
class Linearization:
    """Whitened residuals and Jacobian blocks at one state (also used by the precision module)."""

    r: NDArray            # (n_obs, 2) whitened image residuals
    Ac: NDArray           # (n_obs, 2, p)
    Ap: NDArray           # (n_obs, 2, 3)
    U: NDArray            # (n_cam, p, p)
    V: NDArray            # (n_pt, 3, 3)
    W: NDArray | None     # (n_obs, p, 3); None on the compiled path (formed on the fly from Ac, Ap)
    gc: NDArray           # (n_cam * p,)
    gp: NDArray           # (n_pt, 3)
    rx: NDArray           # (m,) whitened camera-level residuals
    Jx: sp.csr_matrix | None
    Nx: sp.csr_matrix | None
    gx: NDArray           # (n_red,)
    cost: float
    prior_r: NDArray | None = None
    #: rows of the point-observing terms (reference DTMs): their rows in ``rx``, points and whitened partials (m, 3)
    xp_rows: NDArray | None = None
    xp_idx: NDArray | None = None
    xp_J: NDArray | None = None


def prior_terms(problem: BundleProblem, points: NDArray):
    """Weighted control points: indices (k,), whitened residuals ``W (X - xyz)`` (k, 3) and ``W`` (k, 3, 3).

    ``W^T W`` is the inverse covariance of each control point (diagonal for per-axis sigma, full
    for correlated priors such as lat/lon/h control converted to body-fixed XYZ).
    """
    pr = problem.priors
    if pr is None:
        return None
    m = ~pr.fixed
    idx = pr.idx[m]
    W = pr.sqrt_weight()[m]
    return idx, np.einsum("kij,kj->ki", W, points[idx] - pr.xyz[m]), W


def term_linearize(t, cam_params: NDArray, extra: NDArray, points: NDArray):
    """``(r, J, Jp)`` of a term: whitened residuals, Jacobian on the reduced unknowns, and for terms that
    observe points (``uses_points``, e.g. :class:`~lunarmap.adjust.terrain.DtmHeights`) the whitened partials
    ``(m, 3)`` w.r.t. the point of every row (``t.point_index``); ``Jp`` is None for camera-level terms."""
    if getattr(t, "uses_points", False):
        return t.linearize(cam_params, extra, points)
    r, J = t.linearize(cam_params, extra)
    return r, J, None


def term_residuals(t, cam_params: NDArray, extra: NDArray, points: NDArray) -> NDArray:
    """Whitened residuals of a term (see :func:`term_linearize`)."""
    return term_linearize(t, cam_params, extra, points)[0]


def image_residuals(problem: BundleProblem, state: AdjustmentState) -> NDArray:
    o = problem.obs
    m = problem.model
    if hasattr(m, "project_indexed"):
        x = m.project_indexed(state.cam_params, o.cam_idx, state.points, o.pt_idx)
    else:
        x = m.project(state.cam_params, o.cam_idx, state.points[o.pt_idx])
    return (x - o.xy) * (np.sqrt(state.obs_weight)[:, None] / o.sigma)


def evaluate_cost(problem: BundleProblem, state: AdjustmentState) -> float:
    """Half the weighted sum of squared residuals of all observations."""
    r = image_residuals(problem, state)
    c = float(np.sum(r * r))
    pt = prior_terms(problem, state.points)
    if pt is not None:
        c += float(np.sum(pt[1] ** 2))
    for t, e in zip(problem.terms, split_extra(problem, state.extra)):
        rx = term_residuals(t, state.cam_params, e, state.points)
        c += float(rx @ rx)
    return 0.5 * c


def split_extra(problem, extra):
    out, s = [], 0
    for t in problem.terms:
        out.append(extra[s:s + t.n_extra])
        s += t.n_extra
    return out


class Terms:
    """Concatenates the camera-level terms into one whitened residual vector and Jacobian."""

    def __init__(self, problem: BundleProblem):
        self.problem = problem
        self.n_cam_red = problem.n_images * problem.model.n_params
        self.n_extra = sum(t.n_extra for t in problem.terms)
        #: some term's rows couple several points, or points with reduced unknowns (laser altimetry): the
        #: point blocks are not independent and the normal equations are solved whole (:func:`full_system`)
        self.coupled = any(getattr(t, "couples_points", False) for t in problem.terms)

    def linearize(self, cam_params, extra, points=None):
        """Whitened residuals, Jacobian on the reduced unknowns, and the point partials of point-observing
        terms as ``(rows, point index, (m, 3))`` (None if there are none)."""
        if not self.problem.terms:
            return np.zeros(0), None, None
        rs, Js, s = [], [], 0
        xp: list[tuple[NDArray, NDArray, NDArray]] = []
        row0 = 0
        for t in self.problem.terms:
            r, J, Jp = term_linearize(t, cam_params, extra[s:s + t.n_extra], points)
            if Jp is not None:
                pi, Jp = np.asarray(t.point_index, np.int64), np.asarray(Jp, float)
                rows = row0 + np.arange(r.size)
                if pi.ndim == 2:
                    # a row observing several points (laser altimetry: the triangle's vertices): one entry each
                    rows, pi, Jp = np.repeat(rows, pi.shape[1]), pi.reshape(-1), Jp.reshape(-1, 3)
                xp.append((rows, pi, Jp))
            row0 += r.size
            # each term's Jacobian uses [cams | its own extras]; map its extras to the global slot
            J = sp.csr_matrix(J)
            Jc = J[:, :self.n_cam_red]
            Je = J[:, self.n_cam_red:]
            pad_l = sp.csr_matrix((J.shape[0], s))
            pad_r = sp.csr_matrix((J.shape[0], self.n_extra - s - t.n_extra))
            Js.append(sp.hstack([Jc, pad_l, Je, pad_r], format="csr"))
            rs.append(r)
            s += t.n_extra
        pts = None if not xp else tuple(np.concatenate(a) for a in zip(*xp))
        return np.concatenate(rs), sp.vstack(Js, format="csr"), pts


def _model_linearize(problem: BundleProblem, state: AdjustmentState):
    o = problem.obs
    m = problem.model
    if hasattr(m, "linearize_indexed"):  # no (n_obs, 3) gather of the points
        return m.linearize_indexed(state.cam_params, o.cam_idx, state.points, o.pt_idx)
    return m.linearize(state.cam_params, o.cam_idx, state.points[o.pt_idx])


def linearize(problem: BundleProblem, state: AdjustmentState, structure: SchurStructure, terms: Terms,
              fixed_pt: NDArray) -> Linearization:
    """Residuals, Jacobians and normal-equation blocks at ``state`` (all observations at once)."""
    o = problem.obs
    with phase("jacobians"):
        x, Jc, Jp = _model_linearize(problem, state)
    with phase("whiten"):
        ws = np.sqrt(state.obs_weight)[:, None] / o.sigma        # (n, 2) sqrt of weights
        # whitened in place (fresh, writable, contiguous float arrays from the model; copied otherwise)
        Ac = np.require(Jc, np.float64, ["C", "W"])
        Ap = np.require(Jp, np.float64, ["C", "W"])
        assert problem.cam_param_free is not None      # set by BundleProblem.__post_init__
        r, cost = whiten(np.ascontiguousarray(x, np.float64), o.xy, ws, Ac, Ap, problem.cam_param_free, fixed_pt,
                         structure.cam_idx, structure.pt_idx)
    with phase("normal_blocks"):
        U, V, W, gc, gp = normal_blocks(Ac, Ap, r, structure.cam_idx, structure.pt_idx, structure.n_cam,
                                        structure.n_pt, want_W=not structure.compiled)
    gc = gc.ravel()
    pt = prior_terms(problem, state.points)
    if pt is not None:
        idx, rr, Wp = pt
        np.add.at(V, idx, np.einsum("kji,kjl->kil", Wp, Wp))
        np.add.at(gp, idx, np.einsum("kji,kj->ki", Wp, rr))
        cost += float(np.sum(rr * rr))
    rx, Jx, xp = terms.linearize(state.cam_params, state.extra, state.points)
    if xp is not None:
        # point-only rows (reference DTM heights): rank-1 additions to the point blocks, like control points;
        # the diagonal blocks of rows coupling several points (altimetry) alike (their cross blocks: full_system)
        rows, idx, Jp = xp
        np.add.at(V, idx, Jp[:, :, None] * Jp[:, None, :])
        np.add.at(gp, idx, Jp * rx[rows][:, None])
    # fixed points: identity placeholder keeps V invertible; they do not move
    V[fixed_pt] = np.eye(3)
    gp[fixed_pt] = 0.0
    n_red = terms.n_cam_red + terms.n_extra
    if Jx is not None:
        Nx = (Jx.T @ Jx).tocsr()
        gx = Jx.T @ rx
        cost += float(rx @ rx)
    else:
        Nx, gx = None, np.zeros(n_red)
    return Linearization(r, Ac, Ap, U, V, W, gc, gp, rx, Jx, Nx, gx, 0.5 * cost,
                         pt[1] if pt is not None else None, *(xp if xp is not None else (None, None, None)))


def reduced_system(lin: Linearization, structure: SchurStructure, terms: Terms, mu: float, free_red: NDArray):
    """Damped reduced camera system.

    Returns ``S`` (CSR, free unknowns only), its right-hand side, the damped point inverses
    ``(V + mu D_p)^-1 (n_pt, 3, 3)`` and the damping diagonal ``D`` of the reduced unknowns
    (all of them, free or not; the damping added is ``mu * D``).
    """
    p = structure.p
    if structure.compiled:
        with phase("schur_complement"):
            blocks, Fg, Vinv = structure.schur(lin.U, lin.V, lin.Ac, lin.Ap, lin.gp, mu)
        rhs_c = -lin.gc + Fg.ravel()
    else:
        assert lin.W is not None        # formed on the NumPy path
        V = lin.V.copy()
        dV = np.clip(np.diagonal(lin.V, axis1=1, axis2=2), 1e-6, 1e32)
        V[:, [0, 1, 2], [0, 1, 2]] += mu * dV
        Vinv = inv_sym3(V)
        F = np.matmul(lin.W, Vinv[structure.pt_of_obs])                               # W_i V_j^-1, (n_obs, p, 3)
        # Schur complement S = U - W V^-1 W^T (pair blocks), rhs = -g_c + W V^-1 g_p
        blocks = -structure.pair_blocks(F, lin.W)
        blocks[structure.diag_block] += lin.U
        Fg = np.einsum("nij,nj->ni", F, lin.gp[structure.pt_of_obs])
        rhs_c = -lin.gc + (structure.cam_agg @ Fg).ravel()
    n_cam_red = terms.n_cam_red
    diag = np.zeros(n_cam_red + terms.n_extra)
    diag[:n_cam_red] = np.diagonal(lin.U, axis1=1, axis2=2).ravel()
    if lin.Nx is not None:
        diag += lin.Nx.diagonal()
    D = np.clip(diag, 1e-6, 1e32)
    rhs = np.concatenate([rhs_c, np.zeros(terms.n_extra)]) - lin.gx
    if not terms.n_extra and lin.Nx is None:
        # camera damping straight into the diagonal blocks: no sparse sum
        if mu != 0.0:
            db = blocks[structure.diag_block]
            db[:, np.arange(p), np.arange(p)] += mu * D.reshape(-1, p)
            blocks[structure.diag_block] = db
        with phase("assemble_S"):
            S = structure.assemble(blocks)
    else:
        S = structure.assemble(blocks)
        if terms.n_extra:
            S = sp.bmat([[S, None], [None, sp.csr_matrix((terms.n_extra, terms.n_extra))]], format="csr")
        if lin.Nx is not None:
            S = (S + lin.Nx).tocsr()
        S = (S + sp.diags(mu * D)).tocsr()
    if not free_red.all():
        idx = np.nonzero(free_red)[0]
        S = S[idx][:, idx]
        rhs = rhs[idx]
    return S, rhs, Vinv, D


def back_substitute(lin: Linearization, structure: SchurStructure, Vinv: NDArray, dred: NDArray, terms: Terms,
                    problem: BundleProblem) -> NDArray:
    """Point corrections ``dp_j = V_j^-1 (-g_p,j - sum_i W_i^T dc_cam(i))``, ``(n_pt, 3)``."""
    p = structure.p
    o = problem.obs
    dc = dred[:terms.n_cam_red].reshape(-1, p)
    if structure.compiled:
        return structure.back_substitute(lin.Ac, lin.Ap, Vinv, lin.gp, dc)
    assert lin.W is not None        # formed on the NumPy path
    Wdc = np.einsum("nij,ni->nj", lin.W, dc[o.cam_idx])
    t = -lin.gp - structure.pt_agg @ Wdc
    return np.einsum("nij,nj->ni", Vinv, t)


def full_design(lin: Linearization, problem: BundleProblem, terms: Terms, fixed_pt: NDArray):
    """The whole whitened Jacobian ``A`` (CSR, columns ``[reduced unknowns | 3 n_pt point coordinates]``) and
    residuals ``r`` of all rows: image coordinates (2 per measurement), term rows, weighted control points (3 each).

    For problems whose terms couple points (:attr:`Terms.coupled`); fixed points' columns are zero.
    """
    o = problem.obs
    n_red = terms.n_cam_red + terms.n_extra
    n_pt = problem.n_points
    p = lin.Ac.shape[2]
    n = o.n
    rows_i = np.arange(2 * n).reshape(n, 2)
    Ai_r = np.broadcast_to(rows_i[:, :, None], (n, 2, p + 3))
    Ai_c = np.concatenate([np.broadcast_to((o.cam_idx[:, None] * p + np.arange(p))[:, None, :], (n, 2, p)),
                           np.broadcast_to((n_red + 3 * o.pt_idx[:, None] + np.arange(3))[:, None, :], (n, 2, 3))],
                          axis=2)
    Ai_v = np.concatenate([lin.Ac, lin.Ap], axis=2)
    parts_r, parts_c, parts_v = [Ai_r.ravel()], [Ai_c.ravel()], [Ai_v.ravel()]
    res = [lin.r.ravel()]
    row0 = 2 * n
    m_t = lin.rx.size
    if m_t:
        if lin.Jx is not None:
            Jx = sp.coo_matrix(lin.Jx)
            parts_r.append(row0 + Jx.row)
            parts_c.append(Jx.col)
            parts_v.append(Jx.data)
        if lin.xp_rows is not None and lin.xp_idx is not None and lin.xp_J is not None:
            keep = ~fixed_pt[lin.xp_idx]
            parts_r.append(np.repeat(row0 + lin.xp_rows[keep], 3))
            parts_c.append((n_red + 3 * lin.xp_idx[keep][:, None] + np.arange(3)).ravel())
            parts_v.append(lin.xp_J[keep].ravel())
        res.append(lin.rx)
        row0 += m_t
    if lin.prior_r is not None and problem.priors is not None:
        pr = problem.priors
        m = ~pr.fixed
        idx = pr.idx[m]
        W = pr.sqrt_weight()[m]
        k = idx.size
        rr = np.broadcast_to((row0 + np.arange(3 * k).reshape(k, 3))[:, :, None], (k, 3, 3))
        cc = np.broadcast_to((n_red + 3 * idx[:, None] + np.arange(3))[:, None, :], (k, 3, 3))
        parts_r.append(rr.ravel())
        parts_c.append(cc.ravel())
        parts_v.append(W.ravel())
        res.append(lin.prior_r.ravel())
        row0 += 3 * k
    A = sp.csr_matrix((np.concatenate(parts_v), (np.concatenate(parts_r), np.concatenate(parts_c))),
                      shape=(row0, n_red + 3 * n_pt))
    A.sum_duplicates()
    return A, np.concatenate(res)


def full_system(lin: Linearization, problem: BundleProblem, terms: Terms, mu: float, free_red: NDArray,
                fixed_pt: NDArray):
    """Damped normal equations of all unknowns (reduced and points) for coupled terms (:attr:`Terms.coupled`).

    Returns ``N + mu D`` (CSR, free unknowns only: ``free_red`` then the free points' coordinates), its
    right-hand side ``-g``, the damping diagonal of the reduced unknowns (all of them) and the free mask of
    the whole vector. The points are not eliminated (their blocks are coupled by the terms' rows); the size
    is ``n_red + 3 n_pt``: blocks of a few thousand unknowns.
    """
    A, r = full_design(lin, problem, terms, fixed_pt)
    N = (A.T @ A).tocsr()
    g = A.T @ r
    free = np.concatenate([free_red, np.repeat(~fixed_pt, 3)])
    diag = N.diagonal()
    D = np.clip(diag, 1e-6, 1e32)
    if mu != 0.0:
        N = (N + sp.diags(mu * D)).tocsr()
    idx = np.flatnonzero(free)
    return N[idx][:, idx].tocsr(), -g[idx], D[:free_red.size], free
