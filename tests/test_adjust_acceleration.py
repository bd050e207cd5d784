"""Anderson acceleration of the Levenberg-Marquardt steps (issue 32, item 2).

Oracles: the fixed point of an affine map (closed form), and the Newton decrement of the cost from
finite-difference derivatives of a projection written here, on a weak-geometry block (base-to-height ratio 0.03, the geometry on
which Gauss-Newton converges only linearly: the second-order term of the Hessian is not small against
``J^T J`` in its weak directions).
"""

from __future__ import annotations

import numpy as np

from lunarmap.adjust import BALData, SolverOptions, bal_to_problem, problem_to_bal_cameras, solve
from lunarmap.adjust.solver import _anderson


def test_anderson_finds_the_fixed_point_of_an_affine_map():
    """On ``x -> x - M (x - x*)`` Anderson's multisecant step with memory >= n is GMRES: exact in n + 1 steps."""
    rng = np.random.default_rng(3)
    n = 6
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    lam = np.array([0.08, 0.1, 0.3, 1.0, 1.7, 1.88])      # the spread of N^-1 H measured on weak blocks
    M = Q @ np.diag(lam) @ Q.T
    x_star = rng.normal(size=n)
    x = x_star + rng.normal(size=n)
    e0 = np.linalg.norm(x - x_star)
    xs, ds = [], []
    for _ in range(n + 2):
        d = -M @ (x - x_star)
        xs.append(x.copy())
        ds.append(d)
        xa = _anderson(xs, ds, np.ones(n))
        x = x + d if xa is None else xa
    assert np.linalg.norm(x - x_star) < 1e-8 * e0
    # the plain iteration only contracts by max |1 - lambda| = 0.92 per step: 0.92^8 = 0.51
    assert np.max(np.abs(1 - lam)) ** (n + 2) > 0.5


def _project(cams, X):
    """BAL projection written here (Rodrigues), independent of lunarmap's collinearity code."""
    w = cams[:, 0:3]
    th = np.linalg.norm(w, axis=1, keepdims=True)
    k = np.divide(w, th, out=np.zeros_like(w), where=th > 0)
    c, s = np.cos(th), np.sin(th)
    P = X * c + np.cross(k, X) * s + k * np.sum(k * X, axis=1, keepdims=True) * (1.0 - c) + cams[:, 3:6]
    return cams[:, 6:7] * (-P[:, :2] / P[:, 2:3])


def _weak_block(seed: int):
    """Two strips of 7 nadir frame images at 400 km, B/H 0.03, 4 control points (km, pixels)."""
    rng = np.random.default_rng(seed)
    f, H, half = 3913.0, 400.0, 14.0             # focal (px), height (km), half footprint (km)
    B = 0.03 * H
    centres = np.array([[sx, sy, H + rng.normal(0, 1.0)] for sx in (0.0, 1.4 * half) for sy in B * np.arange(7)])
    X = np.column_stack([rng.uniform(-half, 1.4 * half + half, 400), rng.uniform(-half, B * 6 + half, 400),
                         np.zeros(400)])
    X[:, 2] = 2.0 * np.sin(X[:, 0] / 7.0) * np.cos(X[:, 1] / 9.0)
    cams, cam_idx, pt_idx = [], [], []
    for i, C in enumerate(centres):
        w = rng.normal(0, np.radians(0.05), 3)
        th = np.linalg.norm(w)
        K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]) / th
        R = np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K       # camera z up: looks down -z
        cams.append(np.concatenate([w, -R @ C, [f, 0.0, 0.0]]))
        P = (X - C) @ R.T
        uv = f * (-P[:, :2] / P[:, 2:3])
        seen = np.nonzero((np.abs(uv[:, 0]) < 192) & (np.abs(uv[:, 1]) < 144))[0]
        cam_idx += [i] * seen.size
        pt_idx += seen.tolist()
    cams = np.array(cams)
    cam_idx, pt_idx = np.array(cam_idx), np.array(pt_idx)
    keep = np.nonzero(np.bincount(pt_idx, minlength=len(X)) >= 2)[0]
    remap = -np.ones(len(X), int)
    remap[keep] = np.arange(keep.size)
    m = remap[pt_idx] >= 0
    cam_idx, pt_idx, X = cam_idx[m], remap[pt_idx[m]], X[keep]
    obs = _project(cams[cam_idx], X[pt_idx]) + rng.normal(0, 0.3, (cam_idx.size, 2))
    control = rng.choice(len(X), 4, replace=False)
    c0 = cams.copy()
    c0[:, 0:3] += rng.normal(0, np.radians(0.01), (len(cams), 3))
    c0[:, 3:6] += rng.normal(0, 0.1, (len(cams), 3))
    X0 = X + rng.normal(0, 0.3, X.shape)
    X0[control] = X[control]
    return BALData(c0, X0, cam_idx, pt_idx, obs), control


