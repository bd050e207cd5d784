"""Sparse symmetric positive-definite factorisation of the reduced camera system.

Backends (chosen by name, ``"auto"`` picks the first available):

* ``"cholmod"`` -- CHOLMOD's *supernodal* Cholesky (BLAS-3 on dense supernodes, AMD ordering)
  through the optional ``cvxopt`` wheel (``pip install lunarmap[sparse]``; GPL-3, hence optional).
  The symbolic analysis (ordering, elimination tree) is done once per sparsity pattern and
  reused by every LM iteration; only the numeric factorisation is repeated.  On the
  12,000 x 12,000 reduced system of a 2,000-image block the numeric step takes ~0.05 s,
  against ~0.55 s for the simplicial CHOLMOD bundled in ``cholespy`` and ~0.4 s for SuperLU;
* ``"cholespy"`` -- CHOLMOD (simplicial, LGPL modules only) through the ``cholespy`` wheel;
* ``"splu"`` -- scipy's SuperLU in symmetric mode with the minimum-degree
  ordering of ``A^T + A`` and no pivoting (always available);
* ``"dense"`` -- LAPACK Cholesky, for small systems.
"""

from __future__ import annotations

import threading
from typing import Callable

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..blas import single_threaded_blas
from ..errors import DatumDefectError
from .timing import phase

__all__ = ["factorize", "available_backends", "Factorizer"]


def available_backends() -> list[str]:
    """Names of the factorisation backends importable here, fastest first."""
    out = []
    try:
        from cvxopt import cholmod  # noqa: F401

        out.append("cholmod")
    except ImportError:
        pass
    try:
        import cholespy  # noqa: F401

        out.append("cholespy")
    except ImportError:
        pass
    return out + ["splu", "dense"]


#: Guards the lazy creation of a Factorizer's CHOLMOD state. The state itself (symbolic analysis and
#: factor, reused between calls) belongs to one solve: a Factorizer is not shared between threads.
_CVX_LOCK = threading.RLock()


class _CvxoptCholmod:
    """Supernodal CHOLMOD with the symbolic analysis kept for a fixed sparsity pattern."""

    def __init__(self):
        from cvxopt import cholmod

        cholmod.options["supernodal"] = 2  # always supernodal: BLAS-3 on the dense fronts
        cholmod.options["postorder"] = True
        self._cholmod = cholmod
        self._key = None
        self._symbolic = None
        self._A = None

    def __call__(self, S: sp.csr_matrix):
        from cvxopt import matrix, spmatrix

        n = S.shape[0]
        lower = getattr(S, "lower_csc", None)  # set by SchurStructure.assemble: pattern arrays are reused
        if lower is not None:
            indptr, rows, cols, data = lower
            key = (n, len(rows), id(indptr), id(rows))
        else:
            L = sp.tril(S, format="csc")
            L.sort_indices()
            indptr, rows, data = L.indptr, L.indices.astype(np.int32), L.data
            cols = np.repeat(np.arange(n, dtype=np.int32), np.diff(L.indptr))
            key = (n, L.nnz, L.indptr.tobytes(), L.indices.tobytes())
        values = matrix(np.ascontiguousarray(data, dtype=np.float64))
        if key != self._key:
            with phase("factor_symbolic"):
                A = spmatrix(values, matrix(rows), matrix(cols), (n, n))
                self._symbolic = self._cholmod.symbolic(A, uplo="L")
            self._key, self._A = key, A
        else:
            # same pattern, entries in the same (column, row) order: swap the values only
            A = self._A
            A.V = values
        F = self._symbolic
        try:
            with phase("factor_numeric"):
                self._cholmod.numeric(A, F)
        except ArithmeticError as exc:  # cvxopt raises ArithmeticError for a non-PD matrix
            raise np.linalg.LinAlgError(str(exc)) from exc
        cholmod = self._cholmod

        def solve(b):
            with phase("triangular_solves"):
                x = matrix(np.array(b, dtype=np.float64, order="F").reshape(n, -1))
                cholmod.solve(F, x)
                return np.array(x).reshape(np.shape(b))

        return solve


def _cholespy(S: sp.csr_matrix):
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
    d = S.diagonal()
    if not np.all(d > 0):
        raise np.linalg.LinAlgError("non-positive diagonal")
    # Jacobi scaling, so the relative pivot test does not mistake radians-vs-metres scale for singularity
    s = 1.0 / np.sqrt(d)
    Ss = sp.csc_matrix(S.multiply(s[:, None]).multiply(s[None, :]))
    lu = spla.splu(Ss, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    piv = lu.U.diagonal()
    if not np.all(np.isfinite(piv)) or piv.min() <= 1e-13 * np.abs(piv).max():
        raise np.linalg.LinAlgError("singular or indefinite reduced system")

    def solve(b):
        sb = s.reshape((-1,) + (1,) * (np.ndim(b) - 1))
        return lu.solve(np.asarray(b, dtype=np.float64) * sb) * sb

    return solve


def _dense(S: sp.csr_matrix):
    # small systems: OpenBLAS threads only spin-wait here, and on a loaded machine turn a 1 ms factorisation
    # of a 336 x 336 system into 0.8 s (measured); one thread is never slower at this size
    with single_threaded_blas():
        c = sla.cho_factor(S.toarray(), lower=True, check_finite=False)

    def solve(b):
        with single_threaded_blas():
            return sla.cho_solve(c, b, check_finite=False)

    return solve


class Factorizer:
    """Repeated factorisations of matrices with (usually) one sparsity pattern, as in LM iterations.

    Keeps backend state between calls (CHOLMOD's symbolic analysis), so build one per adjustment.

    Parameters
    ----------
    backend : str
        ``"auto"``, ``"cholmod"``, ``"cholespy"``, ``"splu"`` or ``"dense"``.
    """

    def __init__(self, backend: str = "auto"):
        self.backend = backend
        self._cvx: _CvxoptCholmod | None = None

    def __call__(self, S: sp.csr_matrix) -> Callable[[np.ndarray], np.ndarray]:
        """Factorise the symmetric positive-definite ``S``; returns ``solve(b)``.

        Raises
        ------
        DatumDefectError
            If ``S`` is not positive definite (an undefined datum or an unobserved unknown).
        """
        backend = self.backend
        if backend == "auto":
            backend = "dense" if S.shape[0] <= 600 else available_backends()[0]
        if backend == "cholmod":
            with _CVX_LOCK:   # one CHOLMOD state per Factorizer, created once
                if self._cvx is None:
                    self._cvx = _CvxoptCholmod()
            fn: Callable[[sp.csr_matrix], Callable[[np.ndarray], np.ndarray]] = self._cvx
        else:
            fn = {"cholespy": _cholespy, "splu": _splu, "dense": _dense}[backend]
        try:
            if fn is self._cvx:
                solve = fn(S)       # times its symbolic / numeric phases itself
            else:
                with phase("factorize"):
                    solve = fn(S)
        except (np.linalg.LinAlgError, RuntimeError, ValueError, ArithmeticError) as exc:
            raise DatumDefectError(
                f"the reduced normal equations ({S.shape[0]} unknowns) are singular or not positive definite "
                f"({exc}); the datum is not defined or a parameter is not observed"
            ) from exc
        return solve


def factorize(S: sp.csr_matrix, backend: str = "auto") -> Callable[[np.ndarray], np.ndarray]:
    """Factorise the symmetric positive-definite matrix ``S`` once; returns ``solve(b)``.

    Raises
    ------
    DatumDefectError
        If ``S`` is not positive definite (an undefined datum or an unobserved unknown).
    """
    return Factorizer(backend)(S)
