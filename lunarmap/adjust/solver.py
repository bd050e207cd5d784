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
   needs no pass over the observations);
5. Anderson acceleration (``SolverOptions.acceleration_memory`` steps, :func:`_anderson`): after an
   accepted step, the multisecant combination of the last iterates and steps is evaluated once more and
   taken instead of the LM point only if its cost is lower; the history is dropped after a rejected step
   (the damping, hence the fixed-point map, changed) and after reweighting (another cost function).

Why 5: on weak geometry (base-to-height 0.03, the shared generator's blocks) Gauss-Newton itself converges
only linearly, so no damping rule gets the ~5 iterations of a small-residual problem. Measured on the
generator's 50-image block at its minimum: the eigenvalues of ``N^-1 H`` (``H`` the full Hessian, with
``sum r_i grad^2 r_i``) span 0.08..1.88 while 99 % are 1 within 1e-5; the GN error contracts by
``|1 - lambda|`` per step, 0.92 in the worst of a few hundred camera-dominated directions. The damping
is not the limit: undamped GN (mu = 1e-16 from the start) on an 800-image block takes 18 iterations to
ftol 1e-6 and 80 do not reach the minimum (rate ~0.94). Anderson's step removes those few slow
directions (it is GMRES on the linearised fixed-point map): 800 images, 15 instead of 20 iterations to
Ceres' final cost. Where steps are rejected often (a soft, curved valley: seed 2 of the same block) it
rarely applies and the iteration is plain LM.

Convergence: relative cost decrease below ``ftol`` (equivalently, relative change
of sigma0^2), step norm below ``xtol`` times the parameter norm, or the maximum
number of iterations.

Weights may change between iterations: ``reweight(state)`` is called after each
accepted step and may return new per-observation weight factors
(robust/Danish reweighting); the cost is then re-evaluated with them.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from ..blas import single_threaded_blas
from ..errors import AdjustmentDivergedError, AdjustmentInputError, DatumDefectError
from .factor import Factorizer
from .normal import (
    AdjustmentState,
    Linearization,
    Terms,
    back_substitute,
    evaluate_cost,
    full_system,
    linearize,
    reduced_system,
)
from .pcg import block_jacobi, pcg
from .problem import BundleProblem
from .schur import SchurStructure
from .timing import phase

_log = logging.getLogger(__name__)

#: PCG's relative residual (and least iteration cap) for the step that checks an inexact solve's ftol stop:
#: the cost decrease of a step solved this closely is the exact step's to a few percent
PCG_CHECK_TOLERANCE = 1e-4
PCG_CHECK_ITERATIONS = 1000

#: The datum test's bound on the smallest / largest eigenvalue of the Jacobi-scaled reduced system. A
#: missing datum gives rounding-level ratios (1e-16..1e-14); narrow-angle images of real size that only
#: their navigation observations place along the line of sight are determined at ratios of about 4e-11
#: (8 full-size LRO-NAC-like images, 0.5 m navigation sigma): the bound lies between, where Cholesky
#: in double precision still solves the system.
DATUM_EIGENVALUE_RATIO = 1e-12

__all__ = ["SolverOptions", "AdjustmentState", "Linearization", "solve", "linearize", "evaluate_cost"]