def _newton_gap(data: BALData, control, cams, X) -> float:
    """Newton decrement ``g^T H^-1 g / 2`` of the cost at BAL cameras ``cams`` and points ``X``: the distance
    to the minimum in cost, accurate to second order. Gradient and full Hessian (``J^T J`` plus the
    second-order term ``sum r grad^2 r``) by central differences of :func:`_project` per observation in its
    9 unknowns (angle-axis, translation, point): independent of the solver's Jacobians and normal equations."""
    free = np.ones(len(X), bool)
    free[control] = False
    ci, pj = data.cam_idx, data.pt_idx
    q = np.column_stack([cams[ci, :6], X[pj]])                      # (n_obs, 9)
    h = 1e-6 * np.maximum(np.abs(q), 1.0)
    fixed = cams[ci, 6:]

    def res(q):
        return _project(np.column_stack([q[:, :6], fixed]), q[:, 6:]) - data.obs

    def jac(q):
        J = np.empty((len(q), 2, 9))
        for a in range(9):
            e = np.zeros((1, 9))
            e[0, a] = 1.0
            J[:, :, a] = (res(q + h * e) - res(q - h * e)) / (2 * h[:, a:a + 1])
        return J

    r, J = res(q), jac(q)
    H2 = np.empty((len(q), 9, 9))
    for a in range(9):
        e = np.zeros((1, 9))
        e[0, a] = 1.0
        ha = 100 * h[:, a:a + 1]
        dJ = (jac(q + ha * e) - jac(q - ha * e)) / (2 * ha[:, :, None])
        H2[:, a, :] = np.einsum("ni,nij->nj", r, dJ)
    Hk = np.einsum("nia,nib->nab", J, J) + 0.5 * (H2 + H2.transpose(0, 2, 1))
    gk = np.einsum("nia,ni->na", J, r)
    # global index of every observation's 9 unknowns (fixed control points: a discarded last slot)
    n = 6 * len(cams) + 3 * int(free.sum())
    pt_col = np.full(len(X), n)
    pt_col[free] = 6 * len(cams) + 3 * np.arange(int(free.sum()))
    idx = np.column_stack([6 * ci[:, None] + np.arange(6),
                           np.where(free[pj, None], pt_col[pj, None] + np.arange(3), n)])
    g = np.zeros(n + 1)
    H = np.zeros((n + 1, n + 1))
    np.add.at(g, idx, gk)
    np.add.at(H, (idx[:, :, None], idx[:, None, :]), Hk)
    g, H = g[:n], H[:n, :n]
    return 0.5 * float(g @ np.linalg.solve(H, g))


def test_accelerated_steps_reach_the_minimum_plain_steps_do_not():
    data, control = _weak_block(1)
    pb = bal_to_problem(data, control=control)
    acc = solve(pb, SolverOptions(ftol=1e-12, xtol=1e-14, max_iterations=200))
    assert acc.converged
    gap = _newton_gap(data, control, problem_to_bal_cameras(pb.model, acc.cam_params), acc.points)
    # within 1e-9 of the minimum's cost (BAL's cost, half the square sum in pixels, is lunarmap's at 1 px sigma)
    assert 0.0 <= gap < 1e-9 * acc.cost
    # plain LM steps, as many: linear convergence at 1 - lambda_min(N^-1 H) per step leaves them far off
    plain = solve(pb, SolverOptions(ftol=0.0, xtol=0.0, max_iterations=acc.iterations, acceleration_memory=0))
    assert _newton_gap(data, control, problem_to_bal_cameras(pb.model, plain.cam_params), plain.points) > 1e-7 * acc.cost
