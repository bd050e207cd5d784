"""The per-block peak of resident memory (``lunarmap.procmem``): what the run's per-step memory figures rest on."""

from __future__ import annotations

import sys
import threading
import time

import numpy as np
import pytest

from lunarmap.procmem import peak_rss_during, rss_mb

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/status")


def test_peak_sees_memory_freed_before_the_block_ends():
    # oracle: the size of an array that lives only inside the block, touched page by page (np.ones)
    with peak_rss_during(0.01) as mem:
        a = np.ones(200 * 2**20 // 8)           # 200 MB resident
        time.sleep(0.2)
        del a
        end = rss_mb()
    assert mem.peak_mb - end > 150.0
    assert 150.0 < mem.added_mb < 260.0


def test_many_blocks_use_one_thread_and_nest():
    before = threading.active_count()
    with peak_rss_during(0.01) as outer:
        for _ in range(2000):                   # a rerun's reused steps: no thread started or joined per block
            with peak_rss_during(0.1):
                pass
        b = np.ones(100 * 2**20 // 8)
        time.sleep(0.1)
        del b
    assert threading.active_count() <= before + 1
    assert outer.added_mb > 70.0
