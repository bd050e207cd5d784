"""Cameras, RFMs and the SPICE layer hammered from several threads at once.

Each round makes fresh objects, so the first use (the lazy per-line EO table, the DTM sampler, the
frame-corrections stack, the kernel pool) is concurrent; 4 threads released by a barrier run every
operation in a different order, and every result must be bit-identical to the same operations run
serially on an independent copy. ``in_threads`` re-raises any thread's exception, so a crashing
thread fails the test (``test_thread_helper_fails_when_a_thread_raises`` in test_kernels.py).
"""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from lunarmap.camera import FrameCamera, LineScanCamera, Shape
from lunarmap.simulate.orbits import NAC_LINE_TIME, frame_interior, nac_like_interior, polar_orbit_eo
from threadhelp import in_threads

ROUNDS = 100
N_THREADS = 4


def _linescan(workers: int = 1, n_lines: int = 4000) -> LineScanCamera:
    eo = polar_orbit_eo(lat_center=10.0, lon=30.0, half_span=0.6 * n_lines * NAC_LINE_TIME + 0.5, step=0.05)
    return LineScanCamera(nac_like_interior(n_lines=n_lines), eo, Shape.moon(),
                          line_times=(-n_lines * NAC_LINE_TIME / 2.0, NAC_LINE_TIME), workers=workers)


def _frame() -> FrameCamera:
    eo = polar_orbit_eo(lat_center=10.0, lon=30.0, half_span=0.0, step=1.0)
    return FrameCamera(frame_interior(), eo, Shape.moon())


def _dtm(height: float, tilt: float) -> xr.DataArray:
    lat, lon = np.linspace(8, 12, 81), np.linspace(28, 32, 81)
    z = height + tilt * (lat[:, None] - 10.0) * 1e3 + 0.0 * lon[None, :]
    return xr.DataArray(z, dims=("lat", "lon"), coords={"lat": lat, "lon": lon})


@pytest.fixture(scope="module")
def inputs():
    rng = np.random.default_rng(15)
    dtms = (_dtm(300.0, 0.2), _dtm(-500.0, -0.1))
    ls_pix = (rng.uniform(0, 4000, 300), rng.uniform(0, 5064, 300))
    fr_pix = (rng.uniform(0, 288, 300), rng.uniform(0, 384, 300))
    return dtms, ls_pix, fr_pix


def _camera_ops(cam, pix, dtms):
    """Every operation with a lazy cache behind it, as (name, thunk) pairs."""
    line, sample = pix
    ground = cam.image_to_ground(line, sample, height=100.0)  # computed up front: the thunks read it only
    return [
        ("g2i", lambda: cam.ground_to_image(ground)),
        ("i2g_dtm_a", lambda: cam.image_to_ground(line, sample, dtm=dtms[0])),
        ("i2g_dtm_b", lambda: cam.image_to_ground(line, sample, dtm=dtms[1])),
        ("rays", lambda: cam.rays(line, sample)),
        ("partials", lambda: cam.ground_partials(ground)),
        ("corr_partials", lambda: cam.corrections().partials(np.zeros(cam.corrections().n_params), ground)),
    ]


