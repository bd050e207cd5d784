"""Every reader of outside files, fuzzed: a result or a named lunarmap exception, never a raw one.

The contract and the edits are in ``tests/fuzzhelp.py``, the readers and their seed files in
``tests/fuzz_targets.py``. Inputs here are drawn deterministically (``derandomize``) with a fixed
budget per reader, so a run is reproducible; ``python bench/fuzz.py`` draws fresh, larger budgets.
"""

from __future__ import annotations

import os

import pytest

pytest.importorskip("hypothesis")

from fuzz_targets import READERS, build_targets  # noqa: E402
from fuzzhelp import COUNTS, fuzz  # noqa: E402

#: inputs per reader in the suite (split evenly over a reader's targets)
BUDGET = int(os.environ.get("LUNARMAP_FUZZ_BUDGET", "200"))


@pytest.fixture(scope="module")
def targets(tmp_path_factory):
    from lunarmap.spice import clear

    yield build_targets(tmp_path_factory.mktemp("fuzz_seeds"))
    clear()   # the label targets keep their kernel set resident; later tests expect an empty pool


@pytest.mark.parametrize("reader", sorted(READERS))
def test_reader_survives_mutated_inputs(reader, targets):
    mine = [targets[n] for n in READERS[reader] if n in targets]
    if not mine:
        pytest.skip(f"no seed files for {reader} (the shared kernel sets are absent)")
    per = -(-BUDGET // len(mine))
    for target in mine:
        before = sum(COUNTS[target.name].values())
        fuzz(target, max_examples=per)
        assert sum(COUNTS[target.name].values()) - before >= per * 0.95  # hypothesis ran the budget
