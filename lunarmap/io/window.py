"""Image pixels read by window: the one way the tie-point chain touches an image file.

A :class:`PixelSource` names an image file (ISIS cube, PDS3 image, GeoTIFF through
:func:`~lunarmap.io.raster.open_image`, or a netCDF variable such as
:func:`lunarmap.simulate.render_block` writes) and reads any window ``[l0, l1) x [s0, s1)`` of it as
float64, NaN where the file says there is no data. Nothing is read until a window is asked for, and
only the file's blocks that the window touches are read (ISIS tiles, PDS3 records, GDAL windows,
netCDF/HDF5 chunks). An :class:`ArraySource` does the same for pixels already in memory, so the
matcher has one code path for both.

Sources are picklable by path (the open handle is not pickled: each process opens the file itself)
and hold no pixels, so a worker's memory does not grow with the size or the number of images it
has read from. Caching belongs to the callers that know what they will reuse
(:class:`lunarmap.matching.windowed.WindowedImage`), bounded in bytes.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from ..errors import ImageWindowError, LunarmapError

__all__ = ["PixelSource", "ArraySource", "WindowSource", "open_source"]

Array = NDArray[np.float64]


@runtime_checkable
class WindowSource(Protocol):
    """Anything the matcher can read pixels from by window.

    Attributes
    ----------
    shape : (int, int)
        ``(lines, samples)``.
    name : str
        What to call it in messages.
    """

    shape: tuple[int, int]
    name: str

    def read(self, l0: int, l1: int, s0: int, s1: int) -> Array:
        """Pixels ``[l0, l1) x [s0, s1)`` (array indices inside the image) as float64, NaN = no data."""
        ...


def _check_window(src: WindowSource, l0: int, l1: int, s0: int, s1: int) -> None:
    h, w = src.shape
    if not (0 <= l0 < l1 <= h and 0 <= s0 < s1 <= w):
        raise ImageWindowError(f"{src.name}: window lines [{l0}, {l1}) samples [{s0}, {s1}) is empty or outside "
                               f"the {h} x {w} image")


class ArraySource:
    """Pixels in memory, read by window like a file (see the module docstring).

    Parameters
    ----------
    pixels : array_like (lines, samples)
        Grey levels (NaN = no data).
    name : str
        What to call it in messages.
    """

    def __init__(self, pixels: Any, name: str = "image") -> None:
        arr = np.asarray(pixels)
        if arr.ndim != 2:
            raise ImageWindowError(f"{name}: pixels must be 2-D (line, sample), got shape {arr.shape}")
        self.pixels = arr
        self.shape = (int(arr.shape[0]), int(arr.shape[1]))
        self.name = name
        # saturation -> whether no pixel is invalid (views need no masking): see view()
        self._validity: dict[float | None, bool] = {}

    def read(self, l0: int, l1: int, s0: int, s1: int) -> Array:
        _check_window(self, l0, l1, s0, s1)
        return np.array(self.pixels[l0:l1, s0:s1], dtype=np.float64)

    def view(self, l0: int, l1: int, s0: int, s1: int, saturation: float | None = None) -> Array | None:
        """Pixels ``[l0, l1) x [s0, s1)`` as a read-only view of the array (no copy), or ``None``.

        ``None`` unless the array is float64 and none of its pixels is invalid (NaN, infinite or from
        ``saturation`` up): then a window needs no masking, and a reader that only reads it may skip
        :meth:`read`'s copy (issue 32, item 5: on a full-size NAC-like pair the copies of the matcher's
        regions were an eighth of its time). Checked once per array and saturation.
        """
        _check_window(self, l0, l1, s0, s1)
        if not self._valid(saturation):
            return None
        v = self.pixels[l0:l1, s0:s1]
        v.flags.writeable = False
        return v

    def _valid(self, saturation: float | None) -> bool:
        key = None if saturation is None else float(saturation)
        validity: dict[float | None, bool] = self.__dict__.setdefault("_validity", {})   # sources pickled before it
        known = validity.get(key)
        if known is None:
            px = self.pixels
            known = bool(px.dtype == np.float64 and px.size and np.isfinite(px).all()
                         and (key is None or px.max() < key))
            validity[key] = known
        return known

    def __repr__(self) -> str:
        return f"ArraySource({self.name!r}, {self.shape[0]} x {self.shape[1]})"


_NETCDF = (".nc", ".nc4", ".netcdf")

#: HDF5 chunk cache of each netCDF variable read by window, bytes (four 256 x 256 float32 chunks).
NETCDF_CHUNK_CACHE_BYTES = 1 << 20


class PixelSource:
    """An image file read by window (see the module docstring).

    Parameters
    ----------
    path : path-like
        ISIS cube, PDS3 image (attached or detached label), GeoTIFF/GDAL raster, or netCDF file.
    variable : str, optional
        netCDF variable (default: the file's only data variable).
    band : int
        0-based band of a multi-band file.

    Raises
    ------
    ImageWindowError
        No such file, an unreadable or damaged header, a variable that is not 2-D, a band that does
        not exist.
    """

    def __init__(self, path: str | os.PathLike[str], variable: str | None = None, band: int = 0) -> None:
        self.path = str(path)
        self.variable = variable
        self.band = int(band)
        self.name = self.path
        self._lock = threading.Lock()
        self._handle: Any = None
        handle = self._open()
        self.shape = (int(handle.shape[-2]), int(handle.shape[-1]))

    # -- opening ----------------------------------------------------------------------------
    def _open(self) -> Any:
        with self._lock:
            if self._handle is not None:
                return self._handle
            p = Path(self.path)
            if not p.is_file():
                raise ImageWindowError(f"image {self.path} does not exist")
            try:
                if p.suffix.lower() in _NETCDF:
                    handle = self._open_netcdf(p)
                else:
                    from .raster import open_image

                    handle = open_image(p).data           # dask (band, line, sample), nothing read yet
                    if not 0 <= self.band < handle.shape[0]:
                        raise ImageWindowError(f"image {self.path} has {handle.shape[0]} band(s); band {self.band} "
                                               "does not exist")
            except ImageWindowError:
                raise
            except (OSError, ValueError, KeyError, LunarmapError) as err:
                raise ImageWindowError(f"image {self.path} is not readable: {type(err).__name__}: {err}") from None
            self._handle = handle
            return handle

    def _open_netcdf(self, p: Path) -> Any:
        from .nclock import netcdf_library

        with netcdf_library():
            return self._open_netcdf_locked(p)

    def _open_netcdf_locked(self, p: Path) -> Any:
        import netCDF4

        ds = netCDF4.Dataset(p, "r")
        ds.set_auto_mask(False)
        names = [self.variable] if self.variable else [n for n, v in ds.variables.items()
                                                        if n not in ds.dimensions and v.ndim >= 2]
        if len(names) != 1 or names[0] not in ds.variables:
            ds.close()     # under the lock already
            raise ImageWindowError(f"netCDF image {p}: give one 2-D pixel variable (found {names or 'none'})")
        var = ds.variables[names[0]]
        if var.ndim != 2:
            ds.close()
            raise ImageWindowError(f"netCDF image {p}: variable {names[0]} must be 2-D (line, sample), got "
                                   f"dims {var.dimensions}")
        # HDF5 keeps a chunk cache per open variable (64 MB by default in netCDF-C 4.9+) that fills as windows
        # are read and is kept while the file is open: a worker holding the four pyramid levels of eight
        # full-size images open grew by ~1 GB. The matcher's region cache (bounded in bytes) already keeps
        # what is read again, so HDF5 keeps only a few chunks
        if var.chunking() != "contiguous":
            var.set_var_chunk_cache(size=NETCDF_CHUNK_CACHE_BYTES, nelems=61, preemption=0.75)
        return _NetcdfVariable(ds, var)

    # -- reading ----------------------------------------------------------------------------
    def read(self, l0: int, l1: int, s0: int, s1: int) -> Array:
        """Pixels ``[l0, l1) x [s0, s1)`` as float64 (NaN = no data / special pixels).

        Raises
        ------
        ImageWindowError
            A window outside the image, or a file that turns out damaged or truncated where the
            window lies (the file and the window are named).
        """
        _check_window(self, l0, l1, s0, s1)
        handle = self._open()
        try:
            if isinstance(handle, _NetcdfVariable):
                block = handle.read(l0, l1, s0, s1)       # under the process's netCDF lock
            else:
                block = handle[self.band, l0:l1, s0:s1].compute(scheduler="sync")
        except ImageWindowError:
            raise
        except (OSError, ValueError, RuntimeError, LunarmapError) as err:
            raise ImageWindowError(f"image {self.path}: window lines [{l0}, {l1}) samples [{s0}, {s1}) is not "
                                   f"readable: {type(err).__name__}: {err}") from None
        out = np.asarray(block, dtype=np.float64)
        if out.shape != (l1 - l0, s1 - s0):
            raise ImageWindowError(f"image {self.path}: window lines [{l0}, {l1}) samples [{s0}, {s1}) read as "
                                   f"{out.shape}: the file is shorter than its header says")
        return out

    # -- pickling: the path, not the handle -----------------------------------------------------
    def __getstate__(self) -> dict[str, Any]:
        return {"path": self.path, "variable": self.variable, "band": self.band, "shape": self.shape}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.path, self.variable, self.band = state["path"], state["variable"], state["band"]
        self.shape = tuple(state["shape"])
        self.name = self.path
        self._lock = threading.Lock()
        self._handle = None

    def close(self) -> None:
        """Close the open file (it is reopened on the next read)."""
        with self._lock:
            if isinstance(self._handle, _NetcdfVariable):
                self._handle.close()
            self._handle = None

    def __repr__(self) -> str:
        return f"PixelSource({self.path!r}, {self.shape[0]} x {self.shape[1]})"


class _NetcdfVariable:
    """An open netCDF variable: slices read through netCDF4 (only the chunks touched), fill values -> NaN."""

    def __init__(self, ds: Any, var: Any) -> None:
        self.ds, self.var = ds, var
        self.shape = tuple(int(n) for n in var.shape)
        fill = getattr(var, "_FillValue", None)
        self.fill = None if fill is None else float(np.asarray(fill).ravel()[0])
        self.scale = float(getattr(var, "scale_factor", 1.0))
        self.offset = float(getattr(var, "add_offset", 0.0))

    def read(self, l0: int, l1: int, s0: int, s1: int) -> Array:
        from .nclock import netcdf_library

        with netcdf_library():                  # netCDF-C/HDF5 are not thread-safe (lunarmap.io.nclock)
            raw = np.asarray(self.var[l0:l1, s0:s1])
        out = raw.astype(np.float64)
        if self.fill is not None and not np.isnan(self.fill):
            out[raw == self.fill] = np.nan
        if self.scale != 1.0 or self.offset != 0.0:
            out = self.offset + self.scale * out
        return out

    def close(self) -> None:
        from .nclock import close_dataset

        close_dataset(self.ds)

    def __del__(self) -> None:
        # dropped without close(): closed under the lock (or by its next holder), never by netCDF4's
        # deallocator in whatever thread the collector runs
        try:
            from .nclock import close_dataset

            close_dataset(self.ds, wait=False)
        except Exception:  # noqa: BLE001 - interpreter shutdown: modules may be gone
            pass


def open_source(pixels: Any, name: str = "image") -> WindowSource:
    """A :class:`WindowSource` for a path (:class:`PixelSource`), a source, or in-memory pixels.

    Parameters
    ----------
    pixels : path-like, WindowSource, xarray.DataArray or array_like
        An image file, a source, or pixels (an ``xarray.DataArray`` backed by dask stays lazy: each
        window computes only the chunks it touches).
    name : str
        Name of in-memory pixels in messages.
    """
    if isinstance(pixels, (str, os.PathLike)):
        return PixelSource(pixels)
    if isinstance(pixels, WindowSource) and not isinstance(pixels, np.ndarray):
        return pixels
    data = getattr(pixels, "data", pixels)
    if hasattr(data, "dask"):
        return _LazySource(data, name)
    return ArraySource(pixels.values if hasattr(pixels, "values") and not isinstance(pixels, np.ndarray)
                       else pixels, name)


class _LazySource:
    """A lazy (dask) 2-D array read by window: each window computes only the chunks it touches."""

    def __init__(self, data: Any, name: str) -> None:
        if data.ndim != 2:
            raise ImageWindowError(f"{name}: pixels must be 2-D (line, sample), got shape {data.shape}")
        self.data, self.name = data, name
        self.shape = (int(data.shape[0]), int(data.shape[1]))

    def read(self, l0: int, l1: int, s0: int, s1: int) -> Array:
        _check_window(self, l0, l1, s0, s1)
        return np.asarray(self.data[l0:l1, s0:s1].compute(scheduler="sync"), dtype=np.float64)

