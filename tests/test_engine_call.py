"""The run graph's task function (``lunarmap.workflows.engine._call``) on a distributed worker: steps must not
see the worker's client as dask's scheduler, or xarray takes a cluster-wide ``distributed.Lock`` (a round trip
to the scheduler) for every netCDF file a step writes, which serialised the workers' RFM writes (measured: 48
RFM steps on 2 workers, 0.181 s per step with the lock, 0.089 s without)."""

from __future__ import annotations

import pytest

distributed = pytest.importorskip("distributed")


def _xarray_scheduler() -> str | None:
    from xarray.backends.locks import get_dask_scheduler

    return get_dask_scheduler()


def test_steps_on_a_worker_write_netcdf_without_the_cluster_lock():
    from lunarmap.workflows.engine import _call

    with distributed.Client(processes=False, n_workers=1, threads_per_worker=1, dashboard_address=":0") as client:
        bare = client.submit(_xarray_scheduler, pure=False).result()
        wrapped = client.submit(_call, _xarray_scheduler, pure=False).result()
    assert bare == "distributed"          # the oracle: xarray's own choice on a worker, without the wrapper
    assert wrapped != "distributed"
