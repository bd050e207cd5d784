"""The tie-point chain as a dask graph: one task per image tile (detection) and per image pair (matching).

Every task is a plain function of picklable inputs (arrays, sensor models,
parameter dataclasses), so the graph runs on the threaded scheduler, on
processes or on a ``distributed`` cluster alike. Images that are lazy dask
arrays (e.g. from :func:`lunarmap.simulate.render_image`) are rendered by
their own tasks upstream.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import dask
import xarray as xr
from dask.delayed import Delayed

from ..errors import InvalidInputError
from .pairs import as_array
from .tiepoints import TiePointParams, assemble_tiepoints, detect_tile, match_pair, merge_points, tile_windows

__all__ = ["tiepoint_graph"]


def _shape(image: Any) -> tuple[int, int]:
    shape = tuple(getattr(image, "shape", ()))
    if len(shape) != 2:
        raise InvalidInputError(f"images must be 2-D (line, sample), got shape {shape}")
    return shape  # type: ignore[return-value]


def tiepoint_graph(images: Mapping[str, Any], sensors: Mapping[str, Any],
                   pairs: Sequence[tuple[str, str]] | None = None, height: Any = 0.0,
                   params: TiePointParams | None = None) -> Delayed:
    """Delayed tie-point table of a set of images; see :func:`~lunarmap.matching.find_tiepoints`."""
    params = params or TiePointParams()
    names = list(images)
    if len(names) < 2:
        raise InvalidInputError(f"tie points need at least 2 images, got {len(names)}")
    missing = [n for n in names if n not in sensors]
    if missing:
        raise InvalidInputError(f"no sensor model for image(s) {missing}")
    if pairs is None:
        pairs = [(a, b) for k, a in enumerate(names) for b in names[k + 1:]]
    for a, b in pairs:
        if a not in images or b not in images or a == b:
            raise InvalidInputError(f"pair ({a!r}, {b!r}) does not name two different images")
    sat = params.match.saturation
    arrays = {}
    for n in names:
        img = images[n]
        data = img.data if isinstance(img, xr.DataArray) else img
        _shape(data)
        arrays[n] = dask.delayed(as_array, pure=True)(data, n, sat)
    halo = params.detect.border + params.detect.window + params.detect.nms
    points: dict[str, Any] = {}
    for n in sorted({a for a, _ in pairs}):
        data = images[n].data if isinstance(images[n], xr.DataArray) else images[n]
        tiles = []
        for core, pad in tile_windows(_shape(data), params.detect.tile, halo):
            window = data[pad[0]:pad[1], pad[2]:pad[3]]
            tiles.append(dask.delayed(detect_tile, pure=True)(window, core, pad, params.detect, sat, n))
        points[n] = dask.delayed(merge_points, pure=True)(tiles)
    index = {n: k for k, n in enumerate(names)}
    sens = {n: dask.delayed(sensors[n], traverse=False) for n in names}
    h = dask.delayed(height, traverse=False) if isinstance(height, xr.DataArray) else height
    matched = []
    for a, b in pairs:
        m = dask.delayed(match_pair, pure=True)(arrays[a], arrays[b], sens[a], sens[b], points[a], h, params,
                                                f"{a} -> {b}")
        matched.append(dask.delayed(tuple)([index[a], index[b], m]))
    return dask.delayed(assemble_tiepoints, pure=True)(matched, names, params.track_tol)
