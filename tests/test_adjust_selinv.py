"""Selected inversion (adjust.selinv) against numpy's dense inverse: entries on the factor's pattern."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from lunarmap.adjust.selinv import nested_dissection, selected_inverse, symbolic_factor
from lunarmap.errors import DatumDefectError


def _grid_system(nx=14, ny=9, p=6, n_extra=4, coupled=30, seed=0):
    """A block system shaped like an image block: nodes on a grid (strips x images), each coupled to
    +-1 strip and +-2 images, and extra parameters coupled to the first ``coupled`` nodes."""
    rng = np.random.default_rng(seed)
    nn = nx * ny
    n = nn * p + n_extra
    A = np.zeros((n, n))
    for i in range(nx):
        for j in range(ny):
            for di in (0, 1):
                for dj in range(-2, 3):
                    ii, jj = i + di, j + dj
                    a, b = i * ny + j, ii * ny + jj
                    if 0 <= ii < nx and 0 <= jj < ny and b > a:
                        B = rng.normal(size=(p, p)) * 0.3
                        A[a * p:(a + 1) * p, b * p:(b + 1) * p] = B
                        A[b * p:(b + 1) * p, a * p:(a + 1) * p] = B.T
    coupled = min(coupled, nn)
    E = rng.normal(size=(coupled * p, n_extra)) * 0.2
    A[:coupled * p, nn * p:] = E
    A[nn * p:, :coupled * p] = E.T
    A += np.eye(n) * (np.abs(A).sum(axis=1).max() + 1.0)      # diagonally dominant: SPD
    ptr = np.concatenate([np.arange(0, nn * p + 1, p), [n] if n_extra else []]).astype(np.int64)
    return A, ptr, nn


def test_selected_inverse_equals_dense_inverse_on_the_pattern():
    A, ptr, nn = _grid_system()
    sym = symbolic_factor(sp.csr_matrix(A), ptr, last_nodes=np.array([nn]))
    assert len(sym.sn_cols) < nn                                 # supernodes group nodes
    r, c = np.nonzero(np.tril(A))
    got = selected_inverse(sp.csr_matrix(A), sym, r, c)
    Z = np.linalg.inv(A)
    np.testing.assert_allclose(got, Z[r, c], rtol=0, atol=1e-12 * np.abs(Z).max())
    # entries asked for in either triangle
    np.testing.assert_allclose(selected_inverse(sp.csr_matrix(A), sym, c, r), Z[c, r], rtol=0,
                               atol=1e-12 * np.abs(Z).max())


def test_nested_dissection_is_a_permutation_and_beats_the_natural_order():
    A, ptr, nn = _grid_system(nx=30, ny=20, n_extra=0, coupled=0, p=1)
    G = sp.csr_matrix(A != 0)
    order = nested_dissection(G)
    assert np.array_equal(np.sort(order), np.arange(G.shape[0]))
    band = symbolic_factor(sp.csr_matrix(A), ptr, leaf=10 ** 9)   # one leaf: reverse Cuthill-McKee, a band
    nd = symbolic_factor(sp.csr_matrix(A), ptr)
    print(f"factor entries, 30 x 20 grid: nested dissection {nd.nnz_factor()}, band {band.nnz_factor()}")
    assert nd.nnz_factor() < band.nnz_factor()


def test_not_positive_definite_and_singular_raise_datum_defect():
    A, ptr, nn = _grid_system(nx=5, ny=4)
    B = A.copy()
    B[7, 7] = -1.0
    sym = symbolic_factor(sp.csr_matrix(B), ptr, last_nodes=np.array([nn]))
    with pytest.raises(DatumDefectError, match="not positive definite"):
        selected_inverse(sp.csr_matrix(B), sym, np.array([0]), np.array([0]))
    # nearly singular (a tiny eigenvalue), caught by the scaled-variance limit
    w, V = np.linalg.eigh(A)
    w[0] = 1e-15 * w[-1]
    C = (V * w) @ V.T
    C = 0.5 * (C + C.T)
    d = 1 / np.sqrt(np.diag(C))
    Cs = C * d[:, None] * d[None, :]
    sym = symbolic_factor(sp.csr_matrix(Cs), ptr, last_nodes=np.array([nn]))
    with pytest.raises(DatumDefectError):
        selected_inverse(sp.csr_matrix(Cs), sym, np.array([0]), np.array([0]), max_scaled_variance=1e13)