def _same(a, b) -> bool:
    if isinstance(a, tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return np.array_equal(a, b, equal_nan=True)


def _hammer(make, pix, dtms, rounds: int = ROUNDS) -> int:
    """``rounds`` rounds of 4 threads on a fresh object each; returns the operations compared."""
    reference = {name: fn() for name, fn in _camera_ops(make(), pix, dtms)}
    compared = 0
    for r in range(rounds):
        cam = make()
        ops = _camera_ops(cam, pix, dtms) if r % 2 else None  # odd rounds: the table exists before g2i's ground

        def work(i: int) -> dict:
            mine = ops if ops is not None else _camera_ops(cam, pix, dtms)
            k = (i + r) % len(mine)
            return {name: fn() for name, fn in mine[k:] + mine[:k]}   # each thread in its own order

        for got in in_threads(work, N_THREADS):
            for name, value in got.items():
                assert _same(value, reference[name]), f"round {r}: {name} differs from the serial result"
                compared += 1
    return compared


def test_linescan_camera_first_use_from_threads(inputs):
    dtms, ls_pix, _ = inputs
    assert _hammer(_linescan, ls_pix, dtms) == ROUNDS * N_THREADS * 6


def test_frame_camera_first_use_from_threads(inputs):
    dtms, _, fr_pix = inputs
    assert _hammer(_frame, fr_pix, dtms) == ROUNDS * N_THREADS * 6


def test_threaded_ground_to_image_equals_serial():
    """``workers > 1`` splits the points over a thread pool; 4 callers at once on a fresh camera each round."""
    serial = _linescan(workers=1, n_lines=20000)
    rng = np.random.default_rng(3)
    n = 80_000   # > 2 chunks of 32,768 points: the pool really splits
    ground = serial.image_to_ground(rng.uniform(0, 20000, n), rng.uniform(0, 5064, n), height=rng.uniform(-2e3, 2e3, n))
    ref = serial.ground_to_image(ground)
    assert np.all(np.isfinite(ref[0]))
    for _ in range(5):
        cam = _linescan(workers=3, n_lines=20000)
        for line, sample in in_threads(lambda i: cam.ground_to_image(ground), N_THREADS):
            assert np.array_equal(line, ref[0]) and np.array_equal(sample, ref[1])


@pytest.fixture(scope="module")
def rfm():
    from lunarmap.rpc import fit_rpc

    return fit_rpc(_frame(), (-3000.0, 3000.0), check=False).model


def test_rfm_from_threads(rfm, inputs):
    dtms, _, fr_pix = inputs
    line, sample = fr_pix
    o = rfm.offsets

    def ops():
        return [("l2i", lambda: rfm.lonlat_to_image(o[3] + 0.01 * np.sin(line), o[2] + 0.01 * np.cos(sample), 50.0)),
                ("i2l", lambda: rfm.image_to_lonlat(line, sample, 50.0)),
                ("i2g_dtm", lambda: rfm.image_to_ground(line, sample, dtm=dtms[0])),
                ("jac", lambda: rfm.jacobian(o[3], o[2], 0.0))]

    reference = {name: fn() for name, fn in ops()}
    for r in range(ROUNDS):
        def work(i: int) -> dict:
            mine = ops()
            k = (i + r) % len(mine)
            return {name: fn() for name, fn in mine[k:] + mine[:k]}

        for got in in_threads(work, N_THREADS):
            assert all(_same(v, reference[k]) for k, v in got.items()), f"round {r}"


def test_rpc_fits_from_threads(rfm):
    """Four fits at once (OpenBLAS is held at one thread by a shared, counted context) equal the serial fit."""
    from lunarmap.rpc import fit_rpc

    for _ in range(5):
        cam = _frame()
        fits = in_threads(lambda i: fit_rpc(cam, (-3000.0, 3000.0), check=False).model, N_THREADS)
        for m in fits:
            assert np.array_equal(m.coefficients, rfm.coefficients)
            assert np.array_equal(m.offsets, rfm.offsets) and np.array_equal(m.scales, rfm.scales)


def test_spice_layer_from_threads(sim_mission, tmp_path):
    """The kernel pool is loaded by whichever thread comes first; two kernel sets alternate between threads."""
    from lunarmap.spice import KernelSet, clear, kernels
    from lunarmap.spice import queries as q
    from lunarmap.synthetic.ids import NAC_FRAME, SPACECRAFT_ID

    mission = KernelSet.from_metakernel(sim_mission)
    text = tmp_path / "t.tpc"
    text.write_text("KPL/PCK\n\\begindata\nLUNARMAP_THREADS = ( 1.5 2.5 )\n\\begintext\n")
    other = KernelSet.from_files([text])
    with kernels(mission):
        t0 = q.str2et("2026-03-21T00:17:40")
    ets = t0 + np.linspace(0.0, 10.0, 50)

    def job(i: int):
        if i % 2:
            with kernels(other):
                return q.pool_values("LUNARMAP_THREADS")
        with kernels(mission):
            return q.states(SPACECRAFT_ID, ets, "J2000", "NONE", 301), q.rotations("J2000", NAC_FRAME, ets)

    clear()
    reference = [job(i) for i in range(N_THREADS)]
    for _ in range(ROUNDS):
        clear()   # nothing resident: the first use is concurrent
        got = in_threads(job, N_THREADS)
        for a, b in zip(got, reference):
            assert _same(tuple(a), tuple(b))
    clear()


def test_image_support_from_threads(sim_mission):
    """Whole ISDs (driver, label, one locked SPICE pass) for 4 images at once equal the serial ones."""
    from lunarmap.orientation.drivers import image_support
    from lunarmap.spice import clear

    # the two frame images, twice each (a NAC-like ISD of 52,224 lines takes ~1 s: too slow to repeat)
    labels = sorted(sim_mission.parent.glob("sim_frame_*.lbl")) * 2
    assert len(labels) == N_THREADS
    clear()
    reference = [image_support(lab, sim_mission).to_ale_dict() for lab in labels]
    for _ in range(25):
        clear()
        got = in_threads(lambda i: image_support(labels[i], sim_mission).to_ale_dict(), N_THREADS)
        assert got == reference
    clear()


def test_lazy_caches_are_built_once_under_contention(monkeypatch, inputs):
    """Slowed-down builders: 4 threads asking at once still build each cache exactly once."""
    import threading
    import time

    import lunarmap.camera.corrections as corrections
    import lunarmap.camera.frame as frame

    dtms, ls_pix, fr_pix = inputs
    calls = {"table": 0, "sampler": 0, "stack": 0}
    count_lock = threading.Lock()

    def count(name):
        with count_lock:
            calls[name] += 1
        time.sleep(0.05)   # a wide window for a second builder to slip in

    def slow_table(self):
        count("table")
        return new_table(self)

    class SlowSampler(frame.DtmSampler):
        def __init__(self, *args, **kwargs):
            count("sampler")
            super().__init__(*args, **kwargs)

    class SlowStack(corrections.FrameStack):
        def __init__(self, *args, **kwargs):
            count("stack")
            super().__init__(*args, **kwargs)

    new_table = LineScanCamera._new_table
    monkeypatch.setattr(LineScanCamera, "_new_table", slow_table)
    monkeypatch.setattr(frame, "DtmSampler", SlowSampler)
    monkeypatch.setattr(corrections, "FrameStack", SlowStack)

    cam = _linescan()
    in_threads(lambda i: cam.image_to_ground(*ls_pix, dtm=dtms[0]), N_THREADS)
    fcam = _frame()
    corr = fcam.corrections()
    ground = fcam.image_to_ground(*fr_pix)
    in_threads(lambda i: corr.project(np.zeros(6), ground), N_THREADS)
    assert calls == {"table": 1, "sampler": 1, "stack": 1}
