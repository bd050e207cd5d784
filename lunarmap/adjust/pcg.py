"""Preconditioned conjugate gradients on the reduced camera system (iterative Schur).

The alternative to the sparse Cholesky of :mod:`.factor` for large blocks: the explicit reduced system
``S`` (assembled anyway, :meth:`.schur.SchurStructure.assemble`) is solved to a relative residual by CG
with a block-Jacobi preconditioner (the inverse of each image's ``p x p`` diagonal block of ``S``, Ceres'
SCHUR_JACOBI). One CG iteration is one sparse product with ``S`` (``O(nnz S)``) and one batched
``p x p`` product; no fill-in, no ordering, no symbolic analysis.

The step is inexact: with exactly back-substituted points it solves the full damped normal equations up
to ``[e; 0]``, ``e = S dc - b``, and its linear-model decrease is the exact step's formula minus
``dc^T e / 2``. For CG started at zero that term vanishes (the residual is orthogonal to the Krylov space
holding the iterate); :func:`lunarmap.adjust.solver.solve` still subtracts it (one product with ``S``),
against the loss of orthogonality in long CG runs, so the LM acceptance ratio stays that of the model the
step actually minimised.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

__all__ = ["block_jacobi", "pcg"]


def block_jacobi(S: sp.csr_matrix, groups: NDArray[np.int64]) -> Callable[[NDArray], NDArray]:
    """Inverse of the block diagonal of ``S`` as a function ``r -> M^-1 r``.

    Parameters
    ----------
    S : (n, n) sparse, symmetric positive definite
    groups : (n,) int
        Block of every row, non-decreasing from 0 (an image's free unknowns share one block).

    Raises
    ------
    numpy.linalg.LinAlgError
        A diagonal block is not positive definite.
    """
    groups = np.asarray(groups, np.int64)
    n = groups.size
    n_groups = int(groups[-1]) + 1 if n else 0
    start = np.searchsorted(groups, np.arange(n_groups))
    pos = np.arange(n) - start[groups]
    size = int(pos.max(initial=-1)) + 1
    C = sp.coo_matrix(S)
    keep = groups[C.row] == groups[C.col]
    B = np.zeros((n_groups, size, size))
    B[groups[C.row[keep]], pos[C.row[keep]], pos[C.col[keep]]] = C.data[keep]
    # blocks smaller than the largest (an image with fixed parameters): unit pivots in the unused slots
    used = np.zeros((n_groups, size), bool)
    used[groups, pos] = True
    gi, pi = np.nonzero(~used)
    B[gi, pi, pi] = 1.0
    L = np.linalg.cholesky(B)             # raises LinAlgError if a block is not positive definite
    eye = np.broadcast_to(np.eye(size), B.shape)
    Linv = np.linalg.solve(L, eye)
    Minv = np.einsum("gki,gkj->gij", Linv, Linv)     # B^-1 = L^-T L^-1

    if n == n_groups * size:
        # every block full (no fixed image parameters): the vector is the blocks one after another
        def apply_full(r: NDArray) -> NDArray:
            return np.matmul(Minv, r.reshape(n_groups, size, 1)).reshape(n)

        return apply_full

    def apply(r: NDArray) -> NDArray:
        x = np.zeros((n_groups, size))
        x[groups, pos] = r
        return np.matmul(Minv, x[:, :, None])[:, :, 0][groups, pos]

    return apply


def pcg(S: sp.csr_matrix, b: NDArray, precond: Callable[[NDArray], NDArray], rtol: float, max_iterations: int,
        x0: NDArray | None = None) -> tuple[NDArray, int, float]:
    """Solve ``S x = b`` by preconditioned CG until ``||r||_M^-1 <= rtol ||b - S x0||_M^-1``.

    The preconditioned residual norm ``sqrt(r^T M^-1 r)`` is unit-free (radians and metres of the image
    parameters are scaled by their own blocks), unlike the Euclidean norm of ``r``.

    Returns
    -------
    x : (n,) solution
    iterations : int
        CG iterations taken (``max_iterations`` if the tolerance was not reached).
    relative_residual : float
        Final ``||r||_M^-1 / ||r_0||_M^-1``.

    Raises
    ------
    numpy.linalg.LinAlgError
        Non-positive curvature ``p^T S p <= 0``: ``S`` is not positive definite.
    """
    x = np.zeros_like(b) if x0 is None else np.array(x0, float)
    r = b - S @ x if x0 is not None else b.copy()
    z = precond(r)
    rz = float(r @ z)
    rz0 = rz
    if not rz0 > 0.0:
        return x, 0, 0.0
    d = z.copy()
    target = rtol * rtol * rz0
    k = 0
    while k < max_iterations and rz > target:
        q = S @ d
        dq = float(d @ q)
        if not dq > 0.0:
            raise np.linalg.LinAlgError(f"non-positive curvature {dq:.3g} in CG iteration {k}")
        alpha = rz / dq
        x += alpha * d
        r -= alpha * q
        z = precond(r)
        rz_new = float(r @ z)
        d *= rz_new / rz
        d += z
        rz = rz_new
        k += 1
    return x, k, float(np.sqrt(max(rz, 0.0) / rz0))
