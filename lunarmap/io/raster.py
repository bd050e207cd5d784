"""One entry point for image pixels: ISIS cubes, PDS3 images and GeoTIFF, as lazy ``xarray.DataArray``.

:func:`open_image` recognises the file by its first bytes and returns ``(band, line, sample)``
pixel values (NaN where the file says there is no data) with the pixel-centre coordinates of the
project's convention (CSM: first pixel centre at 0.5), chunked with dask; nothing but the label
(header) is read until values are asked for.

* ISIS cubes: :class:`lunarmap.io.cube.IsisCube` (all five special pixels to NaN);
* PDS3 images (``PDS_VERSION_ID``, attached label or a detached ``.lbl`` whose ``^IMAGE`` names
  the data file): band-sequential ``IMAGE`` objects of ``MSB``/``LSB``/``PC``/``MAC`` integers
  and ``IEEE``/``PC`` reals, with line prefix and suffix bytes, ``OFFSET`` and
  ``SCALING_FACTOR``; the label's ``MISSING_CONSTANT`` / ``NULL`` and saturation values become
  NaN. Read here (a ``pread`` per chunk), like the ISIS core;
* GeoTIFF (and anything else GDAL reads): through ``rasterio`` (optional dependency, ``pip
  install lunarmap[raster]``), one window per chunk; the band's nodata value becomes NaN.
  TIFF's compression, tiling and overviews are GDAL's business, not ours.
"""

from __future__ import annotations

import os
import re
from typing import Any

import dask.array as da
import numpy as np
import xarray as xr
from numpy.typing import NDArray

from ..errors import CubeFormatError, LabelError
from ..labels import Label, parse_label
from ..labels.pvl import label_int
from .cube import IsisCube

__all__ = ["open_image", "image_kind"]

_PDS3_TYPES = {
    ("MSB_INTEGER", 1): ">i1", ("MSB_INTEGER", 2): ">i2", ("MSB_INTEGER", 4): ">i4",
    ("LSB_INTEGER", 1): "<i1", ("LSB_INTEGER", 2): "<i2", ("LSB_INTEGER", 4): "<i4",
    ("MSB_UNSIGNED_INTEGER", 1): "u1", ("MSB_UNSIGNED_INTEGER", 2): ">u2", ("MSB_UNSIGNED_INTEGER", 4): ">u4",
    ("LSB_UNSIGNED_INTEGER", 1): "u1", ("LSB_UNSIGNED_INTEGER", 2): "<u2", ("LSB_UNSIGNED_INTEGER", 4): "<u4",
    ("UNSIGNED_INTEGER", 1): "u1", ("UNSIGNED_INTEGER", 2): ">u2", ("UNSIGNED_INTEGER", 4): ">u4",
    ("INTEGER", 1): "i1", ("INTEGER", 2): ">i2", ("INTEGER", 4): ">i4",
    ("SUN_INTEGER", 2): ">i2", ("SUN_INTEGER", 4): ">i4", ("MAC_INTEGER", 2): ">i2", ("MAC_INTEGER", 4): ">i4",
    ("PC_INTEGER", 2): "<i2", ("PC_INTEGER", 4): "<i4", ("PC_UNSIGNED_INTEGER", 2): "<u2",
    ("PC_UNSIGNED_INTEGER", 4): "<u4", ("VAX_INTEGER", 2): "<i2", ("VAX_INTEGER", 4): "<i4",
    ("IEEE_REAL", 4): ">f4", ("IEEE_REAL", 8): ">f8", ("PC_REAL", 4): "<f4", ("PC_REAL", 8): "<f8",
    ("MAC_REAL", 4): ">f4", ("MAC_REAL", 8): ">f8", ("SUN_REAL", 4): ">f4", ("SUN_REAL", 8): ">f8",
}
_NODATA_KEYS = ("MISSING_CONSTANT", "NULL", "CORE_NULL", "LOW_INSTR_SATURATION", "HIGH_INSTR_SATURATION",
                "LOW_REPR_SATURATION", "HIGH_REPR_SATURATION")


