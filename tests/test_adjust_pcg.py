"""Iterative Schur solver (block-Jacobi PCG): oracles are dense numpy solves of the same systems and the
explicit dense linear model of the whitened Jacobian."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla
import scipy.sparse as sp
from test_adjust_acceleration import _weak_block

from lunarmap.adjust import SolverOptions, bal_to_problem, solve
from lunarmap.adjust.normal import AdjustmentState, Terms, back_substitute, linearize, reduced_system
from lunarmap.adjust.pcg import block_jacobi, pcg
from lunarmap.adjust.schur import SchurStructure
from lunarmap.adjust.solver import _model_decrease
from lunarmap.errors import AdjustmentInputError


@pytest.fixture(scope="module")
def weak():
    data, control = _weak_block(1)
    return bal_to_problem(data, control=control)


def _reduced(pb, mu=1e-3):
    fixed = pb.point_fixed()
    st = SchurStructure(pb.obs.cam_idx, pb.obs.pt_idx, pb.n_images, pb.n_points, pb.model.n_params,
                        active_pt=~fixed)
    terms = Terms(pb)
    state = AdjustmentState(pb.cam_params.copy(), pb.points.copy(), np.zeros(0), np.ones(pb.obs.n))
    lin = linearize(pb, state, st, terms, fixed)
    free = np.ones(pb.n_images * pb.model.n_params, bool)
    S, rhs, Vinv, D = reduced_system(lin, st, terms, mu, free)
    return lin, st, terms, S, rhs, Vinv, D, fixed


def test_block_jacobi_is_the_inverse_of_the_block_diagonal():
    rng = np.random.default_rng(3)
    groups = np.array([0, 0, 1, 1, 1, 2, 3, 3])        # unequal blocks, as with fixed image parameters
    A = rng.normal(size=(8, 8))
    S = A @ A.T + 8 * np.eye(8)
    blocks = [S[np.ix_(groups == g, groups == g)] for g in range(4)]
    r = rng.normal(size=8)
    expected = np.linalg.solve(sla.block_diag(*blocks), r)
    assert np.allclose(block_jacobi(sp.csr_matrix(S), groups)(r), expected, rtol=1e-12, atol=1e-12)
    with pytest.raises(np.linalg.LinAlgError):
        block_jacobi(sp.csr_matrix(np.diag([1.0, -1.0])), np.array([0, 1]))


def test_pcg_solves_the_reduced_camera_system(weak):
    *_, S, rhs, _, _, _ = _reduced(weak)
    Sd = S.toarray()
    exact = np.linalg.solve(Sd, rhs)
    p = weak.model.n_params
    groups = np.repeat(np.arange(weak.n_images), p)
    M = block_jacobi(S, groups)
    x, k, rel = pcg(S, rhs, M, 1e-12, 10_000)
    assert rel <= 1e-12 and k > 0
    assert np.linalg.norm(x - exact) <= 1e-8 * np.linalg.norm(exact)
    # a loose forcing tolerance: the preconditioned residual norm, computed here from dense block inverses,
    # is within it, and the error in the S-norm is bounded by the residual in the S^-1 norm (CG's measure)
    Minv = sla.block_diag(*[np.linalg.inv(Sd[i * p:(i + 1) * p, i * p:(i + 1) * p]) for i in range(weak.n_images)])
    for tol in (1e-1, 1e-3):
        x, k, rel = pcg(S, rhs, M, tol, 10_000)
        res = rhs - Sd @ x
        assert np.sqrt(res @ Minv @ res) <= tol * np.sqrt(rhs @ Minv @ rhs) * (1 + 1e-9)
        assert abs(np.sqrt(res @ Minv @ res / (rhs @ Minv @ rhs)) - rel) < 1e-6
        e = x - exact
        assert np.isclose(e @ Sd @ e, res @ np.linalg.solve(Sd, res), rtol=1e-6)


def test_inexact_step_model_decrease_is_the_explicit_linear_model(weak):
    mu = 1e-3
    lin, st, terms, S, rhs, Vinv, D, fixed = _reduced(weak, mu)
    p = weak.model.n_params
    o = weak.obs
    n, nc = o.n, weak.n_images * p
    # oracle: the dense whitened Jacobian J of all image observations and L(0) - L(d) = -r^T J d - |J d|^2 / 2
    J = np.zeros((2 * n, nc + 3 * weak.n_points))
    rows = np.arange(2 * n).reshape(n, 2)
    for k in range(2):
        J[rows[:, k][:, None], o.cam_idx[:, None] * p + np.arange(p)] = lin.Ac[:, k, :]
        J[rows[:, k][:, None], nc + 3 * o.pt_idx[:, None] + np.arange(3)] = lin.Ap[:, k, :]
    dc_cg, _, rel = pcg(S, rhs, block_jacobi(S, np.repeat(np.arange(weak.n_images), p)), 1e-1, 10_000)
    assert rel > 1e-6             # really inexact
    rng = np.random.default_rng(0)
    dc_any = np.linalg.solve(S.toarray(), rhs) * (1 + 0.2 * rng.normal(size=nc))   # not a Galerkin iterate
    for dc, galerkin in ((dc_cg, True), (dc_any, False)):
        dp = back_substitute(lin, st, Vinv, dc, terms, weak)
        exact_formula = _model_decrease(lin, mu, D, dc, dp)
        pred = exact_formula - 0.5 * float(dc @ (S @ dc - rhs))
        Jd = J @ np.concatenate([dc, dp.ravel()])
        explicit = -float(lin.r.ravel() @ Jd) - 0.5 * float(Jd @ Jd)
        assert pred == pytest.approx(explicit, rel=1e-8)
        # CG from zero leaves its residual orthogonal to its iterate: the exact-step formula holds as it is;
        # any other approximate step needs the residual term
        assert (abs(exact_formula - explicit) < 1e-8 * abs(explicit)) == galerkin


def test_pcg_step_and_solution_equal_the_direct_ones(weak):
    one = dict(max_iterations=1, acceleration_memory=0, check_datum=False)
    rd = solve(weak, SolverOptions(linear_solver="direct", **one))
    rp = solve(weak, SolverOptions(linear_solver="pcg", pcg_tolerance=1e-10, **one))
    assert rp.linear_solver == "pcg" and rd.linear_solver == "direct" and len(rp.linear_iterations) == 1
    step = np.linalg.norm(rd.cam_params - weak.cam_params)
    assert np.linalg.norm(rp.cam_params - rd.cam_params) <= 1e-7 * step
    assert np.linalg.norm(rp.points - rd.points) <= 1e-7 * np.linalg.norm(rd.points - weak.points)
    # whole solves at the default forcing tolerance reach the same minimum
    full = SolverOptions(linear_solver="direct", ftol=1e-10)
    cd = solve(weak, full).cost
    rp = solve(weak, SolverOptions(linear_solver="pcg", ftol=1e-10))
    assert rp.converged and rp.cost == pytest.approx(cd, rel=1e-8)
    # "auto": direct by default, PCG from its image-count threshold on
    assert solve(weak, SolverOptions(max_iterations=1)).linear_solver == "direct"
    assert solve(weak, SolverOptions(max_iterations=1, pcg_min_images=weak.n_images)).linear_solver == "pcg"


def test_unknown_linear_solver_is_rejected(weak):
    with pytest.raises(AdjustmentInputError, match="linear_solver"):
        solve(weak, SolverOptions(linear_solver="cg"))


def test_phase_timer_counts_each_phase_of_the_iteration(weak, monkeypatch):
    import itertools
    import types

    from lunarmap.adjust import timing
    from lunarmap.adjust.timing import PhaseTimer, phase

    opts = SolverOptions(linear_solver="direct", acceleration_memory=0, max_iterations=4, check_datum=False)
    with PhaseTimer() as t:
        res = solve(weak, opts)
    # one linearisation before the loop and one after every accepted step but a converged last one; one
    # cost evaluation and one back-substitution per step
    assert t.calls["jacobians"] in (res.accepted, res.accepted + 1)
    assert t.calls["cost"] == res.iterations == t.calls["back_substitution"]
    # no active timer: nothing is recorded
    solve(weak, opts)
    assert t.calls["cost"] == res.iterations
    # nested phases are charged exclusively: a clock that ticks 1 s per reading gives the inner phase 1 s
    # (its two readings) and the outer one 3 - 1 = 2 s
    cpu, wall = itertools.count(), itertools.count()
    monkeypatch.setattr(timing, "time", types.SimpleNamespace(process_time=lambda: float(next(cpu)),
                                                              perf_counter=lambda: float(next(wall))))
    with PhaseTimer() as t2:
        with phase("outer"):
            with phase("inner"):
                pass
    assert t2.cpu == {"outer": 2.0, "inner": 1.0} and t2.wall == {"outer": 2.0, "inner": 1.0}


def test_an_inexact_step_does_not_stop_the_solve_before_the_minimum(weak):
    """A loose PCG step decreases the cost little because it is inexact, not because the minimum is near: the
    ftol stop is checked with a near-exact step (oracle: the direct solve to ftol 1e-10; before the check,
    three CG iterations per step stopped 2.6e-5 above it, the direct solver's own ftol-1e-6 stop 7e-7)."""
    best = solve(weak, SolverOptions(linear_solver="direct", ftol=1e-10)).cost
    direct = solve(weak, SolverOptions(linear_solver="direct", ftol=1e-6)).cost
    loose = solve(weak, SolverOptions(linear_solver="pcg", pcg_tolerance=0.5, pcg_max_iterations=3, ftol=1e-6,
                                      max_iterations=500))
    assert loose.converged
    assert loose.cost - best <= 2.0 * max(direct - best, 1e-9 * best)
