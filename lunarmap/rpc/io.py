"""Storage of RPC models: netCDF (the xarray dataset) and the GDAL ``_RPC.TXT`` keyword layout.

RPC00B text
-----------
One ``KEY: value`` line per keyword, as GDAL's ``GDALWriteRPCTXTFile``
writes and ``GDALLoadRPCFile`` reads (``gcore/gdal_mdreader.cpp``)::

    LINE_OFF, SAMP_OFF, LAT_OFF, LONG_OFF, HEIGHT_OFF,
    LINE_SCALE, SAMP_SCALE, LAT_SCALE, LONG_SCALE, HEIGHT_SCALE,
    LINE_NUM_COEFF_1..20, LINE_DEN_COEFF_1..20, SAMP_NUM_COEFF_1..20, SAMP_DEN_COEFF_1..20

Pixel convention: RPC files put ``(0, 0)`` at the *centre* of the top-left
pixel; GDAL's RPC transformer adds 0.5 to the RPC's line and sample to get
its own corner-based coordinates (``RPCTransformPoint`` in
``alg/gdal_rpc.cpp``: "RPCs are using the center of upper left pixel = 0,0
convention"). lunarmap's CSM coordinates put the centre of the first pixel
at (0.5, 0.5), like GDAL's, so writing subtracts 0.5 from ``LINE_OFF`` and
``SAMP_OFF`` and reading adds it back; scales and coefficients are
unchanged.

Ground coordinates are planetocentric lunar latitude and east longitude
(degrees) and height above the reference sphere (metres). The text layout
has no datum keyword: tools that read it (GDAL, Ames Stereo Pipeline) must
be told the body (e.g. a 1737.4 km sphere); lunarmap writes the radius as a
comment line and reads it back when present.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..atomic import atomic_write
from ..camera.shape import MOON_RADIUS
from ..errors import RpcFormatError
from ..ncread import load_netcdf
from .model import RationalFunctionModel

__all__ = ["write_netcdf", "read_netcdf", "write_rpc_txt", "read_rpc_txt", "rpc_txt_keywords",
           "GDAL_PIXEL_SHIFT"]

#: RPC-file pixel coordinate = lunarmap (CSM) coordinate - GDAL_PIXEL_SHIFT.
GDAL_PIXEL_SHIFT = 0.5

_SINGLE = ("LINE_OFF", "SAMP_OFF", "LAT_OFF", "LONG_OFF", "HEIGHT_OFF",
           "LINE_SCALE", "SAMP_SCALE", "LAT_SCALE", "LONG_SCALE", "HEIGHT_SCALE")
_MULTI = ("LINE_NUM_COEFF", "LINE_DEN_COEFF", "SAMP_NUM_COEFF", "SAMP_DEN_COEFF")
# model offsets/scales are in (line, sample, lat, lon, height) order, as are _SINGLE's halves
_RADIUS_COMMENT = "# lunarmap reference radius (m):"
_SIZE_COMMENT = "# lunarmap image size (lines samples):"


def write_netcdf(model: RationalFunctionModel, path: str | os.PathLike[str]) -> Path:
    """Write :meth:`RationalFunctionModel.to_dataset` to a netCDF file, atomically.

    Returns
    -------
    Path
        The file written.
    """
    ds = model.to_dataset()
    return atomic_write(path, lambda tmp: ds.to_netcdf(tmp, engine="netcdf4"))


def read_netcdf(path: str | os.PathLike[str]) -> RationalFunctionModel:
    """Read a model written by :func:`write_netcdf`.

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    RpcFormatError
        The file is not a lunarmap RPC dataset.
    """
    ds = load_netcdf(path, RpcFormatError, "RPC model")
    try:
        return RationalFunctionModel.from_dataset(ds)
    except RpcFormatError as err:   # name the file: the dataset does not know where it came from
        raise RpcFormatError(f"{path}: {err}") from None


def rpc_txt_keywords(model: RationalFunctionModel) -> dict[str, float]:
    """The RPC00B keywords of a model in the RPC-file pixel convention (``(0, 0)`` = first pixel centre)."""
    o, s = model.offsets, model.scales
    # (line, sample, lat, lon, height) -> LINE, SAMP, LAT, LONG, HEIGHT: the same order
    values = [o[0] - GDAL_PIXEL_SHIFT, o[1] - GDAL_PIXEL_SHIFT, o[2], o[3], o[4], *s]
    out = dict(zip(_SINGLE, (float(v) for v in values)))
    for name, row in zip(_MULTI, model.coefficients):
        for j, v in enumerate(row, start=1):
            out[f"{name}_{j}"] = float(v)
    return out


def write_rpc_txt(model: RationalFunctionModel, path: str | os.PathLike[str]) -> Path:
    """Write a model in GDAL's ``_RPC.TXT`` keyword layout, atomically.

    Values are written with 17 significant digits, so reading the file back
    reproduces the model exactly. GDAL picks the file up as the RPC metadata
    of ``image.ext`` when it is named ``image_RPC.TXT``.
    """
    kw = rpc_txt_keywords(model)
    lines = [f"{k}: {v:.17g}" for k, v in kw.items()]
    lines.append(f"{_RADIUS_COMMENT} {model.radius:.17g}")
    lines.append(f"{_SIZE_COMMENT} {model.n_lines} {model.n_samples}")
    text = "\n".join(lines) + "\n"

    def write(tmp: Path) -> None:
        with open(tmp, "w", encoding="ascii") as fh:
            fh.write(text)

    return atomic_write(path, write)


def _comment_numbers(path: Path, line: str, prefix: str, count: int, kind: type) -> list:
    """The ``count`` numbers of one of lunarmap's comment lines (radius, image size), checked."""
    parts = line[len(prefix):].split()
    try:
        if len(parts) != count:
            raise ValueError
        values = [kind(p) for p in parts]
    except ValueError:
        raise RpcFormatError(f"{path}: comment line {line!r:.80} needs {count} number(s)") from None
    if not all(np.isfinite(v) and v >= 0 for v in values):
        raise RpcFormatError(f"{path}: comment line {line!r:.80} holds a negative or non-finite number")
    return values


