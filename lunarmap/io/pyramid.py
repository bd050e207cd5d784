"""Image pyramids (overviews) computed once per image, stored chunked, read by window.

Level ``k`` has pixels ``2^k`` times larger than the image's: each of its pixels is the mean of a
``2 x 2`` block of level ``k - 1`` (an odd last row or column is dropped; a block with an invalid
pixel is invalid), exactly :func:`lunarmap.matching.pyramid.build_pyramid` of the image with its
invalid and saturated pixels set to NaN. With the CSM convention a point at ``(line, sample)`` on
level 0 sits at ``(line, sample) / 2^k`` on level ``k``.

:func:`write_pyramid` reads the image in stripes of whole lines (``2^levels`` times a few hundred
lines: its memory does not grow with the image's length) and writes every level chunk by chunk
into one netCDF-4 file, ``level_1`` ... ``level_K`` (float32, NaN = no data, chunks of 256 x 256
pixels), atomically. netCDF-4 rather than Zarr: it is already a dependency, every tool of the field
reads it, and its chunks are read by window (:class:`~lunarmap.io.window.PixelSource`). Values are
stored as float32: exact for 8-bit images up to level 8 and 16-bit images up to level 4 (a level-k
mean of integers has ``2k`` more bits); for float images they are rounded to 2^-24 relative,
far below the grey-level noise, and the finest level, where matching takes its measurements, is
always read from the image itself.

:class:`Pyramid` opens a store, checks that it belongs to the image it is asked for (shape,
levels, saturation, and the image's content digest when the writer was given one) and gives each
level as a window source; a missing or damaged store raises :class:`~lunarmap.errors.PyramidError`,
which a run answers by computing the store again.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..atomic import atomic_path
from ..errors import ImageWindowError, InvalidInputError, PyramidError
from .nclock import close_dataset, netcdf_library
from .window import PixelSource, WindowSource

__all__ = ["write_pyramid", "Pyramid", "pyramid_shapes", "MIN_LEVEL_SIZE"]

#: A level is not made from one whose smaller side is below this (the rule of ``build_pyramid``).
MIN_LEVEL_SIZE = 32
_CHUNK = 256
_FORMAT = "lunarmap image pyramid 1"


def pyramid_shapes(shape: tuple[int, int], levels: int) -> list[tuple[int, int]]:
    """Shapes of levels ``1..`` (at most ``levels``) of an image of ``shape`` (``build_pyramid``'s rule)."""
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or levels < 0:
        raise InvalidInputError(f"pyramid levels must be an integer >= 0, got {levels!r}")
    out: list[tuple[int, int]] = []
    h, w = int(shape[0]), int(shape[1])
    for _ in range(int(levels)):
        if min(h, w) < MIN_LEVEL_SIZE:
            break
        h, w = h // 2, w // 2
        out.append((h, w))
    return out


def _down(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """One 2 x 2 block mean (the arithmetic of ``matching.pyramid.downsample``)."""
    h, w = a.shape[0] // 2 * 2, a.shape[1] // 2 * 2
    a = a[:h, :w]
    return 0.25 * (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2])


def write_pyramid(source: WindowSource, path: str | os.PathLike[str], levels: int,
                  saturation: float | None = None, digest: str = "", stripe_lines: int = 1024,
                  attrs: dict[str, Any] | None = None) -> Path:
    """Compute an image's pyramid levels stripe by stripe and write them, atomically (module docstring).

    Parameters
    ----------
    source : WindowSource
        The image (:func:`lunarmap.io.window.open_source`).
    path : path-like
        Output netCDF file.
    levels : int
        Most reductions (fewer when the image gets smaller than :data:`MIN_LEVEL_SIZE`).
    saturation : float, optional
        Grey level from which pixels count as saturated (invalid), as in matching.
    digest : str
        Content digest of the image, recorded and checked by :class:`Pyramid`.
    stripe_lines : int
        Level-0 lines per stripe (rounded up to a multiple of ``2^levels``).
    attrs : dict, optional
        Further global attributes (provenance).

    Returns
    -------
    pathlib.Path

    Raises
    ------
    ImageWindowError
        The image cannot be read where a stripe lies.
    PyramidError
        The store cannot be written (the partial file is removed).
    """
    import netCDF4

    shapes = pyramid_shapes(source.shape, levels)
    if stripe_lines < 1:
        raise InvalidInputError(f"stripe_lines must be >= 1, got {stripe_lines}")
    k = len(shapes)
    unit = 2 ** k
    stripe = -(-int(stripe_lines) // unit) * unit
    h0, w0 = source.shape
    final = Path(path)
    try:
        with atomic_path(final) as tmp:
            # netCDF-C/HDF5 calls under the process's lock (lunarmap.io.nclock); the source's stripes are
            # read outside it (a netCDF source takes it itself)
            with netcdf_library():
                ds = netCDF4.Dataset(tmp, "w", format="NETCDF4")
            try:
                with netcdf_library():
                    ds.setncatts({"format": _FORMAT, "source": getattr(source, "name", ""), "lines": h0, "samples": w0,
                                  "levels": k, "saturation": "none" if saturation is None else float(saturation),
                                  "digest": digest, "pixel_convention": "CSM: level k pixel centre at (i + 0.5) 2^k",
                                  **(attrs or {})})
                    var = []
                    for lev, (h, w) in enumerate(shapes, start=1):
                        ds.createDimension(f"line_{lev}", h)
                        ds.createDimension(f"sample_{lev}", w)
                        v = ds.createVariable(f"level_{lev}", "f4", (f"line_{lev}", f"sample_{lev}"),
                                              chunksizes=(min(_CHUNK, h), min(_CHUNK, w)),
                                              fill_value=np.float32(np.nan))
                        v.set_auto_mask(False)
                        v.long_name = f"mean of 2^{lev} x 2^{lev} image pixels"
                        var.append(v)
                # stripes start at multiples of 2^k lines, so every level's rows of a stripe are whole
                # blocks of the level below; the last stripe's odd lines drop out as in build_pyramid
                for r0 in range(0, h0 if k else 0, stripe):
                    a = source.read(r0, min(r0 + stripe, h0), 0, w0)
                    if saturation is not None:
                        with np.errstate(invalid="ignore"):
                            a[a >= saturation] = np.nan
                    a[~np.isfinite(a)] = np.nan
                    for lev, (h, _w) in enumerate(shapes, start=1):
                        a = _down(a)
                        a0 = r0 // 2 ** lev
                        rows = min(a.shape[0], h - a0)
                        if rows > 0:
                            with netcdf_library():
                                var[lev - 1][a0:a0 + rows, :] = a[:rows].astype(np.float32)
            finally:
                close_dataset(ds)
    except (ImageWindowError, InvalidInputError):
        raise
    except (OSError, RuntimeError) as err:
        raise PyramidError(f"pyramid {final}: cannot be written: {type(err).__name__}: {err}") from None
    return final


class Pyramid:
    """A stored image pyramid (see the module docstring).

    Parameters
    ----------
    path : path-like
        The store written by :func:`write_pyramid`.
    shape : (int, int), optional
        The image's ``(lines, samples)``: checked against the store.
    digest : str, optional
        The image's content digest: checked against the store's when both are given.

    Attributes
    ----------
    levels : int
        Stored levels (level 0, the image itself, is not in the store).
    saturation : float or None

    Raises
    ------
    PyramidError
        Missing, unreadable or damaged store, or one made from another image.
    """

    def __init__(self, path: str | os.PathLike[str], shape: tuple[int, int] | None = None, digest: str = "") -> None:
        import netCDF4

        self.path = str(path)
        if not os.path.isfile(self.path):
            raise PyramidError(f"pyramid {self.path} does not exist")
        try:
            with netcdf_library(), netCDF4.Dataset(self.path, "r") as ds:
                att = {a: ds.getncattr(a) for a in ds.ncattrs()}
                stored = {n: tuple(int(d) for d in v.shape) for n, v in ds.variables.items()}
        except (OSError, RuntimeError, ValueError) as err:
            raise PyramidError(f"pyramid {self.path} is not readable: {type(err).__name__}: {err}") from None
        if att.get("format") != _FORMAT:
            raise PyramidError(f"pyramid {self.path} is not a lunarmap pyramid store (format {att.get('format')!r})")
        try:
            self.source_shape = (int(att["lines"]), int(att["samples"]))
            self.levels = int(att["levels"])
            sat = att.get("saturation", "none")
            self.saturation = None if isinstance(sat, str) else float(sat)
        except (KeyError, TypeError, ValueError) as err:
            raise PyramidError(f"pyramid {self.path}: attribute {err} is missing or garbled") from None
        self.digest = str(att.get("digest", ""))
        if shape is not None and tuple(int(v) for v in shape) != self.source_shape:
            raise PyramidError(f"pyramid {self.path} was made from a {self.source_shape[0]} x {self.source_shape[1]} "
                               f"image, not this {shape[0]} x {shape[1]} one")
        if digest and self.digest and digest != self.digest:
            raise PyramidError(f"pyramid {self.path} was made from another image (content digest differs)")
        want = pyramid_shapes(self.source_shape, self.levels)
        if len(want) != self.levels or any(stored.get(f"level_{k}") != s for k, s in enumerate(want, start=1)):
            raise PyramidError(f"pyramid {self.path} is damaged: its levels do not have the shapes of a "
                               f"{self.source_shape[0]} x {self.source_shape[1]} image's")

    def level(self, k: int) -> WindowSource:
        """Level ``k`` (1 ... :attr:`levels`) as a window source."""
        if not 1 <= k <= self.levels:
            raise PyramidError(f"pyramid {self.path} has levels 1 to {self.levels}, not {k}")
        src = PixelSource(self.path, variable=f"level_{k}")
        src.name = f"{self.path} level {k}"
        return src

    def __repr__(self) -> str:
        return f"Pyramid({self.path!r}, {self.source_shape[0]} x {self.source_shape[1]}, {self.levels} levels)"
