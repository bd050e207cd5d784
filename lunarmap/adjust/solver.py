"""Levenberg-Marquardt bundle adjustment on the Schur-reduced sparse normal equations.

One iteration (DLR paper, ``seeds/004``, Eq. 4: Gauss-Markov least squares of
the linearised collinearity and navigation observation equations, Eqs. 1-3):

1. whitened residuals and analytic Jacobians of every image observation at once
   (one compiled pass for frame cameras, :mod:`.collinearity`);
2. camera blocks ``U``, point blocks ``V``, cross blocks ``W`` and gradients, one
   compiled pass (:func:`.schur.normal_blocks`);
3. LM damping ``N + mu diag(N)`` (Marquardt scaling, the trust-region update
   of Nielsen as used by Ceres), point elimination (:meth:`.schur.SchurStructure.schur`)
   and a sparse Cholesky of the reduced camera system whose symbolic analysis is
   done once per adjustment (:class:`.factor.Factorizer`), back-substitution of the points;
4. the step is accepted if the cost decreases; the damping adapts from the
   ratio of actual to predicted decrease (the prediction ``(mu d^T D d - g^T d) / 2``
   needs no pass over the observations).

Convergence: relative cost decrease below ``ftol`` (equivalently, relative change
of sigma0^2), step norm below ``xtol`` times the parameter norm, or the maximum
number of iterations.

Weights may change between iterations: ``reweight(state)`` is called after each
accepted step and may return new per-observation weight factors
(robust/Danish reweighting); the cost is then re-evaluated with them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from ..errors import AdjustmentDivergedError, DatumDefectError
from .factor import Factorizer
from .problem import BundleProblem
from .schur import SchurStructure, inv_sym3, normal_blocks, whiten

__all__ = ["SolverOptions", "AdjustmentState", "Linearization", "solve", "linearize", "evaluate_cost"]


@dataclass
class SolverOptions:
    """Iteration controls.

    ``ftol``: relative cost decrease that stops the iteration (Ceres' function tolerance);
    ``xtol``: relative step size that stops it; ``max_iterations``: accepted + rejected steps;
    ``initial_mu``: initial Marquardt damping (1 / Ceres' initial trust-region radius);
    ``min_mu``: smallest damping (1 / Ceres' maximum trust-region radius);
    ``backend``: sparse factorisation (:func:`lunarmap.adjust.factor.factorize`);
    ``compiled``: use the numba kernels for the normal blocks and the Schur complement when numba is
    installed (``False`` forces the numpy path, for testing).
    """

    ftol: float = 1e-6
    xtol: float = 1e-8
    max_iterations: int = 100
    initial_mu: float = 1e-4
    min_mu: float = 1e-16
    backend: str = "auto"
    compiled: bool = True
    verbose: bool = False
    check_datum: bool = True


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


def _prior_terms(problem: BundleProblem, points: NDArray):
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


def _image_residuals(problem: BundleProblem, state: AdjustmentState) -> NDArray:
    o = problem.obs
    m = problem.model
    if hasattr(m, "project_indexed"):
        x = m.project_indexed(state.cam_params, o.cam_idx, state.points, o.pt_idx)
    else:
        x = m.project(state.cam_params, o.cam_idx, state.points[o.pt_idx])
    return (x - o.xy) * (np.sqrt(state.obs_weight)[:, None] / o.sigma)


def evaluate_cost(problem: BundleProblem, state: AdjustmentState) -> float:
    """Half the weighted sum of squared residuals of all observations."""
    r = _image_residuals(problem, state)
    c = float(np.sum(r * r))
    pt = _prior_terms(problem, state.points)
    if pt is not None:
        c += float(np.sum(pt[1] ** 2))
    for t, e in zip(problem.terms, _split_extra(problem, state.extra)):
        rx, _ = t.linearize(state.cam_params, e)
        c += float(rx @ rx)
    return 0.5 * c


def _split_extra(problem, extra):
    out, s = [], 0
    for t in problem.terms:
        out.append(extra[s:s + t.n_extra])
        s += t.n_extra
    return out


class _Terms:
    """Concatenates the camera-level terms into one whitened residual vector and Jacobian."""

    def __init__(self, problem: BundleProblem):
        self.problem = problem
        self.n_cam_red = problem.n_images * problem.model.n_params
        self.n_extra = sum(t.n_extra for t in problem.terms)

    def linearize(self, cam_params, extra):
        if not self.problem.terms:
            return np.zeros(0), None
        rs, Js, s = [], [], 0
        for t in self.problem.terms:
            r, J = t.linearize(cam_params, extra[s:s + t.n_extra])
            # each term's Jacobian uses [cams | its own extras]; map its extras to the global slot
            J = sp.csr_matrix(J)
            Jc = J[:, :self.n_cam_red]
            Je = J[:, self.n_cam_red:]
            pad_l = sp.csr_matrix((J.shape[0], s))
            pad_r = sp.csr_matrix((J.shape[0], self.n_extra - s - t.n_extra))
            Js.append(sp.hstack([Jc, pad_l, Je, pad_r], format="csr"))
            rs.append(r)
            s += t.n_extra
        return np.concatenate(rs), sp.vstack(Js, format="csr")


def _model_linearize(problem: BundleProblem, state: AdjustmentState):
    o = problem.obs
    m = problem.model
    if hasattr(m, "linearize_indexed"):  # no (n_obs, 3) gather of the points
        return m.linearize_indexed(state.cam_params, o.cam_idx, state.points, o.pt_idx)
    return m.linearize(state.cam_params, o.cam_idx, state.points[o.pt_idx])


def linearize(problem: BundleProblem, state: AdjustmentState, structure: SchurStructure, terms: _Terms,
              fixed_pt: NDArray) -> Linearization:
    """Residuals, Jacobians and normal-equation blocks at ``state`` (all observations at once)."""
    o = problem.obs
    x, Jc, Jp = _model_linearize(problem, state)
    ws = np.sqrt(state.obs_weight)[:, None] / o.sigma        # (n, 2) sqrt of weights
    # whitened in place (fresh, writable, contiguous float arrays from the model; copied otherwise)
    Ac = np.require(Jc, np.float64, ["C", "W"])
    Ap = np.require(Jp, np.float64, ["C", "W"])
    r, cost = whiten(np.ascontiguousarray(x, np.float64), o.xy, ws, Ac, Ap, problem.cam_param_free, fixed_pt,
                     structure.cam_idx, structure.pt_idx)
    U, V, W, gc, gp = normal_blocks(Ac, Ap, r, structure.cam_idx, structure.pt_idx, structure.n_cam,
                                    structure.n_pt, want_W=not structure.compiled)
    gc = gc.ravel()
    pt = _prior_terms(problem, state.points)
    if pt is not None:
        idx, rr, Wp = pt
        np.add.at(V, idx, np.einsum("kji,kjl->kil", Wp, Wp))
        np.add.at(gp, idx, np.einsum("kji,kj->ki", Wp, rr))
        cost += float(np.sum(rr * rr))
    # fixed points: identity placeholder keeps V invertible; they do not move
    V[fixed_pt] = np.eye(3)
    gp[fixed_pt] = 0.0
    rx, Jx = terms.linearize(state.cam_params, state.extra)
    n_red = terms.n_cam_red + terms.n_extra
    if Jx is not None:
        Nx = (Jx.T @ Jx).tocsr()
        gx = Jx.T @ rx
        cost += float(rx @ rx)
    else:
        Nx, gx = None, np.zeros(n_red)
    return Linearization(r, Ac, Ap, U, V, W, gc, gp, rx, Jx, Nx, gx, 0.5 * cost,
                         pt[1] if pt is not None else None)


def reduced_system(lin: Linearization, structure: SchurStructure, terms: _Terms, mu: float, free_red: NDArray):
    """Damped reduced camera system.

    Returns ``S`` (CSR, free unknowns only), its right-hand side, the damped point inverses
    ``(V + mu D_p)^-1 (n_pt, 3, 3)`` and the damping diagonal ``D`` of the reduced unknowns
    (all of them, free or not; the damping added is ``mu * D``).
    """
    p = structure.p
    if structure.compiled:
        blocks, Fg, Vinv = structure.schur(lin.U, lin.V, lin.Ac, lin.Ap, lin.gp, mu)
        rhs_c = -lin.gc + Fg.ravel()
    else:
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


def back_substitute(lin: Linearization, structure: SchurStructure, Vinv: NDArray, dred: NDArray, terms: _Terms,
                    problem: BundleProblem) -> NDArray:
    """Point corrections ``dp_j = V_j^-1 (-g_p,j - sum_i W_i^T dc_cam(i))``, ``(n_pt, 3)``."""
    p = structure.p
    o = problem.obs
    dc = dred[:terms.n_cam_red].reshape(-1, p)
    if structure.compiled:
        return structure.back_substitute(lin.Ac, lin.Ap, Vinv, lin.gp, dc)
    Wdc = np.einsum("nij,ni->nj", lin.W, dc[o.cam_idx])
    t = -lin.gp - structure.pt_agg @ Wdc
    return np.einsum("nij,nj->ni", Vinv, t)


def _model_decrease(lin: Linearization, mu: float, D: NDArray, dred: NDArray, dp: NDArray) -> float:
    """Predicted cost decrease of the linear model, ``L(0) - L(delta)``.

    For the exact solution of ``(N + mu D) delta = -g`` this is ``(mu delta^T D delta - g^T delta) / 2``:
    no pass over the observations.
    """
    g_red = lin.gx.copy()
    g_red[:lin.gc.size] += lin.gc
    Dp = np.clip(np.diagonal(lin.V, axis1=1, axis2=2), 1e-6, 1e32)
    quad = float(D @ (dred * dred)) + float(np.sum(Dp * dp * dp))
    lin_term = float(g_red @ dred) + float(np.sum(lin.gp * dp))
    return 0.5 * (mu * quad - lin_term)


def solve(problem: BundleProblem, options: SolverOptions | None = None,
          reweight: Callable[[AdjustmentState], NDArray | None] | None = None,
          callback: Callable[[AdjustmentState], None] | None = None):
    """Adjust ``problem``; returns an :class:`lunarmap.adjust.result.AdjustmentResult`.

    Parameters
    ----------
    problem : BundleProblem
    options : SolverOptions, optional
    reweight : callable, optional
        Called with the state after every accepted step; may return new per-observation
        weight factors ``(n_obs,)`` (1 = a-priori weight, 0 = observation removed).
    callback : callable, optional
        Called with the state after every accepted step (progress, logging).

    Raises
    ------
    DatumDefectError
        The undamped normal equations are singular (datum not defined).
    AdjustmentDivergedError
        The cost became non-finite and no step could reduce it.
    """
    from .result import AdjustmentResult

    opt = options or SolverOptions()
    t_start = time.perf_counter()
    o = problem.obs
    p = problem.model.n_params
    fixed_pt = problem.point_fixed()
    structure = SchurStructure(o.cam_idx, o.pt_idx, problem.n_images, problem.n_points, p, active_pt=~fixed_pt,
                               compiled=opt.compiled)
    factorize = Factorizer(opt.backend)
    terms = _Terms(problem)
    extra0 = np.concatenate([t.initial_extra() for t in problem.terms]) if problem.terms else np.zeros(0)
    free_red = np.concatenate([problem.cam_param_free.ravel()] +
                              [np.asarray(t.extra_free(), bool) for t in problem.terms])
    state = AdjustmentState(problem.cam_params.copy(), problem.points.copy(), extra0.copy(),
                            np.asarray(problem.obs_weight, float).copy())
    t_setup = time.perf_counter() - t_start

    # datum check on the undamped system: a singular S means an undefined datum
    lin = linearize(problem, state, structure, terms, fixed_pt)
    if not np.isfinite(lin.cost):
        raise AdjustmentDivergedError("the initial cost is not finite (a point behind a camera or at infinity?)")
    if opt.check_datum:
        S0, _, _, _ = reduced_system(lin, structure, terms, 0.0, free_red)
        _check_datum(S0, opt.backend)

    cost0 = lin.cost
    state.cost = cost0
    trace = [(time.perf_counter() - t_start, cost0)]
    mu, nu = opt.initial_mu, 2.0
    n_iter = n_accept = 0
    message = "maximum number of iterations reached"
    converged = False
    while n_iter < opt.max_iterations:
        n_iter += 1
        S, rhs, Vinv, D = reduced_system(lin, structure, terms, mu, free_red)
        try:
            solve_S = factorize(S)
        except DatumDefectError:
            # rounding made the damped system indefinite (very weak points): damp more, as for a rejected step
            if mu > 1e32:
                raise
            mu, nu = max(mu, 1e-12) * nu, 2.0 * nu
            continue
        dred = np.zeros(free_red.size)
        dred[free_red] = solve_S(rhs)
        dp = back_substitute(lin, structure, Vinv, dred, terms, problem)
        dp[fixed_pt] = 0.0
        dc = dred[:terms.n_cam_red].reshape(-1, p)
        new = AdjustmentState(state.cam_params + dc, state.points + dp, state.extra + dred[terms.n_cam_red:],
                              state.obs_weight, state.iteration + 1)
        new_cost = evaluate_cost(problem, new)
        pred = _model_decrease(lin, mu, D, dred, dp)
        actual = state.cost - new_cost
        step_norm = np.sqrt(np.sum(dred ** 2) + np.sum(dp ** 2))
        x_norm = np.sqrt(np.sum(state.cam_params ** 2) + np.sum(state.points ** 2) + np.sum(state.extra ** 2))
        if opt.verbose:
            print(f"it {n_iter:3d} cost {state.cost:.6e} -> {new_cost:.6e} mu {mu:.2e} |dx| {step_norm:.3e}")
        if np.isfinite(new_cost) and actual > 0:
            rho = actual / pred if pred > 0 else 1.0
            mu = max(mu * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), opt.min_mu)
            nu = 2.0
            old_cost = state.cost
            state = new
            state.cost = new_cost
            n_accept += 1
            trace.append((time.perf_counter() - t_start, new_cost))
            reweighted = False
            if reweight is not None:
                w = reweight(state)
                if w is not None:
                    state.obs_weight = np.asarray(w, float)
                    state.cost = evaluate_cost(problem, state)
                    reweighted = True
            if callback is not None:
                callback(state)
            if not reweighted and actual <= opt.ftol * old_cost:
                converged, message = True, f"relative cost decrease {actual / old_cost:.2e} <= ftol {opt.ftol:g}"
                break
            if not reweighted and step_norm <= opt.xtol * (x_norm + opt.xtol):
                converged, message = True, f"relative step {step_norm / max(x_norm, 1e-300):.2e} <= xtol {opt.xtol:g}"
                break
            lin = linearize(problem, state, structure, terms, fixed_pt)
        else:
            mu *= nu
            nu *= 2.0
            if step_norm <= opt.xtol * (x_norm + opt.xtol):
                converged, message = True, "step below xtol without cost decrease"
                break
            if mu > 1e32:
                message = "damping exceeded 1e32 without a cost decrease"
                break
    t_solve = time.perf_counter() - t_start
    return AdjustmentResult(problem=problem, state=state, structure=structure, cost_initial=cost0,
                            iterations=n_iter, accepted=n_accept, converged=converged, message=message,
                            trace=trace, solve_seconds=t_solve, setup_seconds=t_setup, options=opt,
                            free_red=free_red)


def _check_datum(S0: sp.csr_matrix, backend: str) -> None:
    """Raise DatumDefectError if the undamped, Jacobi-scaled reduced system is numerically singular."""
    from ..errors import DatumDefectError

    d = S0.diagonal()
    if np.any(d <= 0) or not np.all(np.isfinite(d)):
        bad = int(np.nonzero(~(d > 0))[0][0]) if np.any(~(d > 0)) else -1
        raise DatumDefectError(f"reduced unknown {bad} has no weight in the normal equations (unobserved)")
    if S0.shape[0] > 1500:
        # large systems: a rank test would cost more than the adjustment; an undefined datum then shows
        # as a non-converging, drifting solution and in the posterior precision (DatumDefectError there)
        return
    s = 1.0 / np.sqrt(d)
    Sn = sp.diags(s) @ S0 @ sp.diags(s)
    if Sn.shape[0] <= 1500:
        ev = np.linalg.eigvalsh(Sn.toarray())
        if ev[0] <= 1e-10 * ev[-1]:
            raise DatumDefectError(
                f"the normal equations are rank deficient (smallest/largest scaled eigenvalue "
                f"{ev[0] / ev[-1]:.1e}, {int(np.sum(ev <= 1e-10 * ev[-1]))} near-zero): the datum is not defined")