@dataclass
class SolverOptions:
    """Iteration controls.

    ``ftol``: relative cost decrease that stops the iteration (Ceres' function tolerance);
    ``xtol``: relative step size that stops it; ``max_iterations``: accepted + rejected steps;
    ``initial_mu``: initial Marquardt damping (1 / Ceres' initial trust-region radius);
    ``min_mu``: smallest damping (1 / Ceres' maximum trust-region radius);
    ``min_mu_factor``: smallest factor by which an accepted step lowers the damping (Nielsen: 1/3);
    ``acceleration_memory``: Anderson acceleration over this many previous steps (0: plain LM; module
    docstring, item 5);
    ``backend``: sparse factorisation (:func:`lunarmap.adjust.factor.factorize`);
    ``compiled``: use the numba kernels for the normal blocks and the Schur complement when numba is
    installed (``False`` forces the numpy path, for testing);
    ``linear_solver``: how the damped reduced camera system is solved each iteration: ``"direct"`` (sparse
    Cholesky, ``backend``), ``"pcg"`` (iterative Schur, :mod:`.pcg`: conjugate gradients with the
    per-image block-Jacobi preconditioner to the relative residual ``pcg_tolerance``, at most
    ``pcg_max_iterations`` CG iterations; the LM acceptance uses the model decrease of the inexact step, and
    an ftol stop after an inexact step is confirmed by a step solved to :data:`PCG_CHECK_TOLERANCE`) or
    ``"auto"`` (``"pcg"`` from ``pcg_min_images`` images on, else ``"direct"``; by default always
    ``"direct"``). Blocks whose terms couple points (laser altimetry) are always solved directly. The
    posterior precision does not depend on this choice (:mod:`.precision` factorises the undamped system
    itself).
    """

    ftol: float = 1e-6
    xtol: float = 1e-8
    max_iterations: int = 100
    initial_mu: float = 1e-4
    min_mu: float = 1e-16
    #: smallest factor by which one accepted step lowers the damping (Nielsen's rule gives 1/3 at rho = 1)
    min_mu_factor: float = 1.0 / 3.0
    backend: str = "auto"
    compiled: bool = True
    verbose: bool = False   # log every iteration at INFO (else DEBUG) on the 'lunarmap.adjust.solver' logger
    check_datum: bool = True
    #: progress: log an iteration (cost, sigma0, step) at INFO when this many seconds passed since the last
    #: such line of any solve in this process (0: every iteration); None: only with ``verbose``
    progress: float | None = None
    #: Anderson acceleration of the accepted steps: number of previous steps combined (0: plain LM); see
    #: :func:`_anderson` for the rule and why
    acceleration_memory: int = 5
    #: "auto" | "direct" | "pcg" (see the class docstring)
    linear_solver: str = "auto"
    #: relative residual (preconditioned norm) at which CG stops: the inexact-Newton forcing term. 0.1 (Ceres'
    #: default eta) measured best on the 4,000-image block: 31 LM iterations against 37-40 at 1e-2..1e-3 and
    #: 38 for the direct solver, the same final cost (docs/SCALING.md)
    pcg_tolerance: float = 0.1
    pcg_max_iterations: int = 1000
    #: "auto" takes "pcg" from this many images on; None: "auto" is always "direct". Measured (docs/SCALING.md,
    #: "Where an LM iteration's time goes"): at the default tolerance PCG ties the direct solver on a
    #: 4,000-image strip block (0.95-1.03x its CPU per solve) and larger blocks are not measured to
    #: convergence yet, so no threshold is set
    pcg_min_images: int | None = None


_last_progress = [0.0]     # time of the last progress line (shared by consecutive solves: QC rounds)


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


