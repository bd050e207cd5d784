"""ISIS cubes: label, pixels (lazy, dask-chunked ``xarray.DataArray``), special pixels and tables.

An ISIS cube is a PVL label (``Object = IsisCube``) followed by binary objects at the
1-based byte offsets the label gives: the pixel *core* (``Object = Core``: ``StartByte``,
``Format`` = ``Tile`` or ``BandSequential``, ``Dimensions``, ``Pixels`` type / byte order /
base / multiplier) and tables (``Object = Table``, read by :func:`lunarmap.labels.read_isis_table`).
A detached label names its data file with ``^Core``.

Pixels are read here, not through GDAL's ISIS3 driver: the format is a handful of
keywords, a reader of our own maps all five special pixels (GDAL exposes only Null, as
nodata), reads each chunk with one ``pread`` and needs no compiled library; GDAL is used
where it has no substitute (GeoTIFF, :mod:`lunarmap.io.raster`) and, in the tests, as an
independent reader of the cubes written here.

Tile layout: tiles of ``TileLines x TileSamples`` are stored row by row of tiles, band after
band; edge tiles are stored whole (padding). A dask chunk is one row of tiles by default
(``TileLines`` lines, every sample: one contiguous read) or one tile (``chunks="tile"``).

Pixel coordinates of the returned arrays follow the project's convention (CSM): the centre
of the first pixel is at ``(line, sample) = (0.5, 0.5)``; ISIS's is at ``(1, 1)``.
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import dask.array as da
import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from ..atomic import atomic_write
from ..errors import CubeFormatError, CubeWriteError, LabelError
from ..labels import Label, load_label, read_isis_table
from ..labels.pvl import label_int
from .pvl_write import format_pvl
from .special import PIXEL_TYPES, SPECIAL_CODES, classify, encode_special

__all__ = ["IsisCube", "CubeLayout", "Table", "open_cube", "write_cube", "CubeWriter", "copy_cube_with_tables",
           "table_bytes", "TABLE_TYPES"]

#: ISIS table field types -> numpy dtype character code.
TABLE_TYPES = {"Double": "f8", "Integer": "i4", "Real": "f4"}
_LABEL_BYTES = 65536


@dataclass(frozen=True)
class CubeLayout:
    """Where and how the pixel core of a cube is stored.

    Attributes
    ----------
    data_file : str
        File holding the core (the cube itself unless the label is detached).
    offset : int
        0-based byte offset of the core.
    fmt : str
        ``"Tile"`` or ``"BandSequential"``.
    bands, lines, samples : int
        Dimensions, pixels.
    dtype : numpy.dtype
        Stored pixel type with its byte order.
    tile_lines, tile_samples : int
        Tile size (``fmt == "Tile"``), pixels.
    base, multiplier : float
        ``DN = base + multiplier * stored``.
    """

    data_file: str
    offset: int
    fmt: str
    bands: int
    lines: int
    samples: int
    dtype: np.dtype
    tile_lines: int
    tile_samples: int
    base: float
    multiplier: float

    @property
    def tile_rows(self) -> int:
        return -(-self.lines // self.tile_lines)

    @property
    def tile_cols(self) -> int:
        return -(-self.samples // self.tile_samples)

    @property
    def nbytes(self) -> int:
        """Bytes the core occupies in the file (padding of edge tiles included)."""
        if self.fmt == "Tile":
            n = self.bands * self.tile_rows * self.tile_cols * self.tile_lines * self.tile_samples
        else:
            n = self.bands * self.lines * self.samples
        return n * self.dtype.itemsize


def _layout(label: Label, path: str) -> CubeLayout:
    cube = label.get("IsisCube")
    if not isinstance(cube, Label) or not isinstance(cube.get("Core"), Label):
        raise CubeFormatError(f"{path} is not an ISIS cube: its label has no IsisCube/Core object")
    core = cube["Core"]
    try:
        dims, pix = core["Dimensions"], core["Pixels"]
        bands, lines, samples = (label_int(dims[k], f"ISIS cube {path}: Dimensions {k}") for k in ("Bands", "Lines",
                                                                                                    "Samples"))
        ptype = str(pix["Type"])
        order = str(pix.get("ByteOrder", "Lsb"))
        base, mult = float(pix.get("Base", 0.0)), float(pix.get("Multiplier", 1.0))
        fmt = str(core.get("Format", "Tile"))
    except (KeyError, TypeError, ValueError, OverflowError) as err:
        raise CubeFormatError(f"ISIS cube {path}: Core/Dimensions or Core/Pixels is incomplete ({err})") from None
    if ptype not in PIXEL_TYPES:
        raise CubeFormatError(f"ISIS cube {path}: pixel type {ptype!r} is not supported; known: {sorted(PIXEL_TYPES)}")
    if order.lower() not in ("lsb", "msb"):
        raise CubeFormatError(f"ISIS cube {path}: ByteOrder {order!r} is neither Lsb nor Msb")
    if fmt not in ("Tile", "BandSequential"):
        raise CubeFormatError(f"ISIS cube {path}: core format {fmt!r} is not Tile or BandSequential")
    if min(bands, lines, samples) < 1:
        raise CubeFormatError(f"ISIS cube {path}: dimensions {bands} x {lines} x {samples} are not positive")
    dtype = np.dtype(("<" if order.lower() == "lsb" else ">") + PIXEL_TYPES[ptype])
    detached = core.get("^Core")
    data_file = os.path.join(os.path.dirname(path), str(detached)) if detached is not None else path
    try:
        start = label_int(core.get("StartByte", 1), f"ISIS cube {path}: Core StartByte", 1)
        tl = label_int(core.get("TileLines", lines), f"ISIS cube {path}: TileLines", 1) if fmt == "Tile" else lines
        ts = label_int(core.get("TileSamples", samples), f"ISIS cube {path}: TileSamples", 1) if fmt == "Tile" else samples
    except LabelError as err:
        raise CubeFormatError(str(err)) from None
    if not (np.isfinite(base) and np.isfinite(mult)):
        raise CubeFormatError(f"ISIS cube {path}: pixel Base {base} / Multiplier {mult} are not finite")
    return CubeLayout(data_file, start - 1, fmt, bands, lines, samples, dtype, tl, ts, base, mult)


class _CoreReader:
    """Array-like ``(bands, lines, samples)`` of stored values for ``dask.array.from_array``.

    Holds only the layout (picklable); every ``__getitem__`` opens the file and reads the
    bytes of the requested window: one contiguous range per band and row of tiles.
    """

    def __init__(self, layout: CubeLayout) -> None:
        self.layout = layout
        self.shape = (layout.bands, layout.lines, layout.samples)
        self.dtype = layout.dtype
        self.ndim = 3

    def __getitem__(self, key: Any) -> NDArray:
        lay = self.layout
        if not isinstance(key, tuple):
            key = (key,)
        key = key + (slice(None),) * (3 - len(key))
        if not all(isinstance(k, slice) and k.step in (None, 1) for k in key):
            # integer or strided indices (not used by dask's chunking): read everything, then index
            return self[(slice(None),) * 3][key]
        rng = [range(*k.indices(n)) for k, n in zip(key, self.shape)]
        b0, b1 = rng[0].start, rng[0].stop
        l0, l1 = rng[1].start, rng[1].stop
        s0, s1 = rng[2].start, rng[2].stop
        out = np.empty((max(b1 - b0, 0), max(l1 - l0, 0), max(s1 - s0, 0)), dtype=lay.dtype)
        if out.size == 0:
            return out
        item = lay.dtype.itemsize
        with open(lay.data_file, "rb") as fh:
            fd = fh.fileno()
            for ib, b in enumerate(range(b0, b1)):
                if lay.fmt == "BandSequential":
                    start = lay.offset + ((b * lay.lines + l0) * lay.samples) * item
                    n = (l1 - l0) * lay.samples
                    block = _pread(fd, start, n * item, lay).view(lay.dtype).reshape(l1 - l0, lay.samples)
                    out[ib] = block[:, s0:s1]
                    continue
                tl, ts, ncol = lay.tile_lines, lay.tile_samples, lay.tile_cols
                c0, c1 = s0 // ts, (s1 - 1) // ts + 1
                for r in range(l0 // tl, (l1 - 1) // tl + 1):
                    tile0 = (b * lay.tile_rows + r) * ncol + c0
                    n = (c1 - c0) * tl * ts
                    raw = _pread(fd, lay.offset + tile0 * tl * ts * item, n * item, lay).view(lay.dtype)
                    rows = raw.reshape(c1 - c0, tl, ts).transpose(1, 0, 2).reshape(tl, (c1 - c0) * ts)
                    a0, a1 = max(l0, r * tl), min(l1, (r + 1) * tl)
                    out[ib, a0 - l0:a1 - l0] = rows[a0 - r * tl:a1 - r * tl, s0 - c0 * ts:s1 - c0 * ts]
        return out


def _pread(fd: int, offset: int, nbytes: int, lay: CubeLayout) -> NDArray:
    buf = os.pread(fd, nbytes, offset)
    if len(buf) != nbytes:
        raise CubeFormatError(f"ISIS cube {lay.data_file} is truncated: {nbytes} bytes at offset {offset} "
                              f"requested, {len(buf)} present")
    return np.frombuffer(buf, dtype=np.uint8)


@dataclass
class Table:
    """An ISIS table to write: named fields of one type each, plus label keywords.

    Parameters
    ----------
    name : str
        Table name (``"InstrumentPointing"``).
    columns : dict of str to ndarray
        One ``(records,)`` array per field, in field order.
    types : dict of str to str, optional
        ISIS field type per field (``"Double"``, ``"Integer"``, ``"Real"``); ``"Double"`` by default.
    keywords : list of (str, value)
        Further table-label keywords (``TimeDependentFrames``, ``CacheType``, ...), in order.
    """

    name: str
    columns: dict[str, NDArray]
    types: dict[str, str] = field(default_factory=dict)
    keywords: list[tuple[str, Any]] = field(default_factory=list)

    @property
    def records(self) -> int:
        sizes = {np.asarray(v).shape[0] for v in self.columns.values()}
        if len(sizes) != 1:
            raise CubeFormatError(f"table {self.name}: columns of different lengths {sorted(sizes)}")
        return sizes.pop()

    def dtype(self) -> np.dtype:
        for n, t in self.types.items():
            if t not in TABLE_TYPES:
                raise CubeFormatError(f"table {self.name}: field {n} has unsupported type {t!r}")
        return np.dtype([(n, "<" + TABLE_TYPES[self.types.get(n, "Double")]) for n in self.columns])

    def label_items(self, start_byte: int, nbytes: int) -> list[Any]:
        items: list[Any] = [("Name", self.name), ("StartByte", start_byte), ("Bytes", nbytes),
                            ("Records", self.records), ("ByteOrder", "Lsb"), *self.keywords]
        for n in self.columns:
            items.append(("Group", "Field", [("Name", n), ("Type", self.types.get(n, "Double")), ("Size", 1)]))
        return items


def table_bytes(table: Table) -> bytes:
    """The binary records of a table (little-endian)."""
    rec = np.empty(table.records, dtype=table.dtype())
    for n, v in table.columns.items():
        rec[n] = np.asarray(v)
    return rec.tobytes()


class IsisCube:
    """An ISIS cube opened for reading; nothing but the label is read until pixels are asked for.

    Parameters
    ----------
    path : path-like
        The cube (label attached) or its detached label.

    Raises
    ------
    CubeFormatError
        Not a cube, an unsupported layout, or a file shorter than its label says (truncated).
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = os.fspath(path)
        if not os.path.isfile(self.path):
            raise FileNotFoundError(f"ISIS cube {self.path} does not exist")
        try:
            self.label = load_label(self.path)
        except LabelError as err:
            raise CubeFormatError(f"ISIS cube {self.path}: unreadable label: {err}") from None
        self.layout = _layout(self.label, self.path)
        self._check_size()

    def _check_size(self) -> None:
        lay = self.layout
        if not os.path.isfile(lay.data_file):
            raise CubeFormatError(f"ISIS cube {self.path}: data file {lay.data_file} (^Core) does not exist")
        size = os.path.getsize(lay.data_file)
        if lay.offset + lay.nbytes > size:
            raise CubeFormatError(
                f"ISIS cube {self.path} is truncated: its core needs bytes {lay.offset + 1}..{lay.offset + lay.nbytes} "
                f"but {lay.data_file} has {size} bytes")
        for obj in self.label.all("Table") + self.label.all("History") + self.label.all("OriginalLabel"):
            if isinstance(obj, Label) and "StartByte" in obj and "Bytes" in obj and "^Core" not in self.cube_label["Core"]:
                what = f"ISIS cube {self.path}: object {obj.get('Name', '?')}"
                try:
                    end = label_int(obj["StartByte"], f"{what} StartByte", 1) - 1 + label_int(obj["Bytes"],
                                                                                            f"{what} Bytes", 0)
                except LabelError as err:
                    raise CubeFormatError(str(err)) from None
                if end > os.path.getsize(self.path):
                    raise CubeFormatError(f"ISIS cube {self.path} is truncated: object {obj.get('Name', '?')} ends at "
                                          f"byte {end}, the file has {os.path.getsize(self.path)}")

    # -- label ----------------------------------------------------------------
    @property
    def cube_label(self) -> Label:
        """The ``IsisCube`` object of the label."""
        return self.label["IsisCube"]

    def group(self, name: str) -> Label | None:
        """A group of the ``IsisCube`` object (``Instrument``, ``Kernels``, ``AlphaCube``...), or ``None``."""
        g = self.cube_label.get(name)
        return g if isinstance(g, Label) else None

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(bands, lines, samples)``."""
        return (self.layout.bands, self.layout.lines, self.layout.samples)

    @property
    def table_names(self) -> list[str]:
        return [str(t.get("Name", "")) for t in self.label.all("Table")]

    def table(self, name: str) -> tuple[dict[str, NDArray], Label]:
        """Columns and label of the table ``name`` (see :func:`lunarmap.labels.read_isis_table`)."""
        return read_isis_table(self.path, name)

    # -- pixels ---------------------------------------------------------------
    def _chunks(self, chunks: Any) -> tuple[int, int, int]:
        lay = self.layout
        if chunks is None:
            return (1, lay.tile_lines if lay.fmt == "Tile" else min(lay.lines, max(1, (16 << 20) // (lay.samples * lay.dtype.itemsize))), lay.samples)
        if chunks == "tile":
            if lay.fmt != "Tile":
                raise CubeFormatError(f"ISIS cube {self.path} is BandSequential: it has no tiles")
            return (1, lay.tile_lines, lay.tile_samples)
        c = tuple(int(v) for v in chunks)
        return c if len(c) == 3 else (1, *c)  # type: ignore[return-value]

    def raw(self, chunks: Any = None) -> da.Array:
        """Stored pixel values ``(bands, lines, samples)`` as a lazy dask array (native byte order)."""
        arr = da.from_array(_CoreReader(self.layout), chunks=self._chunks(chunks), asarray=True,
                            name=f"isis-raw-{_token(self.path)}", meta=np.empty((0, 0, 0), self.layout.dtype))
        return arr.astype(self.layout.dtype.newbyteorder("="))

    def _wrap(self, data: da.Array, name: str, attrs: dict[str, Any]) -> xr.DataArray:
        b, l, s = self.shape
        return xr.DataArray(data, dims=("band", "line", "sample"), name=name,
                            coords={"band": np.arange(1, b + 1), "line": np.arange(l) + 0.5,
                                    "sample": np.arange(s) + 0.5},
                            attrs={"source": self.path, "pixel_convention": "CSM: first pixel centre 0.5", **attrs})

    def pixels(self, chunks: Any = None, dtype: Any = None) -> xr.DataArray:
        """Pixel values (``base + multiplier * stored``), special pixels as NaN; lazy.

        Parameters
        ----------
        chunks : None, ``"tile"`` or (lines, samples)
            Dask chunks: a row of tiles (default), one tile, or explicit sizes.
        dtype : numpy dtype, optional
            Output type; float32 for 1-, 2-byte and Real pixels, float64 for 4-byte integers.

        Returns
        -------
        xarray.DataArray
            Dims ``(band, line, sample)``; coordinates are pixel centres (CSM convention).
        """
        lay = self.layout
        out = np.dtype(dtype) if dtype is not None else np.dtype(np.float64 if lay.dtype.kind in "iu" and lay.dtype.itemsize == 4 else np.float32)
        base, mult = lay.base, lay.multiplier

        def convert(raw: NDArray) -> NDArray:
            val = raw.astype(out)
            if base != 0.0 or mult != 1.0:
                val = (base + mult * raw.astype(np.float64)).astype(out)
            val[classify(raw) != 0] = np.nan
            return val

        data = da.map_blocks(convert, self.raw(chunks), dtype=out)
        return self._wrap(data, "dn", {"base": base, "multiplier": mult})

    def special(self, chunks: Any = None) -> xr.DataArray:
        """Special-pixel codes ``(band, line, sample)`` int8, lazy: 0 valid, 1 Null, 2 Lrs, 3 Lis, 4 His, 5 Hrs."""
        data = da.map_blocks(classify, self.raw(chunks), dtype=np.int8)
        return self._wrap(data, "special", {"flag_values": list(SPECIAL_CODES.values()),
                                            "flag_meanings": " ".join(SPECIAL_CODES)})

    def __repr__(self) -> str:
        b, l, s = self.shape
        return f"IsisCube({self.path!r}, {b} x {l} x {s}, {self.layout.dtype}, {self.layout.fmt})"


def _token(path: str) -> str:
    st = os.stat(path)
    return f"{abs(hash((os.path.abspath(path), st.st_size, st.st_mtime_ns))):x}"


def open_cube(path: str | os.PathLike[str], chunks: Any = None) -> xr.DataArray:
    """The pixels of an ISIS cube as a lazy ``xarray.DataArray`` (see :meth:`IsisCube.pixels`).

    Special pixels are NaN; :meth:`IsisCube.special` says which kind each one was.
    """
    return IsisCube(path).pixels(chunks=chunks)


# -- writing -------------------------------------------------------------------

def write_cube(path: str | os.PathLike[str], data: ArrayLike, *, pixel_type: str = "Real",
               special: ArrayLike | None = None, base: float = 0.0, multiplier: float = 1.0,
               fmt: str = "Tile", tile: tuple[int, int] = (128, 128), byte_order: str = "Lsb",
               groups: list[Any] | None = None, tables: list[Table] | None = None,
               objects: list[Any] | None = None, label_bytes: int = _LABEL_BYTES) -> Path:
    """Write an ISIS cube (label attached), atomically.

    Parameters
    ----------
    path : path-like
        Output file.
    data : array-like
        ``(lines, samples)`` or ``(bands, lines, samples)`` pixel values (DN); NaN becomes Null.
        Values are stored as ``round((data - base) / multiplier)`` for integer types.
    pixel_type : str
        ISIS ``Pixels/Type``: ``UnsignedByte``, ``SignedWord``, ``UnsignedWord``, ``SignedInteger``,
        ``UnsignedInteger`` or ``Real``.
    special : array-like of int8, optional
        Special-pixel codes (:data:`~lunarmap.io.special.SPECIAL_CODES`) to store where non-zero.
    base, multiplier : float
        ``DN = base + multiplier * stored``.
    fmt : str
        ``"Tile"`` or ``"BandSequential"``.
    tile : (int, int)
        ``(TileLines, TileSamples)``.
    byte_order : str
        ``"Lsb"`` or ``"Msb"``.
    groups : list, optional
        PVL items (see :mod:`lunarmap.io.pvl_write`) placed in ``IsisCube`` after ``Core``
        (``("Group", "Instrument", [...])``, ...).
    tables : list of Table, optional
        Tables stored after the core.
    objects : list, optional
        Further top-level label objects (``("Object", "NaifKeywords", [...])``).
    label_bytes : int
        Space reserved for the label (ISIS's default 65536).

    Raises
    ------
    CubeFormatError
        Unknown pixel type or format, values outside the pixel type's range, a label
        longer than ``label_bytes``.
    """
    _check_pixel_type(pixel_type, fmt)
    raw = _encode(data, special, pixel_type, base, multiplier, byte_order, path)
    b, l, s = raw.shape
    tl, ts = (min(tile[0], l), min(tile[1], s)) if fmt == "Tile" else (l, s)
    if fmt == "Tile":
        core = _tiles(raw, tl, ts).tobytes()
    else:
        core = raw.tobytes()

    table_blobs = [table_bytes(t) for t in (tables or [])]

    def label_text(label_size: int) -> str:
        start = label_size + 1
        items = _cube_items(fmt, tl, ts, (b, l, s), pixel_type, byte_order, base, multiplier, start, label_size,
                            groups)
        pos = start + len(core)
        for t, blob in zip(tables or [], table_blobs):
            items.append(("Object", "Table", t.label_items(pos, len(blob))))
            pos += len(blob)
        items += list(objects or [])
        return format_pvl(items)

    text = _label_bytes(label_text(label_bytes), label_bytes, path)

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            fh.write(text)
            fh.write(core)
            for blob in table_blobs:
                fh.write(blob)

    return atomic_write(path, write)


class CubeWriter:
    """An ISIS cube (label attached, ``Tile`` format) written window by window, renamed into place when complete.

    For images too large to hold in memory: the core is written as stripes of whole rows of tiles
    (each one contiguous range of the file), in any order, into a hidden temporary file beside the
    target whose full size is reserved when it is opened (a full disk fails then, not after an hour of
    rendering). :meth:`finish` checks that every row of tiles was written, flushes and renames the
    file onto its name; :meth:`abort` (or an exception inside ``with``) removes it. A process killed
    mid-write leaves at most the hidden ``.<name>.*.tmp`` file, never a partial cube under the name.

    Parameters
    ----------
    path : path-like
        Final file name; its folder must exist and be writable.
    lines, samples : int
        Image size, pixels.
    bands : int
        Bands.
    pixel_type, base, multiplier, byte_order, label_bytes, groups
        As for :func:`write_cube` (no tables: they would follow the core).
    tile : (int, int)
        ``(TileLines, TileSamples)``; every :meth:`write` starts on a multiple of ``TileLines``.

    Raises
    ------
    CubeFormatError
        Bad pixel type, tile size or dimensions, a label longer than ``label_bytes``.
    CubeWriteError
        The folder is missing or not writable, or the disk has no room for the cube.

    Examples
    --------
    >>> with CubeWriter("big.cub", 52224, 5064, pixel_type="UnsignedByte") as cube:  # doctest: +SKIP
    ...     for l0 in range(0, 52224, 512):
    ...         cube.write(render(l0, l0 + 512), l0)
    """

    def __init__(self, path: str | os.PathLike[str], lines: int, samples: int, *, bands: int = 1,
                 pixel_type: str = "Real", base: float = 0.0, multiplier: float = 1.0,
                 tile: tuple[int, int] = (128, 128), byte_order: str = "Lsb", groups: list[Any] | None = None,
                 label_bytes: int = _LABEL_BYTES) -> None:
        _check_pixel_type(pixel_type, "Tile")
        self.path = Path(path)
        if min(int(bands), int(lines), int(samples)) < 1 or min(int(tile[0]), int(tile[1])) < 1:
            raise CubeFormatError(f"writing {self.path}: dimensions {bands} x {lines} x {samples} and tile {tile} "
                                  "must be positive")
        self.shape = (int(bands), int(lines), int(samples))
        self.pixel_type, self.base, self.multiplier, self.byte_order = pixel_type, float(base), float(multiplier), \
            byte_order
        self.tile_lines, self.tile_samples = min(int(tile[0]), self.shape[1]), min(int(tile[1]), self.shape[2])
        self._rows = -(-self.shape[1] // self.tile_lines)
        self._cols = -(-self.shape[2] // self.tile_samples)
        self._item = np.dtype(PIXEL_TYPES[pixel_type]).itemsize
        self._label_bytes = int(label_bytes)
        items = _cube_items("Tile", self.tile_lines, self.tile_samples, self.shape, pixel_type, byte_order, base,
                            multiplier, self._label_bytes + 1, self._label_bytes, groups)
        text = _label_bytes(format_pvl(items), self._label_bytes, self.path)
        self._written = np.zeros((self.shape[0], self._rows), dtype=bool)
        self._tmp: Path | None = None
        self._fd = -1
        folder = self.path.parent if str(self.path.parent) else Path(".")
        if not folder.is_dir():
            raise CubeWriteError(f"cannot write the cube {self.path}: folder {folder} does not exist")
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=folder)
        except OSError as err:
            raise CubeWriteError(f"cannot write the cube {self.path}: {err.strerror or err}") from None
        self._fd, self._tmp = fd, Path(tmp)
        try:
            mask = os.umask(0)
            os.umask(mask)
            os.fchmod(fd, 0o666 & ~mask)   # mkstemp's 0600 would make the cube private to its writer
            self._reserve(self.nbytes)
            self._pwrite(text, 0)
        except BaseException:
            self.abort()
            raise

    @property
    def nbytes(self) -> int:
        """Size of the finished file, bytes (label space and padded tiles)."""
        return self._label_bytes + self.shape[0] * self._rows * self._cols * self.tile_lines * self.tile_samples \
            * self._item

    def _fail(self, err: OSError) -> CubeWriteError:
        return CubeWriteError(f"writing the cube {self.path} failed: {err.strerror or err} "
                              f"({'the disk is full' if err.errno == errno.ENOSPC else 'nothing was left under its name'})")

    def _reserve(self, nbytes: int) -> None:
        try:
            os.posix_fallocate(self._fd, 0, nbytes)
        except AttributeError:  # pragma: no cover - no posix_fallocate on this platform
            os.ftruncate(self._fd, nbytes)
        except OSError as err:
            if err.errno in (errno.EOPNOTSUPP, errno.EINVAL, errno.ENOSYS):  # the file system cannot reserve
                try:
                    os.ftruncate(self._fd, nbytes)
                except OSError as err2:
                    raise self._fail(err2) from None
            else:
                raise self._fail(err) from None

    def _pwrite(self, data: bytes | memoryview, offset: int) -> None:
        view = memoryview(data).cast("B")
        try:
            while view:
                n = os.pwrite(self._fd, view, offset)
                view, offset = view[n:], offset + n
        except OSError as err:
            raise self._fail(err) from None

    def write(self, data: ArrayLike, line0: int = 0, band: int = 1, *, special: ArrayLike | None = None) -> None:
        """Write DN values of lines ``[line0, line0 + n)`` of one band (all samples).

        Parameters
        ----------
        data : array-like, shape (n, samples)
            DN; NaN becomes Null; integer types store ``round((data - base) / multiplier)``. Values
            already of the stored dtype (e.g. ``uint8`` for UnsignedByte with base 0, multiplier 1)
            are written as they are, without a float copy.
        line0 : int
            First line (0-based); a multiple of ``TileLines``. ``n`` is a multiple of ``TileLines``
            unless the stripe ends at the last line.
        band : int
            1-based band.
        special : array-like of int8, optional
            Special-pixel codes to store where non-zero.
        """
        if self._fd < 0:
            raise CubeFormatError(f"cube {self.path} is already finished or aborted")
        b, l, s = self.shape
        arr = np.asarray(data)
        if arr.ndim != 2 or arr.shape[1] != s:
            raise CubeFormatError(f"writing {self.path}: a stripe must be (lines, {s}), got {arr.shape}")
        n = arr.shape[0]
        tl = self.tile_lines
        if not (0 <= line0 < l and line0 % tl == 0 and line0 + n <= l and (n % tl == 0 or line0 + n == l) and n):
            raise CubeFormatError(f"writing {self.path}: stripe of {n} lines at line {line0} does not cover whole "
                                  f"rows of {tl}-line tiles inside the {l} lines")
        if not 1 <= int(band) <= b:
            raise CubeFormatError(f"writing {self.path}: band {band} is not in 1..{b}")
        stored = np.dtype(PIXEL_TYPES[self.pixel_type]).newbyteorder("<" if self.byte_order.lower() == "lsb" else ">")
        if arr.dtype == stored and special is None and self.base == 0.0 and self.multiplier == 1.0:
            raw = arr[None]
        else:
            raw = _encode(arr, special, self.pixel_type, self.base, self.multiplier, self.byte_order, self.path)
        core = np.ascontiguousarray(_tiles(raw, tl, self.tile_samples))
        r0 = line0 // tl
        tile_bytes = tl * self.tile_samples * self._item
        offset = self._label_bytes + ((int(band) - 1) * self._rows + r0) * self._cols * tile_bytes
        self._pwrite(core.data, offset)
        self._written[int(band) - 1, r0:r0 + core.shape[1]] = True

    def finish(self) -> Path:
        """Check that every row of tiles was written, flush, and rename the cube onto its name; returns it."""
        if self._fd < 0:
            raise CubeFormatError(f"cube {self.path} is already finished or aborted")
        missing = np.argwhere(~self._written)
        if missing.size:
            band, row = missing[0]
            self.abort()
            raise CubeFormatError(f"cube {self.path}: {len(missing)} row(s) of tiles were never written (first: "
                                  f"band {band + 1}, lines {row * self.tile_lines}..); nothing was kept")
        try:
            os.fsync(self._fd)
            os.close(self._fd)
            self._fd = -1
            assert self._tmp is not None        # set by __enter__
            os.replace(self._tmp, self.path)
        except OSError as err:
            self.abort()
            raise self._fail(err) from None
        self._tmp = None
        return self.path

    def abort(self) -> None:
        """Remove the temporary file; the target is left as it was."""
        if self._fd >= 0:
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._fd = -1
        if self._tmp is not None:
            with contextlib.suppress(OSError):
                self._tmp.unlink()
            self._tmp = None

    def __enter__(self) -> "CubeWriter":
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.finish()
        else:
            self.abort()

    def __del__(self) -> None:  # an abandoned writer must not leave its temporary file
        self.abort()


def _check_pixel_type(pixel_type: str, fmt: str) -> None:
    if pixel_type not in PIXEL_TYPES:
        raise CubeFormatError(f"cannot write pixel type {pixel_type!r}; known: {sorted(PIXEL_TYPES)}")
    if fmt not in ("Tile", "BandSequential"):
        raise CubeFormatError(f"cannot write core format {fmt!r}; use Tile or BandSequential")


def _encode(data: ArrayLike, special: ArrayLike | None, pixel_type: str, base: float, multiplier: float,
            byte_order: str, path: Any) -> NDArray:
    """Stored values ``(bands, lines, samples)`` of DN ``data`` (NaN and ``special`` codes -> special pixels)."""
    arr = np.asarray(data, dtype=np.float64)
    arr = arr[None] if arr.ndim == 2 else arr
    if arr.ndim != 3:
        raise CubeFormatError(f"cube data must be (lines, samples) or (bands, lines, samples), got {arr.shape}")
    codes = np.zeros(arr.shape, np.int8) if special is None else np.broadcast_to(np.asarray(special, np.int8).reshape(
        (1,) * (3 - np.ndim(special)) + np.shape(special)), arr.shape).copy()
    codes[np.isnan(arr) & (codes == 0)] = SPECIAL_CODES["Null"]
    dtype = np.dtype(PIXEL_TYPES[pixel_type])
    stored = (arr - base) / multiplier
    good = codes == 0
    if dtype.kind == "f":
        raw = np.zeros(arr.shape, np.float32)
        raw[good] = stored[good]
    else:
        rounded = np.rint(np.where(good, stored, 0.0))
        info = np.iinfo(dtype)
        if np.any(rounded < info.min) or np.any(rounded > info.max):
            raise CubeFormatError(f"writing {os.fspath(path)}: values outside the range of {pixel_type}")
        raw = rounded.astype(dtype)
    encode_special(raw, codes)
    if dtype.kind != "f" and np.any(classify(raw)[good] != 0):
        raise CubeFormatError(f"writing {os.fspath(path)}: some data values fall on {pixel_type}'s special pixels")
    order: Literal["<", ">"] = "<" if byte_order.lower() == "lsb" else ">"
    return raw.astype(raw.dtype.newbyteorder(order))


def _tiles(raw: NDArray, tl: int, ts: int) -> NDArray:
    """``(bands, lines, samples)`` as ISIS stores tiles: row of tiles by row of tiles, edge tiles padded."""
    b, l, s = raw.shape
    rows, cols = -(-l // tl), -(-s // ts)
    padded = np.zeros((b, rows * tl, cols * ts), raw.dtype)
    padded[:, :l, :s] = raw
    return padded.reshape(b, rows, tl, cols, ts).transpose(0, 1, 3, 2, 4)


def _cube_items(fmt: str, tl: int, ts: int, shape: tuple[int, int, int], pixel_type: str, byte_order: str,
                base: float, multiplier: float, start: int, label_size: int, groups: list[Any] | None) -> list[Any]:
    """The label items of a cube's ``IsisCube`` and ``Label`` objects."""
    b, l, s = shape
    core_items: list[Any] = [("StartByte", start), ("Format", fmt)]
    if fmt == "Tile":
        core_items += [("TileSamples", ts), ("TileLines", tl)]
    core_items += [("Group", "Dimensions", [("Samples", s), ("Lines", l), ("Bands", b)]),
                   ("Group", "Pixels", [("Type", pixel_type),
                                        ("ByteOrder", "Lsb" if byte_order.lower() == "lsb" else "Msb"),
                                        ("Base", float(base)), ("Multiplier", float(multiplier))])]
    return [("Object", "IsisCube", [("Object", "Core", core_items), *(groups or [])]),
            ("Object", "Label", [("Bytes", label_size)])]


def _label_bytes(text: str, label_bytes: int, path: Any) -> bytes:
    """The label padded with NULs to ``label_bytes``."""
    raw = text.encode("latin-1")
    if len(raw) > label_bytes:
        raise CubeFormatError(f"writing {os.fspath(path)}: the label needs {len(raw)} bytes, more than "
                              f"label_bytes={label_bytes}")
    return raw + b"\0" * (label_bytes - len(raw))


_TABLE_BLOCK = re.compile(r"^(Object\s*=\s*Table\s*\n)(.*?)(^End_Object\s*\n)", re.MULTILINE | re.DOTALL | re.IGNORECASE)


def copy_cube_with_tables(source: str | os.PathLike[str], target: str | os.PathLike[str],
                          tables: list[Table]) -> Path:
    """Copy a cube, replacing (or adding) tables; the source is not modified.

    The copy keeps the source's bytes and label text; each replaced table's label block is
    rewritten and its records are appended after the source's data (the old records stay as
    unreferenced bytes, as when ISIS rewrites a blob), so every other object keeps its offset.

    Raises
    ------
    CubeFormatError
        The source is not a readable cube, or the new label does not fit in the label space
        the source reserved.
    """
    src = IsisCube(source)  # validates the source (layout, truncation)
    if Path(source).resolve() == Path(target).resolve():
        raise CubeFormatError(f"copy_cube_with_tables: the target {target} is the source; write to a copy")
    with open(src.path, "rb") as fh:
        content = fh.read()
    m = re.search(rb"^End\s*$", content, re.MULTILINE)
    if m is None:
        raise CubeFormatError(f"ISIS cube {src.path}: label has no End line")
    label_end = m.end()
    label = content[:label_end].decode("latin-1")
    label_obj = src.label.get("Label")
    label_space = int(label_obj["Bytes"]) if isinstance(label_obj, Label) and "Bytes" in label_obj else \
        int(src.cube_label["Core"].get("StartByte", len(content) + 1)) - 1
    pos = len(content) + 1
    blobs: list[bytes] = []
    for t in tables:
        blob = table_bytes(t)
        block = format_pvl([("Object", "Table", t.label_items(pos, len(blob)))], end=False).rstrip("\n") + "\n"
        replaced = False

        def swap(mm: re.Match) -> str:
            nonlocal replaced
            if re.search(rf"^\s*Name\s*=\s*{re.escape(t.name)}\s*$", mm.group(2), re.MULTILINE) and not replaced:  # noqa: B023,E501
                replaced = True
                return block  # noqa: B023 (swap runs in this iteration)
            return mm.group(0)

        label = _TABLE_BLOCK.sub(swap, label)
        if not replaced:
            label = re.sub(r"^End\s*$", block.replace("\\", "\\\\") + "\nEnd", label, count=1, flags=re.MULTILINE)
        blobs.append(blob)
        pos += len(blob)
    new_label = label.encode("latin-1")
    if len(new_label) > label_space:
        raise CubeFormatError(f"copy of {src.path}: the new label needs {len(new_label)} bytes, the cube reserves "
                              f"{label_space}")

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            fh.write(new_label)
            fh.write(b"\0" * (label_end - len(new_label)) if len(new_label) < label_end else b"")
            fh.write(content[max(label_end, len(new_label)):])
            for blob in blobs:
                fh.write(blob)

    return atomic_write(target, write)
