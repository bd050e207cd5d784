"""Reading netCDF files that may come from anywhere: load, close, and name every failure.

The netCDF/HDF5 libraries answer a damaged or foreign file with ``OSError``, ``RuntimeError``
("NetCDF: HDF error"), or with ``ValueError`` / ``KeyError`` from xarray's decoding; fuzzing found
each of them escaping lunarmap's readers. :func:`load_netcdf` turns them into the reader's own
lunarmap exception, which names the file; a missing file stays ``FileNotFoundError``.

The file is read into memory and opened from there (``netCDF4.Dataset(memory=...)``): when the
netCDF-C / HDF5 libraries fail to open a damaged *file*, they leave its descriptor open (fuzzing
leaked one per bad file, ~500 in a run, until "Too many open files"); from memory no descriptor is
involved. The whole dataset is loaded anyway, so this costs no more memory than before.
"""

from __future__ import annotations

import os
from pathlib import Path

import xarray as xr

from .errors import LunarmapError

__all__ = ["load_netcdf"]


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