def _anderson(xs: list[NDArray], ds: list[NDArray], w: NDArray) -> NDArray | None:
    """Anderson-accelerated point from the iterates ``xs`` and their LM steps ``ds`` (last = current).

    The LM iteration is the fixed-point map ``x -> x + d(x)``. On weak geometry it converges only
    linearly even undamped: near the optimum the error contracts by ``I - N^-1 H``, and the second-order
    term ``sum r_i grad^2 r_i`` of the true Hessian ``H`` is not small against ``N = J^T J`` in the few
    hundred weak (camera-dominated) directions: on the 50-image block of the shared generator (B/H 0.03)
    the eigenvalues of ``N^-1 H`` span 0.08..1.88 (99 % within 1e-5 of 1), a contraction of 0.92 per
    iteration that no damping rule changes. Anderson's multisecant step (type II, the GMRES of
    the fixed-point map) removes those few slow directions from the combination of the last ``m``
    steps: ``gamma = argmin || w (d_k - dF gamma) ||``, ``x = x_k + d_k - (dX + dF) gamma`` with ``dX``,
    ``dF`` the differences of consecutive iterates and steps and ``w`` the Marquardt scaling
    ``sqrt(diag N)`` (unit-free). Returns None when the history is too short or the small
    least-squares problem is degenerate.
    """
    if len(xs) < 2:
        return None
    dX = np.stack([xs[i + 1] - xs[i] for i in range(len(xs) - 1)], axis=1)
    dF = np.stack([ds[i + 1] - ds[i] for i in range(len(ds) - 1)], axis=1)
    A = w[:, None] * dF
    gamma, *_ = np.linalg.lstsq(A, w * ds[-1], rcond=1e-10)
    if not np.all(np.isfinite(gamma)):
        return None
    return xs[-1] + ds[-1] - (dX + dF) @ gamma


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
    if opt.linear_solver not in ("auto", "direct", "pcg"):
        raise AdjustmentInputError(f"linear_solver must be 'auto', 'direct' or 'pcg', not {opt.linear_solver!r}")
    t_start = time.perf_counter()
    o = problem.obs
    p = problem.model.n_params
    fixed_pt = problem.point_fixed()
    structure = SchurStructure(o.cam_idx, o.pt_idx, problem.n_images, problem.n_points, p, active_pt=~fixed_pt,
                               compiled=opt.compiled)
    factorize = Factorizer(opt.backend)
    terms = Terms(problem)
    extra0 = np.concatenate([t.initial_extra() for t in problem.terms]) if problem.terms else np.zeros(0)
    assert problem.cam_param_free is not None      # set by BundleProblem.__post_init__
    free_red = np.concatenate([problem.cam_param_free.ravel()] +
                              [np.asarray(t.extra_free(), bool) for t in problem.terms])
    state = AdjustmentState(problem.cam_params.copy(), problem.points.copy(), extra0.copy(),
                            np.asarray(problem.obs_weight, float).copy())
    use_pcg = not terms.coupled and (opt.linear_solver == "pcg" or (
        opt.linear_solver == "auto" and opt.pcg_min_images is not None and problem.n_images >= opt.pcg_min_images))
    if use_pcg:
        # preconditioner blocks: one per image (its free parameters), one per free extra unknown
        grp = np.concatenate([np.repeat(np.arange(problem.n_images), p),
                              problem.n_images + np.arange(terms.n_extra)])[free_red]
        pcg_groups = np.unique(grp, return_inverse=True)[1].astype(np.int64)
    linear_iterations: list[int] = []
    t_setup = time.perf_counter() - t_start

    # datum check on the undamped system: a singular S means an undefined datum
    lin = linearize(problem, state, structure, terms, fixed_pt)
    if not np.isfinite(lin.cost):
        raise AdjustmentDivergedError("the initial cost is not finite (a point behind a camera or at infinity?)")
    if opt.check_datum:
        with phase("datum_check"):
            if terms.coupled:
                S0 = full_system(lin, problem, terms, 0.0, free_red, fixed_pt)[0]
            else:
                S0, _, _, _ = reduced_system(lin, structure, terms, 0.0, free_red)
            _check_datum(S0, opt.backend)

    cost0 = lin.cost
    state.cost = cost0
    trace = [(time.perf_counter() - t_start, cost0)]
    mu, nu = opt.initial_mu, 2.0
    n_iter = n_accept = n_accel = 0
    pcg_tol = opt.pcg_tolerance
    hist_x: list[NDArray] = []      # accepted iterates and their LM steps (Anderson acceleration)
    hist_d: list[NDArray] = []
    n_cp = state.cam_params.size
    n_pts = state.points.size
    message = "maximum number of iterations reached"
    converged = False
    while n_iter < opt.max_iterations:
        n_iter += 1
        if terms.coupled:
            # rows coupling several points (laser altimetry): the whole normal equations, points not eliminated
            S, rhs, D, free_all = full_system(lin, problem, terms, mu, free_red, fixed_pt)
        else:
            S, rhs, Vinv, D = reduced_system(lin, structure, terms, mu, free_red)
        try:
            if use_pcg:
                solve_S = _pcg_solver(S, pcg_groups, opt, linear_iterations, pcg_tol)
            else:
                solve_S = factorize(S)
        except DatumDefectError:
            # rounding made the damped system indefinite (very weak points): damp more, as for a rejected step
            if mu > 1e32:
                raise
            mu, nu = max(mu, 1e-12) * nu, 2.0 * nu
            continue
        if terms.coupled:
            dall = np.zeros(free_all.size)
            dall[free_all] = solve_S(rhs)
            dred = dall[:free_red.size]
            dp = dall[free_red.size:].reshape(-1, 3)
        else:
            dred = np.zeros(free_red.size)
            try:
                dfree = solve_S(rhs)
            except DatumDefectError:
                # CG met non-positive curvature (rounding on a nearly singular system): damp more
                if mu > 1e32:
                    raise
                mu, nu = max(mu, 1e-12) * nu, 2.0 * nu
                continue
            dred[free_red] = dfree
            with phase("back_substitution"):
                dp = back_substitute(lin, structure, Vinv, dred, terms, problem)
        dp[fixed_pt] = 0.0
        dc = dred[:terms.n_cam_red].reshape(-1, p)
        new = AdjustmentState(state.cam_params + dc, state.points + dp, state.extra + dred[terms.n_cam_red:],
                              state.obs_weight, state.iteration + 1)
        with phase("cost"):
            new_cost = evaluate_cost(problem, new)
        pred = _model_decrease(lin, mu, D, dred, dp)
        if use_pcg and not terms.coupled:
            # the inexact step solves (N + mu D) d = -g + [e; 0] with e = S dc - rhs: its model decrease is
            # the exact step's formula minus dc^T e / 2 (module docstring of .pcg)
            with phase("pcg"):
                pred -= 0.5 * float(dfree @ (S @ dfree - rhs))
        actual = state.cost - new_cost
        step_norm = np.sqrt(np.sum(dred ** 2) + np.sum(dp ** 2))
        x_norm = np.sqrt(np.sum(state.cam_params ** 2) + np.sum(state.points ** 2) + np.sum(state.extra ** 2))
        now = time.perf_counter()
        if opt.progress is not None and now - _last_progress[0] >= opt.progress:
            _last_progress[0] = now
            r = problem.n_observations() - 2 * int(np.sum(state.obs_weight == 0)) - problem.n_unknowns()
            s0 = np.sqrt(2.0 * min(new_cost, state.cost) / r) if r > 0 and np.isfinite(new_cost) else float("nan")
            _log.info("adjustment iteration %d: cost %.6g -> %.6g (%s), sigma0 %.4f, step %.3g, damping %.1e",
                      n_iter, state.cost, new_cost, "accepted" if new_cost < state.cost else "rejected", s0,
                      step_norm, mu)
        else:
            _log.log(logging.INFO if opt.verbose else logging.DEBUG,
                     "it %3d cost %.6e -> %.6e mu %.2e |dx| %.3e", n_iter, state.cost, new_cost, mu, step_norm)
        if np.isfinite(new_cost) and actual > 0:
            rho = actual / pred if pred > 0 else 1.0
            mu = max(mu * max(opt.min_mu_factor, 1.0 - (2.0 * rho - 1.0) ** 3), opt.min_mu)
            nu = 2.0
            old_cost = state.cost
            if opt.acceleration_memory > 0:
                with phase("acceleration"):
                    x_k = np.concatenate([state.cam_params.ravel(), state.points.ravel(), state.extra])
                    d_k = np.concatenate([dc.ravel(), dp.ravel(), dred[terms.n_cam_red:]])
                    hist_x.append(x_k)
                    hist_d.append(d_k)
                    del hist_x[:-(opt.acceleration_memory + 1)], hist_d[:-(opt.acceleration_memory + 1)]
                    w = np.sqrt(np.concatenate([D[:terms.n_cam_red], np.clip(
                        np.diagonal(lin.V, axis1=1, axis2=2), 1e-6, 1e32).ravel(), D[terms.n_cam_red:]]))
                    xa = _anderson(hist_x, hist_d, w)
                    if xa is not None:
                        acc = AdjustmentState(xa[:n_cp].reshape(state.cam_params.shape),
                                              xa[n_cp:n_cp + n_pts].reshape(state.points.shape), xa[n_cp + n_pts:],
                                              state.obs_weight, state.iteration + 1)
                        with phase("cost"):
                            acc_cost = evaluate_cost(problem, acc)
                        # safeguard: the accelerated point only where it is better than the LM step itself
                        if np.isfinite(acc_cost) and acc_cost < new_cost:
                            new, new_cost, actual = acc, acc_cost, state.cost - acc_cost
                            n_accel += 1
                        _log.log(logging.INFO if opt.verbose else logging.DEBUG,
                                 "     accelerated cost %.6e (%s)", acc_cost, "taken" if acc is new else "not taken")
            state = new
            state.cost = new_cost
            n_accept += 1
            trace.append((time.perf_counter() - t_start, new_cost))
            reweighted = False
            if reweight is not None:
                wr = reweight(state)
                if wr is not None:
                    state.obs_weight = np.asarray(wr, float)
                    state.cost = evaluate_cost(problem, state)
                    reweighted = True
                    hist_x.clear()      # a new cost function: earlier steps belong to another fixed-point map
                    hist_d.clear()
            if callback is not None:
                callback(state)
            if not reweighted and actual <= opt.ftol * old_cost:
                if use_pcg and pcg_tol > PCG_CHECK_TOLERANCE:
                    # an inexact step's small decrease says little about the minimum's distance (measured: the
                    # 10,000-image block stopped 5.8e-5 above Ceres' cost at tolerance 0.1): take the next
                    # step near-exactly and stop only if it too decreases the cost by less than ftol
                    pcg_tol = PCG_CHECK_TOLERANCE
                else:
                    converged, message = True, f"relative cost decrease {actual / old_cost:.2e} <= ftol {opt.ftol:g}"
                    break
            elif use_pcg:
                pcg_tol = opt.pcg_tolerance
            if not reweighted and step_norm <= opt.xtol * (x_norm + opt.xtol):
                converged, message = True, f"relative step {step_norm / max(x_norm, 1e-300):.2e} <= xtol {opt.xtol:g}"
                break
            lin = linearize(problem, state, structure, terms, fixed_pt)
        else:
            mu *= nu
            nu *= 2.0
            hist_x.clear()      # the damping changed by more than the steps' secant model can follow
            hist_d.clear()
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
                            free_red=free_red, linear_solver="pcg" if use_pcg else "direct",
                            linear_iterations=linear_iterations)


