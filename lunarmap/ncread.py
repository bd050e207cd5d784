"""Reading netCDF files that may come from anywhere: load, close, and name every failure.

The netCDF/HDF5 libraries answer a damaged or foreign file with ``OSError``, ``RuntimeError``
("NetCDF: HDF error"), or with ``ValueError`` / ``KeyError`` from xarray's decoding; fuzzing found
each of them escaping lunarmap's readers. :func:`load_netcdf` turns them into the reader's own
lunarmap exception, which names the file; a missing file stays ``FileNotFoundError``.

The file is read into memory and opened from there (``netCDF4.Dataset(memory=...)``): when the
netCDF-C / HDF5 libraries fail to open a damaged *file*, they leave its descriptor open (fuzzing
leaked one per bad file, ~500 in a run, until "Too many open files"); from memory no descriptor is
involved. The whole dataset is loaded anyway, so this costs no more memory than before.

A damaged file can also send HDF5 into an endless loop inside ``nc_open`` (fuzzing found one: a
mutated tie-point table on which netCDF-C never returns, from a file or from memory), which no
Python-level timeout can interrupt. So the open is first tried in a forked child that is killed after
:data:`PROBE_TIMEOUT` seconds (a few milliseconds for a good file); a child that hangs or crashes
means a named error here instead of a hung or crashed caller. A fork taken while another thread
held a lock the child needs could stall a good file's probe, so a timed-out fork is retried once in
a fresh interpreter before the file is declared unreadable.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import xarray as xr

from .errors import LunarmapError

__all__ = ["load_netcdf", "PROBE_TIMEOUT"]

#: Seconds the netCDF library may take to open a file's metadata in the probe before the file counts as
#: one it cannot read (good files take milliseconds; the metadata is all that ``nc_open`` reads).
PROBE_TIMEOUT = float(os.environ.get("LUNARMAP_NETCDF_PROBE_TIMEOUT", "5"))


def _probe_fork(data: bytes, timeout: float) -> str:
    """Open ``data`` with netCDF4 in a forked child: ``"ok"``, ``"hang"`` or ``"crash"``."""
    import netCDF4

    pid = os.fork()
    if pid == 0:  # child: only the open, then leave without running the parent's exit handlers
        try:
            netCDF4.Dataset("probe", mode="r", memory=data).close()
        except BaseException:  # noqa: BLE001 - an exception is the parent's to report, not a hang
            pass
        os._exit(0)
    deadline = time.monotonic() + timeout
    pause = 0.0005
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            return "ok" if os.WIFEXITED(status) else "crash"
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            return "hang"
        time.sleep(pause)
        pause = min(2 * pause, 0.05)


def _probe_spawn(path: Path, timeout: float) -> str:
    """The same probe in a fresh interpreter (no locks inherited from the caller's threads)."""
    code = "import sys, netCDF4\ntry:\n    netCDF4.Dataset(sys.argv[1], mode='r').close()\nexcept Exception:\n    pass\n"
    try:
        res = subprocess.run([sys.executable, "-c", code, str(path)], timeout=timeout + 2.0,
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        return "hang"
    return "ok" if res.returncode == 0 else "crash"


def _probe(path: Path, data: bytes) -> str:
    if not hasattr(os, "fork"):
        return "ok"          # no fork (Windows): open directly, as every netCDF reader does
    out = _probe_fork(data, PROBE_TIMEOUT)
    if out == "hang":
        out = _probe_spawn(path, PROBE_TIMEOUT)
    return out


def load_netcdf(path: str | os.PathLike[str], error: type[LunarmapError], what: str) -> xr.Dataset:
    """Open a netCDF file, load it into memory and close it.

    Parameters
    ----------
    path : path-like
        The file.
    error : type
        The lunarmap exception to raise when the file cannot be read.
    what : str
        What the file should hold (``"control network"``), for the message.

    Raises
    ------
    FileNotFoundError
        No such file.
    error
        The file is not a readable netCDF file.
    """
    import netCDF4

    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{what} {p} does not exist")
    data = p.read_bytes()
    state = _probe(p, data)
    if state != "ok":
        why = (f"the netCDF library did not finish opening it within {PROBE_TIMEOUT:g} s" if state == "hang"
               else "the netCDF library crashed opening it")
        raise error(f"{what} {p} is not a readable netCDF file: {why} (a damaged file)")
    try:
        nc = netCDF4.Dataset(str(p), mode="r", memory=data)
    except Exception as err:  # noqa: BLE001 - whatever the netCDF stack raises on a bad file, named here
        raise error(f"{what} {p} is not a readable netCDF file: {type(err).__name__}: {err}") from err
    try:
        with xr.open_dataset(xr.backends.NetCDF4DataStore(nc)) as ds:
            return ds.load()
    except LunarmapError:
        raise
    except Exception as err:  # noqa: BLE001
        raise error(f"{what} {p} is not a readable netCDF file: {type(err).__name__}: {err}") from err
    finally:
        if nc.isopen():
            nc.close()
