"""The compiled backends and optional extras are really there (on CI they must be: ``LUNARMAP_STRICT=1``).

Without numba every compiled kernel silently falls back to numpy and the suite still passes; without
cvxopt the adjustment uses another sparse Cholesky; the benchmarks and the fuzzing rely on the
``bench`` and ``test`` extras. Locally these tests skip with the reason shown (``-rs``); on CI a
missing piece fails them.
"""

from __future__ import annotations

import importlib

import pytest

from conftest import require

#: module -> why it matters
OPTIONAL = {
    "numba": "compiled adjustment, frame-projection and NCC kernels",
    "cvxopt": "supernodal CHOLMOD, the sparse backend the adjustment benchmarks use (bench extra)",
    "netCDF4": "netCDF output of tie points, networks and RFMs (test extra)",
    "hypothesis": "fuzzing of the readers (test extra)",
    "pytest_benchmark": "the benchmarks (bench extra)",
    "distributed": "dask clusters (runtime dependency)",
}


@pytest.mark.parametrize("module", sorted(OPTIONAL))
def test_optional_module_imports(module):
    try:
        importlib.import_module(module)
        present = True
    except Exception as err:  # noqa: BLE001 - a broken install (ImportError, numba's SystemError) counts as missing
        present, OPTIONAL[module] = False, f"{OPTIONAL[module]}; import failed: {type(err).__name__}: {err}"
    require(present, f"{module} ({OPTIONAL[module]})")


def test_compiled_kernels_are_active():
    """Every module that compiles with numba found it (a fallback to numpy would pass every other test)."""
    from lunarmap.adjust import collinearity, precision, schur
    from lunarmap.camera import corrections
    from lunarmap.matching import ncc

    inactive = [m.__name__ for m in (collinearity, precision, schur, corrections, ncc) if m.numba is None]
    require(not inactive, f"numba in {', '.join(inactive) or '-'}")
    assert schur.HAVE_COMPILED and collinearity._frame_kernel is not None and corrections._frame_pixels is not None


def test_sparse_backend_is_cholmod():
    from lunarmap.adjust import available_backends

    require(available_backends()[0] == "cholmod", f"cvxopt's CHOLMOD (backends found: {available_backends()})")