def _pcg_solver(S: sp.csr_matrix, groups: NDArray, opt: SolverOptions,
                counts: list[int], tol: float) -> Callable[[NDArray], NDArray]:
    """``solve(b)`` by block-Jacobi PCG on ``S`` (:mod:`.pcg`); appends the CG iterations of each solve to ``counts``.

    Raises DatumDefectError (as the direct factorisation does) when a preconditioner block or the CG
    curvature shows ``S`` not positive definite, so the caller damps more.
    """
    try:
        with phase("preconditioner"):
            M = block_jacobi(S, groups)
    except np.linalg.LinAlgError as exc:
        raise DatumDefectError(f"a diagonal block of the reduced system is not positive definite ({exc})") from exc

    def solve_pcg(b: NDArray) -> NDArray:
        try:
            with phase("pcg"):
                cap = opt.pcg_max_iterations if tol > PCG_CHECK_TOLERANCE else max(opt.pcg_max_iterations,
                                                                                   PCG_CHECK_ITERATIONS)
                x, k, _ = pcg(S, b, M, tol, cap)
        except np.linalg.LinAlgError as exc:
            raise DatumDefectError(f"the reduced system is not positive definite ({exc})") from exc
        counts.append(k)
        return x

    return solve_pcg


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
        with single_threaded_blas():       # see factor._dense: threads only spin at this size
            ev = np.linalg.eigvalsh(Sn.toarray())
        if ev[0] <= DATUM_EIGENVALUE_RATIO * ev[-1]:
            raise DatumDefectError(
                f"the normal equations are rank deficient (smallest/largest scaled eigenvalue "
                f"{ev[0] / ev[-1]:.1e}, {int(np.sum(ev <= DATUM_EIGENVALUE_RATIO * ev[-1]))} near-zero): the datum is not defined")
