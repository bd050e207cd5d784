"""Reading netCDF files that may come from anywhere: load, close, and name every failure.

The netCDF/HDF5 libraries answer a damaged or foreign file with ``OSError``, ``RuntimeError``
("NetCDF: HDF error"), or with ``ValueError`` / ``KeyError`` from xarray's decoding; fuzzing found
each of them escaping lunarmap's readers. :func:`load_netcdf` turns them into the reader's own
lunarmap exception, which names the file; a missing file stays ``FileNotFoundError``.
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
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{what} {p} does not exist")
    try:
        with xr.open_dataset(p, engine="netcdf4") as ds:
            return ds.load()
    except LunarmapError:
        raise
    except Exception as err:  # noqa: BLE001 - whatever the netCDF stack raises on a bad file, named here
        raise error(f"{what} {p} is not a readable netCDF file: {type(err).__name__}: {err}") from err
