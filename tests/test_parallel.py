"""The SPICE worker plugin on a real two-process dask cluster."""

from __future__ import annotations

import os

import pytest

from lunarmap.spice import KernelSet

distributed = pytest.importorskip("distributed")


def _pool_value(name: str) -> tuple[int, float, int]:
    import spiceypy

    from lunarmap.spice import SPICE_LOCK

    with SPICE_LOCK:
        return os.getpid(), float(spiceypy.gdpool(name, 0, 1)[0]), int(spiceypy.ktotal("ALL"))


@pytest.mark.slow
def test_worker_plugin_furnishes_every_worker_process(tmp_path):
    from lunarmap.parallel import register_kernels

    k = tmp_path / "w.tpc"
    k.write_text("KPL/PCK\n\\begindata\nLUNARMAP_WORKER_TEST = 42\n\\begintext\n")
    kset = KernelSet.from_files([k])
    with distributed.LocalCluster(n_workers=2, threads_per_worker=2, processes=True, dashboard_address=":0",
                                  silence_logs=40) as cluster, distributed.Client(cluster) as client:
        register_kernels(client, kset)
        futures = [client.submit(_pool_value, "LUNARMAP_WORKER_TEST", pure=False) for _ in range(16)]
        results = client.gather(futures)
        per_worker = client.run(_pool_value, "LUNARMAP_WORKER_TEST")
    assert {v for _, v, _ in results} == {42.0}
    assert {n for _, _, n in results} == {1}  # loaded once, never per task
    assert len(per_worker) == 2 and all(v == 42.0 for _, v, _ in per_worker.values())
    assert os.getpid() not in {pid for pid, _, _ in results}