def read_rpc_txt(path: str | os.PathLike[str], radius: float | None = None, n_lines: int | None = None,
                 n_samples: int | None = None) -> RationalFunctionModel:
    """Read an RPC00B ``_RPC.TXT`` file (GDAL / GeoEye keyword layout).

    Accepts ``KEY: value`` and ``KEY=value`` lines, values optionally
    followed by units (``LINE_OFF: +002048.00 pixels``).

    Parameters
    ----------
    path : path-like
        The text file.
    radius : float, optional
        Reference sphere radius of the heights, metres; default the radius
        lunarmap wrote in its comment line, else 1737.4 km.
    n_lines, n_samples : int, optional
        Image size, pixels; default lunarmap's comment line, else 0.

    Raises
    ------
    FileNotFoundError
        No such file.
    RpcFormatError
        A keyword is missing or its value is not a finite number.
    """
    path = Path(path)
    text = path.read_text(encoding="ascii", errors="replace")
    values: dict[str, str] = {}
    file_radius: float | None = None
    size = (0, 0)
    for raw in text.splitlines():
        line = raw.strip()
        if line.startswith(_RADIUS_COMMENT):
            file_radius = _comment_numbers(path, line, _RADIUS_COMMENT, 1, float)[0]
            continue
        if line.startswith(_SIZE_COMMENT):
            n_l, n_s = _comment_numbers(path, line, _SIZE_COMMENT, 2, int)
            size = (n_l, n_s)
            continue
        if not line or line.startswith("#"):
            continue
        sep = min((i for i in (line.find(":"), line.find("=")) if i >= 0), default=-1)
        if sep < 0:
            continue
        values[line[:sep].strip().upper()] = line[sep + 1:].strip()

    def number(key: str) -> float:
        if key not in values:
            raise RpcFormatError(f"{path}: RPC keyword {key} is missing")
        token = values[key].split()[0] if values[key].split() else ""
        try:
            v = float(token)
        except ValueError:
            raise RpcFormatError(f"{path}: RPC keyword {key} has no number: {values[key]!r}") from None
        if not np.isfinite(v):
            raise RpcFormatError(f"{path}: RPC keyword {key} is not finite: {values[key]!r}")
        return v

    single = [number(k) for k in _SINGLE]
    coeffs = np.array([[number(f"{name}_{j}") for j in range(1, 21)] for name in _MULTI])
    offsets = np.array(single[:5])
    offsets[:2] += GDAL_PIXEL_SHIFT
    scales = np.array(single[5:])
    r = radius if radius is not None else (file_radius if file_radius is not None else MOON_RADIUS)
    return RationalFunctionModel(coeffs, offsets, scales, r,
                                 size[0] if n_lines is None else n_lines,
                                 size[1] if n_samples is None else n_samples,
                                 {"source_file": str(path)})
