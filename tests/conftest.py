"""Shared fixtures.

Tests marked ``shared`` read the real kernel sets in ``../shared/data/kernels``
(beside the checkout). They are skipped, with the reason shown, when that folder
is absent; on CI it is present, and ``LUNARMAP_REQUIRE_SHARED=1`` (set by
``.ci/run``) turns a missing folder into a failure instead of a silent skip.

Likewise for capabilities that have a fallback: without numba lunarmap runs its numpy paths and
without cvxopt another sparse Cholesky, so tests of the compiled kernels would skip and the rest
pass. :func:`require` skips such a test locally but fails it when ``LUNARMAP_STRICT=1`` (set by
``.ci/run`` on CI), where every compiled backend and optional extra must be present.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_KERNELS = Path(os.environ.get("LUNARMAP_SHARED_KERNELS", ROOT.parent / "shared" / "data" / "kernels"))


#: On CI a missing optional capability fails the tests that need it instead of skipping them.
STRICT = os.environ.get("LUNARMAP_STRICT") == "1"


def require(present: bool, what: str) -> None:
    """Skip the calling test when ``what`` is not ``present``; fail instead under ``LUNARMAP_STRICT=1``."""
    if not present:
        if STRICT:
            pytest.fail(f"{what} is required on CI (LUNARMAP_STRICT=1) but missing")
        pytest.skip(f"{what} is missing")


def shared_set(name: str) -> Path:
    folder = SHARED_KERNELS / name
    if not folder.is_dir():
        if os.environ.get("LUNARMAP_REQUIRE_SHARED") == "1":
            pytest.fail(f"shared kernel set {folder} is required (LUNARMAP_REQUIRE_SHARED=1) but absent")
        pytest.skip(f"shared kernel set {folder} not present")
    return folder


@pytest.fixture(scope="session")
def lro_set() -> Path:
    return shared_set("lro_nac_M103595705LE")


@pytest.fixture(scope="session")
def clementine_set() -> Path:
    return shared_set("clementine_uvvis_LUA3107H161")


@pytest.fixture(scope="session")
def kaguya_set() -> Path:
    return shared_set("kaguya_tc_TC1S2B0")


@pytest.fixture(scope="session")
def sim_mission(tmp_path_factory) -> Path:
    """The synthetic mission written once per test session; returns its meta-kernel."""
    from lunarmap.synthetic import write_mission

    return write_mission(tmp_path_factory.mktemp("sim_mission"))


# -- historical film cameras (issue 13) ------------------------------------------------------------

@pytest.fixture(scope="session")
def lo_set() -> Path:
    return shared_set("lunar_orbiter_3133_high_res_1")


@pytest.fixture(scope="session")
def apollo_set() -> Path:
    return shared_set("apollo15_metric_AS15-M-1450")
