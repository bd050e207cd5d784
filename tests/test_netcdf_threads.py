"""netCDF-C and HDF5 are not thread-safe: lunarmap's netCDF readers and writers share one lock per process
(``lunarmap.io.nclock``), also with xarray's own netCDF calls."""

from __future__ import annotations

import gc
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import xarray as xr

from lunarmap.io.nclock import close_dataset, netcdf_library
from lunarmap.io.pyramid import Pyramid, write_pyramid
from lunarmap.io.window import ArraySource, PixelSource


def _images(tmp_path, n=4, shape=(300, 260)):
    rng = np.random.default_rng(3)
    paths, arrays = [], []
    for i in range(n):
        a = rng.normal(100, 10, shape).astype("f4")
        p = tmp_path / f"im{i}.nc"
        xr.DataArray(a, dims=("line", "sample"), name="dn").to_dataset().to_netcdf(
            p, encoding={"dn": {"chunksizes": (min(64, shape[0]), min(64, shape[1]))}})
        paths.append(p)
        arrays.append(a.astype(np.float64))
    return paths, arrays


def test_threads_opening_reading_closing_dropping_and_writing_at_once(tmp_path):
    """Eight threads: windows read from shared sources and from fresh ones (closed, or dropped unclosed: the
    collector closes them in whatever thread it runs), pyramids written;
    every value as read alone (truth: the arrays written). Without the one lock this crashes the process.
    (xarray's own netCDF4 reads are not safe under threads either and are not part of this: the run reads
    pixels only through these sources.)"""
    paths, arrays = _images(tmp_path)
    shared = [PixelSource(p) for p in paths]
    rng = np.random.default_rng(0)
    jobs = [(k, int(rng.integers(4)), int(rng.integers(0, 200)), int(rng.integers(0, 160)), k % 4) for k in range(400)]

    def work(job):
        k, i, l0, s0, kind = job
        want = arrays[i][l0:l0 + 64, s0:s0 + 64]
        if kind == 0:
            got = shared[i].read(l0, l0 + 64, s0, s0 + 64)
        elif kind == 1:
            got = PixelSource(paths[i]).read(l0, l0 + 64, s0, s0 + 64)    # dropped without close()
            gc.collect()
        elif kind == 2:                 # a fresh source closed by its thread
            src = PixelSource(paths[i])
            got = src.read(l0, l0 + 64, s0, s0 + 64)
            src.close()
        else:
            out = tmp_path / f"pyr_{k}.nc"
            write_pyramid(PixelSource(paths[i]), out, levels=2)
            got = PixelSource(out, variable="level_1").read(0, 32, 0, 32)
            want = arrays[i][:64, :64].reshape(32, 2, 32, 2).mean(axis=(1, 3))
            assert Pyramid(out).path == str(out)
        return np.allclose(got, want, rtol=1e-6, atol=1e-4)

    with ThreadPoolExecutor(8) as ex:
        ok = list(ex.map(work, jobs))
    assert all(ok)


def test_a_dataset_dropped_while_the_lock_is_held_is_closed_by_its_next_holder(tmp_path):
    import netCDF4

    paths, _ = _images(tmp_path, n=1, shape=(8, 8))
    with netcdf_library():
        ds = netCDF4.Dataset(paths[0], "r")
        close_dataset(ds, wait=False)          # as a finaliser would, in the thread holding the lock
        assert ds.isopen()                     # not closed behind the lock's back
    with netcdf_library():
        pass
    assert not ds.isopen()


def test_in_memory_sources_need_no_lock():
    a = np.arange(12.0).reshape(3, 4)
    assert np.array_equal(ArraySource(a).read(0, 2, 1, 3), a[0:2, 1:3])
