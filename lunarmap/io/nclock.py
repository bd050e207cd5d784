"""The one lock around the netCDF-C and HDF5 libraries in a process.

Neither library is thread-safe, and netCDF4-python releases the GIL inside them: two threads of one
process in netCDF-C at once (a threaded dask scheduler's reads, a file closed by the garbage collector
in the distributed client's event-loop thread while the main thread opens another) corrupt the
library's state, which shows up as a spurious error far from its cause (measured: ``NetCDF: Can't open
HDF5 attribute`` opening an intact image while building a 192-image run's graph). Every netCDF4 call of
lunarmap's readers and writers holds this lock; it is xarray's own ``HDF5_LOCK``, which xarray's
netCDF4 backend also takes, so lunarmap's calls and xarray's are serialised with each other. Hold it
only around the netCDF calls themselves: it is not re-entrant, and xarray takes it inside its own calls.
"""

from __future__ import annotations

import contextlib
import threading
from typing import Any, Iterator

__all__ = ["netcdf_library", "close_dataset"]

_LOCK: Any
try:
    from xarray.backends.locks import HDF5_LOCK as _LOCK
except ImportError:  # pragma: no cover - xarray is a dependency; an older layout keeps a lock of our own
    _LOCK = threading.Lock()

# datasets dropped (garbage-collected) while another thread was inside the library: closed by the next
# holder of the lock instead of by netCDF4's deallocator, which would close them without it
_PENDING: list[Any] = []
_PENDING_LOCK = threading.Lock()


def _drain() -> None:
    with _PENDING_LOCK:
        pending = _PENDING[:]
        _PENDING.clear()
    for ds in pending:
        _close(ds)


def _close(ds: Any) -> None:
    try:
        ds.close()
    except RuntimeError:      # already closed
        pass


@contextlib.contextmanager
def netcdf_library() -> Iterator[None]:
    """Hold the process's netCDF/HDF5 lock for the calls inside the block (closing deferred datasets first)."""
    with _LOCK:
        _drain()
        yield


def close_dataset(ds: Any, *, wait: bool = True) -> None:
    """Close a netCDF4 Dataset under the lock.

    With ``wait=False`` (a finaliser, which may run in any thread, also in one that holds the lock) the
    close is deferred to the lock's next holder when the lock is taken.
    """
    if wait:
        with netcdf_library():
            _close(ds)
        return
    if _LOCK.acquire(blocking=False):
        try:
            _drain()
            _close(ds)
        finally:
            _LOCK.release()
    else:
        with _PENDING_LOCK:
            _PENDING.append(ds)
