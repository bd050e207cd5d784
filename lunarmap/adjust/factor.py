"""Sparse symmetric positive-definite factorisation of the reduced camera system.

Backends (chosen by name, ``"auto"`` picks the first available):

* ``"cholmod"`` -- supernodal Cholesky with a fill-reducing (AMD) ordering
  through the optional ``cholespy`` wheel (it bundles CHOLMOD);
* ``"splu"`` -- scipy's SuperLU in symmetric mode with the minimum-degree
  ordering of ``A^T + A`` and no pivoting (always available);
* ``"dense"`` -- LAPACK Cholesky, for small systems.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import DatumDefectError

__all__ = ["factorize", "available_backends"]


def available_backends() -> list[str]:
    """Names of the factorisation backends importable here."""
    out = []
    try:
        import cholespy  # noqa: F401

        out.append("cholmod")
    except ImportError:
        pass
    return out + ["splu", "dense"]


def _cholmod(S: sp.csr_matrix):
    from cholespy import CholeskySolverD, MatrixType

    n = S.shape[0]
    # S is symmetric, so its CSR arrays are also its CSC arrays
    solver = CholeskySolverD(n, S.indptr.astype(np.int32), S.indices.astype(np.int32), S.data, MatrixType.CSC)

    def solve(b):
        b = np.ascontiguousarray(b, dtype=np.float64)
        x = np.empty_like(b)
        solver.solve(b, x)
        return x

    return solve


def _splu(S: sp.csr_matrix):
    lu = spla.splu(S.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                   options={"SymmetricMode": True})
    piv = np.abs(lu.U.diagonal())
    if not np.all(np.isfinite(piv)) or piv.min() <= 1e-13 * piv.max():
        raise np.linalg.LinAlgError("singular reduced system")
    return lu.solve


def _dense(S: sp.csr_matrix):
    c = sla.cho_factor(S.toarray(), lower=True, check_finite=False)
    return lambda b: sla.cho_solve(c, b, check_finite=False)


def factorize(S: sp.csr_matrix, backend: str = "auto") -> Callable[[np.ndarray], np.ndarray]:
    """Factorise the symmetric positive-definite matrix ``S``; returns ``solve(b)``.

    Raises
    ------
    DatumDefectError
        If ``S`` is not positive definite (an undefined datum or an unobserved unknown).
    """
    if backend == "auto":
        backend = "dense" if S.shape[0] <= 600 else available_backends()[0]
    fn = {"cholmod": _cholmod, "splu": _splu, "dense": _dense}[backend]
    try:
        solve = fn(S)
    except (np.linalg.LinAlgError, RuntimeError, ValueError) as exc:
        raise DatumDefectError(
            f"the reduced normal equations ({S.shape[0]} unknowns) are singular or not positive definite "
            f"({exc}); the datum is not defined or a parameter is not observed"
        ) from exc
    return solve