def image_kind(path: str | os.PathLike[str]) -> str:
    """``"isis"``, ``"pds3"`` or ``"gdal"`` (anything else: GeoTIFF, ...), from the file's first bytes."""
    with open(path, "rb") as fh:
        head = fh.read(4096)
    text = head.lstrip()
    if text.startswith(b"Object = IsisCube") or text.startswith(b"Object=IsisCube"):
        return "isis"
    if text.startswith(b"PDS_VERSION_ID") or text.startswith(b"CCSD"):
        return "pds3"
    return "gdal"


def _wrap(data: da.Array, path: str, name: str, attrs: dict[str, Any]) -> xr.DataArray:
    b, l, s = data.shape
    return xr.DataArray(data, dims=("band", "line", "sample"), name=name,
                        coords={"band": np.arange(1, b + 1), "line": np.arange(l) + 0.5, "sample": np.arange(s) + 0.5},
                        attrs={"source": path, "pixel_convention": "CSM: first pixel centre 0.5", **attrs})


def open_image(path: str | os.PathLike[str], chunks: Any = None) -> xr.DataArray:
    """Pixels of an ISIS cube, a PDS3 image or a GeoTIFF, lazily (see the module docstring).

    Parameters
    ----------
    path : path-like
        The image (for PDS3, the attached-label image or the detached ``.lbl``).
    chunks : optional
        Dask chunks ``(lines, samples)`` or ``(bands, lines, samples)``; ISIS cubes also take
        ``"tile"``. Default: about 16 MB of whole lines (ISIS: one row of tiles).

    Returns
    -------
    xarray.DataArray
        Dims ``(line, sample)`` (or ``(band, line, sample)``), dask-backed; NaN for special pixels.

    Raises
    ------
    FileNotFoundError
        No such file.
    CubeFormatError
        An unreadable or truncated image, an unsupported layout; ``rasterio`` missing for GeoTIFF.
    """
    p = os.fspath(path)
    if not os.path.isfile(p):
        raise FileNotFoundError(f"image {p} does not exist")
    kind = image_kind(p)
    if kind == "isis":
        return IsisCube(p).pixels(chunks=chunks)
    if kind == "pds3":
        return _open_pds3(p, chunks)
    return _open_gdal(p, chunks)


