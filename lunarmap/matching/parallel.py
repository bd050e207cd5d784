"""The tie-point chain as a dask graph: one task per image tile (detection) and per image pair (matching).

Every task is a plain function of picklable inputs (arrays, sensor models,
parameter dataclasses), so the graph runs on the threaded scheduler, on
processes or on a ``distributed`` cluster alike. Images that are lazy dask
arrays (e.g. from :func:`lunarmap.simulate.render_image`) are rendered by
their own tasks upstream, and each detection tile reads only its chunks;
an in-memory image enters the graph once, as one node that its tiles and
pairs share (slicing it while building the graph would put a copy of every
tile into the graph, shipped to the scheduler on each compute).

Worker processes: start them without distributed's default
``MALLOC_TRIM_THRESHOLD_=65536`` (:data:`WORKER_ENVIRON`, e.g.
``dask.config.set({"distributed.nanny.pre-spawn-environ": WORKER_ENVIRON})``
before creating the cluster). That setting turns off glibc's adaptive mmap
threshold, so every numpy temporary above 128 kB is mmap-ed and page-faulted
afresh: measured on the 4-image bench set, the pair-matching tasks ran 2-7
times slower in worker processes than in the client, and a 2-worker cluster
took 11.3 s against 2.9 s serial.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import dask
import numpy as np
import xarray as xr
from dask.base import is_dask_collection, tokenize
from dask.delayed import Delayed
from numpy.typing import NDArray

from ..camera.sensor import SensorModel
from ..errors import InvalidInputError
from ..rpc.parallel import WORKER_ENVIRON as _RPC_WORKER_ENVIRON
from .interest import InterestPoints
from .pairs import PairMatches, as_array
from .tiepoints import (
    DetectParams,
    TiePointParams,
    assemble_tiepoints,
    detect_tile,
    match_pair,
    merge_points,
    tile_windows,
)

__all__ = ["tiepoint_graph", "find_tiepoints", "WORKER_ENVIRON"]

#: Environment for dask worker processes running the chain (one BLAS/OpenMP thread each, no
#: ``MALLOC_TRIM_THRESHOLD_``); the same as :data:`lunarmap.rpc.parallel.WORKER_ENVIRON`.
WORKER_ENVIRON = dict(_RPC_WORKER_ENVIRON)


def _shape(image: Any) -> tuple[int, int]:
    shape = tuple(getattr(image, "shape", ()))
    if len(shape) != 2:
        raise InvalidInputError(f"images must be 2-D (line, sample), got shape {shape}")
    return shape  # type: ignore[return-value]


def _detect_in(image: NDArray, core: tuple[int, int, int, int], padded: tuple[int, int, int, int],
               params: DetectParams, saturation: float | None, label: str) -> InterestPoints:
    """:func:`detect_tile` on the padded window of a whole image (the window is cut on the worker)."""
    return detect_tile(image[padded[0]:padded[1], padded[2]:padded[3]], core, padded, params, saturation, label)


def _assemble(index_pairs: Sequence[tuple[int, int]], matched: Sequence[PairMatches], names: Sequence[str],
              track_tol: float) -> xr.Dataset:
    """:func:`assemble_tiepoints` of the pair results in graph order."""
    return assemble_tiepoints([(i, j, m) for (i, j), m in zip(index_pairs, matched)], names, track_tol)


def tiepoint_graph(images: Mapping[str, Any], sensors: Mapping[str, SensorModel],
                   pairs: Sequence[tuple[str, str]] | None = None, height: Any = 0.0,
                   params: TiePointParams | None = None, pixels: Mapping[str, Any] | None = None) -> Delayed:
    """Delayed tie-point table of a set of images; see :func:`~lunarmap.matching.find_tiepoints`.

    ``pixels`` optionally maps image names to pixel arrays already placed on a cluster
    (``distributed.Future`` from ``Client.scatter``); those images are not embedded in the graph.
    """
    pixels = pixels or {}
    params = params or TiePointParams()
    names = list(images)
    if len(names) < 2:
        raise InvalidInputError(f"tie points need at least 2 images, got {len(names)}")
    missing = [n for n in names if n not in sensors]
    if missing:
        raise InvalidInputError(f"no sensor model for image(s) {missing}")
    wrong = [n for n in names if not isinstance(sensors[n], SensorModel)]
    if wrong:
        raise InvalidInputError(f"sensor(s) of {wrong} are not lunarmap SensorModels "
                                f"({type(sensors[wrong[0]]).__name__})")
    if pairs is None:
        pairs = [(a, b) for k, a in enumerate(names) for b in names[k + 1:]]
    for a, b in pairs:
        if a not in images or b not in images or a == b:
            raise InvalidInputError(f"pair ({a!r}, {b!r}) does not name two different images")
    sat = params.match.saturation
    raw: dict[str, Any] = {}
    arrays = {}
    for n in names:
        img = images[n]
        data = img.data if isinstance(img, xr.DataArray) else img
        _shape(data)
        # In-memory pixels become one graph node (see the module notes); dask arrays stay lazy.
        if n in pixels:
            raw[n] = pixels[n]
        elif is_dask_collection(data):
            raw[n] = data
        else:
            raw[n] = dask.delayed(np.asarray(data), name=f"pixels-{tokenize(data)}")
        arrays[n] = dask.delayed(as_array, pure=True)(raw[n], n, sat)
    halo = params.detect.border + params.detect.window + params.detect.nms
    points: dict[str, Any] = {}
    for n in sorted({a for a, _ in pairs}):
        data = raw[n]
        lazy = is_dask_collection(data) and not isinstance(data, Delayed)
        tiles = []
        for core, pad in tile_windows(_shape(images[n]), params.detect.tile, halo):
            if lazy:
                tiles.append(dask.delayed(detect_tile, pure=True)(data[pad[0]:pad[1], pad[2]:pad[3]], core, pad,
                                                                  params.detect, sat, n))
            else:
                tiles.append(dask.delayed(_detect_in, pure=True)(data, core, pad, params.detect, sat, n))
        points[n] = dask.delayed(merge_points, pure=True)(tiles)
    index = {n: k for k, n in enumerate(names)}
    sens = {n: dask.delayed(sensors[n], traverse=False) for n in names}
    h = dask.delayed(height, traverse=False) if isinstance(height, xr.DataArray) else height
    matched = []
    for a, b in pairs:
        matched.append(dask.delayed(match_pair, pure=True)(arrays[a], arrays[b], sens[a], sens[b], points[a], h,
                                                           params, f"{a} -> {b}"))
    # Image indices travel as plain values (a delayed tuple per pair would be one more task each).
    return dask.delayed(_assemble, pure=True)([(index[a], index[b]) for a, b in pairs], matched, names,
                                              params.track_tol)


def find_tiepoints(images: Mapping[str, xr.DataArray | NDArray], sensors: Mapping[str, SensorModel],
                   pairs: Sequence[tuple[str, str]] | None = None, height: Any = 0.0,
                   params: TiePointParams | None = None, scheduler: Any = "sync") -> xr.Dataset:
    """Tie points of a set of images (one dask task per tile and per image pair).

    Parameters
    ----------
    images : mapping name -> xarray.DataArray or ndarray
        Images (``line``, ``sample``), grey levels; NaN marks invalid pixels.
    sensors : mapping name -> SensorModel
        Sensor model of each image (cameras or RPCs).
    pairs : sequence of (name, name), optional
        Pairs to match (points of the first are matched into the second);
        default: every pair ``(a, b)`` with ``a`` before ``b``.
    height : float or xarray.DataArray
        Prediction height (metres) or coarse DTM.
    params : TiePointParams, optional
        Every setting of the chain: ``detect`` (Förstner interest points: cell size, thresholds),
        ``match`` (pyramid NCC and least-squares matching: search radius, window, pyramid levels,
        saturation), ``ransac`` (local affine model of each pair), ``track_tol`` (pixels: positions of
        one image this close are one feature of a track) and ``max_points`` (most interest points
        matched per pair, uniform over the overlap; ``None``: all). Default ``TiePointParams()``.
    scheduler : str or distributed.Client
        ``"sync"`` (serial), ``"threads"``, ``"processes"`` or a ``distributed.Client``
        (start its worker processes with :data:`lunarmap.matching.parallel.WORKER_ENVIRON`,
        see :mod:`lunarmap.matching.parallel`).

    Returns
    -------
    xarray.Dataset
        The tie-point table, one row per image observation (dimension ``observation``): ``point_id``,
        ``image_id`` (index into the ``image`` coordinate, the image names), ``line``, ``sample``
        (pixels, CSM convention), ``sigma_line``, ``sigma_sample`` (pixels, from least-squares
        matching) and ``correlation``; :func:`lunarmap.build_block` takes it as it is.
    """
    if hasattr(scheduler, "compute") and hasattr(scheduler, "scatter"):  # a distributed.Client
        # In-memory pixels go to the workers once, by scatter, instead of inside the task graph
        # (which the scheduler would receive, store and forward: distributed warns past 10 MB).
        pixels = {}
        for n, img in images.items():
            data = img.data if isinstance(img, xr.DataArray) else img
            if isinstance(data, np.ndarray):
                pixels[n] = scheduler.scatter(data, hash=True)
        graph = tiepoint_graph(images, sensors, pairs=pairs, height=height, params=params, pixels=pixels)
        return scheduler.compute(graph).result()
    graph = tiepoint_graph(images, sensors, pairs=pairs, height=height, params=params)
    return graph.compute(scheduler=scheduler)
