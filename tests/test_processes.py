"""Worker processes and faults on a real 2-process dask cluster.

One ``LocalCluster`` (2 worker processes, one thread each, nannies) serves the module: matching
and RPC fitting on it equal the serial results; the kernel plugin loads kernels in every worker
process, unloads them when it is removed (teardown) and loads them again in restarted workers; a
worker process killed (SIGKILL) while a graph runs is replaced and the graph completes with results
identical to serial ones. The kill test records how many of the graph's tasks had finished when the
worker died, to show the kill happened mid-graph.
"""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest
import xarray as xr

distributed = pytest.importorskip("distributed")

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def client():
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                                  silence_logs=50) as cluster, distributed.Client(cluster) as c:
        yield c


def _pids(client) -> set[int]:
    return set(client.run(os.getpid).values())


def _frame_cameras(n: int):
    from lunarmap.camera import FrameCamera, Shape
    from lunarmap.simulate.orbits import frame_interior, polar_orbit_eo

    return [FrameCamera(frame_interior(), polar_orbit_eo(lat_center=5.0 * k - 20.0, lon=30.0 + k, half_span=0.0,
                                                         step=1.0, roll_deg=2.0 * k), Shape.moon())
            for k in range(n)]


def test_matching_on_two_worker_processes_equals_serial(client):
    from lunarmap.matching import TiePointParams, find_tiepoints
    from lunarmap.simulate import pointed_camera, render_image, synthetic_scene

    dtm, alb = synthetic_scene(30.0, 0.0, 250.0, 0.5, seed=3)
    cams = {f"e{e:+d}": pointed_camera("linescan", 30.0, 0.0, e, n_lines=160, n_samples=160) for e in (-6, 0, 6)}
    imgs = {k: render_image(c, dtm, alb, noise_sigma=2.0, sun="eo", seed=i).compute()
            for i, (k, c) in enumerate(cams.items())}
    params = TiePointParams()
    params.detect.tile, params.detect.cell, params.detect.per_cell = 80, 16, 1
    params.match.search = 10.0
    serial = find_tiepoints(imgs, cams, params=params, scheduler="sync")
    assert serial.sizes["observation"] > 100
    parallel = find_tiepoints(imgs, cams, params=params, scheduler=client)
    xr.testing.assert_identical(serial, parallel)
    assert os.getpid() not in _pids(client)   # the tasks ran in other processes


def test_rpc_fit_many_on_two_worker_processes_equals_serial(client):
    from lunarmap.rpc import fit_many, fit_rpc

    cams = _frame_cameras(4)
    serial = [fit_rpc(c, (-3000.0, 3000.0)) for c in cams]
    parallel = fit_many(cams, [(-3000.0, 3000.0)] * 4, client=client)
    for a, b in zip(serial, parallel):
        assert np.array_equal(a.model.coefficients, b.model.coefficients)
        assert np.array_equal(a.model.offsets, b.model.offsets) and np.array_equal(a.model.scales, b.model.scales)
        assert a.check.rms == b.check.rms


def _pool_state(name: str) -> tuple[int, int, float | None]:
    import spiceypy

    from lunarmap.spice import SPICE_LOCK

    with SPICE_LOCK:
        n = int(spiceypy.ktotal("ALL"))
        found = spiceypy.expool(name)
        return os.getpid(), n, (float(spiceypy.gdpool(name, 0, 1)[0]) if found else None)


def test_kernel_plugin_teardown_and_worker_restart(client, tmp_path):
    from lunarmap.parallel import register_kernels
    from lunarmap.spice import KernelSet

    k = tmp_path / "plugin.tpc"
    k.write_text("KPL/PCK\n\\begindata\nLUNARMAP_PLUGIN_TEST = 7\n\\begintext\n")
    kset = KernelSet.from_files([k])
    plugin = register_kernels(client, kset)
    loaded = client.run(_pool_state, "LUNARMAP_PLUGIN_TEST")
    assert len(loaded) == 2 and all(s[1:] == (1, 7.0) for s in loaded.values())

    # restarted worker processes (new pids) get the kernels from the plugin again
    before = _pids(client)
    client.restart()
    restarted = client.run(_pool_state, "LUNARMAP_PLUGIN_TEST")
    assert not before & {s[0] for s in restarted.values()}
    assert all(s[1:] == (1, 7.0) for s in restarted.values())

    # removing the plugin tears it down: every worker's pool is empty again
    client.unregister_worker_plugin(plugin.name)
    cleared = client.run(_pool_state, "LUNARMAP_PLUGIN_TEST")
    assert all(s[1:] == (0, None) for s in cleared.values())


def _slow_fit(camera, height_range):
    """A task long enough (>= 0.4 s) for the kill to land while the graph is running."""
    from lunarmap.rpc import fit_rpc

    t0 = time.perf_counter()
    fit = fit_rpc(camera, height_range, check=False)
    time.sleep(max(0.0, 0.4 - (time.perf_counter() - t0)))
    return os.getpid(), fit.model.coefficients


def test_worker_killed_mid_graph_the_graph_completes_identically(client):
    from lunarmap.rpc import fit_rpc

    cams = _frame_cameras(12)
    serial = [fit_rpc(c, (-3000.0, 3000.0), check=False).model.coefficients for c in cams]
    pids_before = _pids(client)
    futures = client.map(_slow_fit, cams, [(-3000.0, 3000.0)] * len(cams), pure=False)
    # wait until some tasks have finished and a worker is running another, then kill that worker
    deadline, victim_addr = time.time() + 120, None
    while time.time() < deadline:
        done = sum(f.status == "finished" for f in futures)
        busy = [a for a, keys in client.processing().items() if keys]
        if done >= 2 and busy:
            victim_addr = busy[0]
            break
        time.sleep(0.02)
    assert victim_addr is not None, "the graph never reached a state with finished and running tasks"
    victim = client.run(os.getpid, workers=[victim_addr])[victim_addr]
    done_at_kill = sum(f.status == "finished" for f in futures)
    os.kill(victim, signal.SIGKILL)
    results = client.gather(futures)
    print(f"worker process {victim} killed with {done_at_kill} of {len(cams)} tasks finished; "
          f"results computed by {sorted({pid for pid, _ in results})}, workers now {sorted(_pids(client))}")
    # the outcome, not how the cluster got there: on a loaded machine the nanny may restart the killed
    # worker, or restart it and then close it (issue 28: `len(pids_after) == 2` failed once with 1)
    assert 0 < done_at_kill < len(cams), done_at_kill               # the kill landed mid-graph
    assert len(results) == len(cams)                                # the graph completed ...
    for (_, coeffs), ref in zip(results, serial):
        assert np.array_equal(coeffs, ref)                          # ... identical to serial
    assert victim in pids_before                                    # the victim was one of the workers
    ran_on = {pid for pid, _ in results}
    # the victim's finished results died with it: every result was (re)computed by another process
    assert victim not in ran_on