def _chunks(chunks: Any, bands: int, lines: int, samples: int, itemsize: int) -> tuple[int, int, int]:
    if chunks is None:
        return (1, max(1, min(lines, (16 << 20) // max(1, samples * itemsize))), samples)
    c = tuple(int(v) for v in chunks)
    return c if len(c) == 3 else (1, *c)  # type: ignore[return-value]


# -- PDS3 -------------------------------------------------------------------------------------

class _LineReader:
    """``(bands, lines, samples)`` of band-sequential records (prefix, samples, suffix) for dask."""

    def __init__(self, path: str, offset: int, record: int, prefix: int, dtype: np.dtype, shape: tuple[int, int, int]):
        self.path, self.offset, self.record, self.prefix = path, offset, record, prefix
        self.dtype, self.shape, self.ndim = dtype, shape, 3

    def __getitem__(self, key: Any) -> NDArray:
        key = key if isinstance(key, tuple) else (key,)
        key = key + (slice(None),) * (3 - len(key))
        if not all(isinstance(k, slice) and k.step in (None, 1) for k in key):
            return self[(slice(None),) * 3][key]
        (b0, b1, _), (l0, l1, _), (s0, s1, _) = (k.indices(n) for k, n in zip(key, self.shape))
        out = np.empty((max(b1 - b0, 0), max(l1 - l0, 0), max(s1 - s0, 0)), self.dtype)
        if out.size == 0:
            return out
        samples = self.shape[2]
        with open(self.path, "rb") as fh:
            for ib, b in enumerate(range(b0, b1)):
                start = self.offset + (b * self.shape[1] + l0) * self.record
                n = (l1 - l0) * self.record
                buf = os.pread(fh.fileno(), n, start)
                if len(buf) != n:
                    raise CubeFormatError(f"PDS3 image {self.path} is truncated at byte {start + len(buf)}")
                rows = np.frombuffer(buf, np.uint8).reshape(l1 - l0, self.record)
                data = rows[:, self.prefix:self.prefix + samples * self.dtype.itemsize]
                out[ib] = np.ascontiguousarray(data).view(self.dtype)[:, s0:s1]
        return out


def _finite(value: Any, what: str) -> float:
    """A label value as a finite number (a ``LabelError`` naming it otherwise)."""
    try:
        out = float(value)
        if isinstance(value, bool) or not np.isfinite(out):
            raise ValueError
    except (TypeError, ValueError, OverflowError):
        raise LabelError(f"{what} {value!r:.60} is not a finite number") from None
    return out


def _pointer(value: Any, record_bytes: int, label_path: str) -> tuple[str, int]:
    """File and 0-based byte offset of a PDS3 ``^IMAGE`` pointer."""
    folder = os.path.dirname(label_path)
    if isinstance(value, list):  # ("FILE.IMG", 5) or ("FILE.IMG", 1024 <BYTES>)
        if not value:
            raise CubeFormatError(f"PDS3 label {label_path}: its ^IMAGE pointer is empty")
        name, where = str(value[0]), value[1] if len(value) > 1 else 1
        path = os.path.join(folder, name)
    elif isinstance(value, str):
        path, where = os.path.join(folder, value), 1
    else:
        path, where = label_path, value
    if not str(path).strip() or os.path.isdir(path):
        raise CubeFormatError(f"PDS3 label {label_path}: its ^IMAGE pointer {value!r:.60} names no file")
    if not os.path.isfile(path):
        # labels name data files in upper case, archives on case-sensitive disks may not
        alt = [os.path.join(folder, f) for f in os.listdir(folder or ".") if f.lower() == os.path.basename(path).lower()]
        if not alt:
            raise CubeFormatError(f"PDS3 label {label_path}: its ^IMAGE file {path} does not exist")
        path = alt[0]
    unit = str(getattr(where, "unit", "")).upper()
    try:
        start = label_int(where, f"PDS3 label {label_path}: ^IMAGE position", 1)
    except LabelError as err:
        raise CubeFormatError(str(err)) from None
    offset = start - 1 if unit == "BYTES" else (start - 1) * record_bytes
    return path, offset


def _pds3_label(path: str) -> Label:
    """The PVL label of a PDS3 file, cut at its ``END`` line (binary data may follow)."""
    with open(path, "rb") as fh:
        head = fh.read(1 << 20)
    m = re.search(rb"^\s*END\s*$", head, re.MULTILINE)
    return parse_label(head[:m.end() if m else len(head)].decode("latin-1"), path)


def _open_pds3(path: str, chunks: Any) -> xr.DataArray:
    try:
        label = _pds3_label(path)
    except LabelError as err:
        raise CubeFormatError(f"PDS3 image {path}: unreadable label: {err}") from None
    image = label.get("IMAGE")
    if not isinstance(image, Label) or "^IMAGE" not in label:
        raise CubeFormatError(f"PDS3 label {path} has no IMAGE object or ^IMAGE pointer")
    what = f"PDS3 label {path}:"
    try:
        lines = label_int(image["LINES"], f"{what} LINES", 1)
        samples = label_int(image["LINE_SAMPLES"], f"{what} LINE_SAMPLES", 1)
        bands = label_int(image.get("BANDS", 1), f"{what} BANDS", 1)
        stype, bits = str(image["SAMPLE_TYPE"]).upper(), label_int(image["SAMPLE_BITS"], f"{what} SAMPLE_BITS", 1)
        prefix = label_int(image.get("LINE_PREFIX_BYTES", 0), f"{what} LINE_PREFIX_BYTES", 0)
        suffix = label_int(image.get("LINE_SUFFIX_BYTES", 0), f"{what} LINE_SUFFIX_BYTES", 0)
        record_bytes = label_int(label.get("RECORD_BYTES", samples * bits // 8), f"{what} RECORD_BYTES", 1)
        scale = _finite(image.get("SCALING_FACTOR", 1.0), f"{what} SCALING_FACTOR")
        add = _finite(image.get("OFFSET", 0.0), f"{what} OFFSET")
    except KeyError as err:
        raise CubeFormatError(f"PDS3 label {path}: IMAGE lacks {err}") from None
    except LabelError as err:
        raise CubeFormatError(str(err)) from None
    storage = str(image.get("BAND_STORAGE_TYPE", "BAND_SEQUENTIAL")).upper()
    if bands > 1 and storage != "BAND_SEQUENTIAL":
        raise CubeFormatError(f"PDS3 image {path}: band storage {storage} is not supported (band-sequential only)")
    key = (stype, bits // 8)
    if key not in _PDS3_TYPES:
        raise CubeFormatError(f"PDS3 image {path}: SAMPLE_TYPE {stype} with {bits} bits is not supported")
    dtype = np.dtype(_PDS3_TYPES[key])
    data_file, offset = _pointer(label["^IMAGE"], record_bytes, path)
    record = prefix + samples * dtype.itemsize + suffix
    need = offset + bands * lines * record
    if os.path.getsize(data_file) < need:
        raise CubeFormatError(f"PDS3 image {data_file} is truncated: its IMAGE needs {need} bytes, the file has "
                              f"{os.path.getsize(data_file)}")
    reader = _LineReader(data_file, offset, record, prefix, dtype, (bands, lines, samples))
    raw = da.from_array(reader, chunks=_chunks(chunks, bands, lines, samples, dtype.itemsize), asarray=True,
                        name=f"pds3-{abs(hash((data_file, offset, os.path.getmtime(data_file)))):x}",
                        meta=np.empty((0, 0, 0), dtype))
    nodata = [float(image[k]) for k in _NODATA_KEYS if k in image and isinstance(image[k], (int, float))]
    out_type = np.float64 if dtype.itemsize >= 4 and dtype.kind in "iu" or dtype.itemsize == 8 else np.float32

    def convert(block: NDArray) -> NDArray:
        values = block.astype(np.float64)
        bad = np.isin(values, nodata) if nodata else np.zeros(values.shape, bool)
        values = (add + scale * values).astype(out_type)
        values[bad] = np.nan
        return values

    return _wrap(raw.map_blocks(convert, dtype=out_type), path, "dn",
                 {"format": "PDS3", "scaling_factor": scale, "offset": add, "nodata": nodata})


# -- GDAL (GeoTIFF, ...) ----------------------------------------------------------------------

class _GdalReader:
    """``(bands, lines, samples)`` of a GDAL raster, one window read per chunk (picklable: the path only)."""

    def __init__(self, path: str, shape: tuple[int, int, int], dtype: np.dtype):
        self.path, self.shape, self.dtype, self.ndim = path, shape, dtype, 3

    def __getitem__(self, key: Any) -> NDArray:
        import rasterio
        from rasterio.windows import Window

        key = key if isinstance(key, tuple) else (key,)
        key = key + (slice(None),) * (3 - len(key))
        if not all(isinstance(k, slice) and k.step in (None, 1) for k in key):
            return self[(slice(None),) * 3][key]
        (b0, b1, _), (l0, l1, _), (s0, s1, _) = (k.indices(n) for k, n in zip(key, self.shape))
        if b1 <= b0 or l1 <= l0 or s1 <= s0:
            return np.empty((max(b1 - b0, 0), max(l1 - l0, 0), max(s1 - s0, 0)), self.dtype)
        import warnings

        from rasterio.errors import RasterioError

        # a damaged tile fails here, when dask computes the chunk: named, with the window
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # NotGeoreferencedWarning for plain images, on every window
                with rasterio.open(self.path) as ds:
                    out = ds.read(list(range(b0 + 1, b1 + 1)), window=Window(s0, l0, s1 - s0, l1 - l0))
        except (RasterioError, OSError, ValueError, MemoryError) as err:
            raise CubeFormatError(f"{self.path}: GDAL cannot read lines [{l0}, {l1}) samples [{s0}, {s1}) "
                                  f"({type(err).__name__}: {err})") from None
        if out.shape != (b1 - b0, l1 - l0, s1 - s0):
            raise CubeFormatError(f"{self.path}: GDAL read {out.shape} for lines [{l0}, {l1}) samples [{s0}, {s1})")
        return out.astype(self.dtype, copy=False)


def _tiff_layout(path: str) -> tuple[int, int] | None:
    """Bands declared by all image directories of a TIFF (main image, overviews, masks) and the largest
    block (tile or strip of every band, bytes) GDAL decodes for one window, read before GDAL opens it.

    GDAL builds one band object (~0.8 kB) per declared sample of every directory at open: a 150-byte
    TIFF declaring 65,535 samples per pixel costs 54 MB, and two such directories 92 MB (issue 28's
    fuzzing), before anything could be compared with the file's size; and a window is decoded in whole
    blocks, whatever the image's size (a 6 kB file of 40 x 40 pixels in tiles declared huge grew the
    process by 84 MB). ``None`` when the file is not a
    TIFF (the other formats GDAL reads) or its directory chain cannot be followed (GDAL says why).
    """
    import struct

    size = os.path.getsize(path)
    with open(path, "rb") as f:
        head = f.read(16)
        if len(head) < 8 or head[:2] not in (b"II", b"MM"):
            return None
        e = "<" if head[:2] == b"II" else ">"
        magic = struct.unpack(e + "H", head[2:4])[0]
        if magic == 42:
            big, offset = False, struct.unpack(e + "I", head[4:8])[0]
        elif magic == 43 and len(head) == 16:
            big, offset = True, struct.unpack(e + "Q", head[8:16])[0]
        else:
            return None
        count_fmt, entry_fmt, entry_size, next_fmt = (("Q", "HHQQ", 20, "Q") if big else ("H", "HHII", 12, "I"))
        total, largest = 0, 0
        seen: set[int] = set()
        # a directory is at least one entry long: the chain cannot be longer than the file allows
        while offset and offset not in seen and len(seen) < size // entry_size + 1:
            seen.add(offset)
            f.seek(offset)
            raw = f.read(struct.calcsize(e + count_fmt))
            if len(raw) < struct.calcsize(e + count_fmt):
                return None
            n = struct.unpack(e + count_fmt, raw)[0]
            if n * entry_size > size:
                return None
            entries = f.read(n * entry_size)
            if len(entries) < n * entry_size:
                return None
            tags: dict[int, int] = {}
            for k in range(n):
                tag, typ, cnt, value = struct.unpack(e + entry_fmt, entries[k * entry_size:(k + 1) * entry_size])
                if cnt == 1 and typ in (3, 4, 16):  # SHORT (left-justified in the value field), LONG, LONG8
                    tags[tag] = value >> (8 * (struct.calcsize(entry_fmt[-1]) - 2)) if e == ">" and typ == 3 \
                        else value & 0xFFFF if typ == 3 else value
            bands = tags.get(277, 1)                       # SamplesPerPixel
            width, rows = tags.get(256, 0), tags.get(257, 0)
            bits = max(tags.get(258, 8), 1)
            if 322 in tags:                                # tiled: TileWidth x TileLength
                block = tags[322] * tags.get(323, 0)
            else:                                          # stripped: RowsPerStrip (at most the image) x width
                block = width * min(tags.get(278, rows) or rows, rows)
            total += bands
            largest = max(largest, block * bands * -(-bits // 8))
            raw = f.read(struct.calcsize(e + next_fmt))
            if len(raw) < struct.calcsize(e + next_fmt):
                break
            offset = struct.unpack(e + next_fmt, raw)[0]
    return total, largest


def _open_gdal(path: str, chunks: Any) -> xr.DataArray:
    try:
        import rasterio
        from rasterio.errors import RasterioError
    except ImportError:
        raise CubeFormatError(f"{path} is neither an ISIS cube nor a PDS3 image; reading it (GeoTIFF, ...) needs "
                              "rasterio: pip install lunarmap[raster]") from None
    import warnings

    # every band must be backed by at least one byte of the file (even compressed), and GDAL allocates
    # per declared band at open: bound the bands before GDAL sees the file (issue 28)
    layout = _tiff_layout(path)
    size = os.path.getsize(path)
    if layout is not None and layout[0] > max(size, 1024):
        raise CubeFormatError(f"{path}: its TIFF directories declare {layout[0]} bands in all, more than a "
                              f"{size}-byte file can hold (damaged header)")
    # a block is decoded whole for any window that touches it: the same bound as the declared pixels below
    if layout is not None and layout[1] > 256 * size + (16 << 20):
        raise CubeFormatError(f"{path}: its TIFF directories declare blocks (tiles or strips of all bands) of "
                              f"{layout[1]} bytes, more than a {size}-byte file can hold even compressed "
                              "(damaged header)")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # NotGeoreferencedWarning for plain images
            with rasterio.open(path) as ds:
                shape = (ds.count, ds.height, ds.width)
                dtype = np.dtype(ds.dtypes[0])
                nodata = ds.nodata
                attrs = {"format": ds.driver, "crs": ds.crs.to_wkt() if ds.crs else "",
                         "transform": list(ds.transform)[:6]}
    except (RasterioError, OSError, ValueError, TypeError, IndexError) as err:
        raise CubeFormatError(f"{path}: GDAL cannot read it ({type(err).__name__}: {err})") from None
    if min(shape) < 1:
        raise CubeFormatError(f"{path}: GDAL reads it as {shape[0]} band(s) of {shape[1]} x {shape[2]} pixels")
    # a damaged header can declare far more pixels than the file could hold even compressed (issue 28: a
    # 6.5 kB GeoTIFF of 59,762 bands, read chunk by chunk for ever): 1,024 x the file's size + 64 MB at most
    # (the float values read are up to 8 bytes per pixel: 256 x the file + 16 MB keeps a damaged file's read
    # within the readers' budget of 10 x + 64 MB; the fuzzing found a 6 kB file growing the process by 113 MB
    # under 1,024 x + 64 MB)
    declared = shape[0] * shape[1] * shape[2] * 8
    if declared > 256 * os.path.getsize(path) + (16 << 20):
        raise CubeFormatError(f"{path}: its header declares {shape[0]} band(s) of {shape[1]} x {shape[2]} "
                              f"{dtype} pixels ({declared} bytes), more than a {os.path.getsize(path)}-byte file "
                              "can hold (damaged header)")
    raw = da.from_array(_GdalReader(path, shape, dtype), chunks=_chunks(chunks, *shape, dtype.itemsize), asarray=True,
                        name=f"gdal-{abs(hash((path, os.path.getmtime(path)))):x}", meta=np.empty((0, 0, 0), dtype))
    out_type = np.float64 if dtype.itemsize >= 4 and dtype.kind in "iu" or dtype.itemsize == 8 else np.float32

    def convert(block: NDArray) -> NDArray:
        values = block.astype(out_type)
        if nodata is not None:
            values[block == nodata if not np.isnan(nodata) else np.isnan(block)] = np.nan
        return values

    return _wrap(raw.map_blocks(convert, dtype=out_type), path, "dn", {**attrs, "nodata": nodata})

