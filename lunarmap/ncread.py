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


def memory_bound(nbytes: int) -> int:
    """Bytes a reader may allocate beyond its base for a file of ``nbytes``: 10 x its size + 64 MB."""
    return 10 * int(nbytes) + (64 << 20)


def _address_space() -> int:
    """This process's virtual address space in bytes (Linux; 0 elsewhere, which disables the limit)."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def _probe_fork(data: bytes, timeout: float) -> str:
    """Open ``data`` with netCDF4 in a forked child: ``"ok"``, ``"hang"``, ``"crash"`` or ``"memory"``.

    The child's address space is limited to its base + :func:`memory_bound` of the file and it also
    reads the variable-length (string) variables, whose sizes are stored in the file: a damaged length
    that asks for gigabytes fails there, quickly, instead of in the caller.
    """
    import netCDF4

    base = _address_space()
    pid = os.fork()
    if pid == 0:  # child: only the open, then leave without running the parent's exit handlers
        code = 0
        try:
            if base:
                import resource

                limit = base + memory_bound(len(data))
                resource.setrlimit(resource.RLIMIT_AS, (limit, resource.getrlimit(resource.RLIMIT_AS)[1]))
            nc = netCDF4.Dataset("probe", mode="r", memory=data)
            for v in nc.variables.values():
                if v.dtype is str or type(v.datatype).__name__ == "VLType":
                    v.set_auto_mask(False)
                    v[...]
            nc.close()
        except MemoryError:
            code = 3
        except BaseException:  # noqa: BLE001 - an exception is the parent's to report, not a hang
            pass
        os._exit(code)
    deadline = time.monotonic() + timeout
    pause = 0.0005
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            if os.WIFEXITED(status):
                return "memory" if os.WEXITSTATUS(status) == 3 else "ok"
            return "crash"
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
        why = {"hang": f"the netCDF library did not finish opening it within {PROBE_TIMEOUT:g} s",
               "memory": f"reading it needs more than {memory_bound(len(data)) >> 20} MB (10 x its size + 64 MB): "
                         "damaged sizes"}.get(state, "the netCDF library crashed opening it")
        raise error(f"{what} {p} is not a readable netCDF file: {why} (a damaged file)")
    from .io.nclock import netcdf_library

    try:
        with netcdf_library():       # netCDF-C is not thread-safe; xarray below takes the same lock itself
            nc = netCDF4.Dataset(str(p), mode="r", memory=data)
    except Exception as err:  # noqa: BLE001 - whatever the netCDF stack raises on a bad file, named here
        raise error(f"{what} {p} is not a readable netCDF file: {type(err).__name__}: {err}") from err
    try:
        declared = 0
        for v in nc.variables.values():
            if isinstance(v.dtype, type) and v.dtype is str:
                continue
            n = 1
            for d in v.shape:
                n *= int(d)
            declared += n * getattr(v.dtype, "itemsize", 8)
        if declared > memory_bound(len(data)):
            raise error(f"{what} {p} is not a readable netCDF file: its variables declare {declared} bytes, more "
                        f"than 10 x the file's {len(data)} bytes + 64 MB (damaged dimensions)")
        with xr.open_dataset(xr.backends.NetCDF4DataStore(nc)) as ds:
            return ds.load()
    except LunarmapError:
        raise
    except Exception as err:  # noqa: BLE001
        raise error(f"{what} {p} is not a readable netCDF file: {type(err).__name__}: {err}") from err
    finally:
        with netcdf_library():
            if nc.isopen():
                nc.close()
