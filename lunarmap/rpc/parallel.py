"""RPC fitting on dask: rigorous grids in tiles, many images in one graph.

The rigorous evaluation of a grid is split into tiles of image lines
(:func:`rigorous_grid_delayed`); each tile is ``camera.image_to_ground`` on
a sub-grid, and the tiles are stitched back in the serial order (layers x
lines x samples), so the fitted coefficients are identical to
:func:`~lunarmap.rpc.fit.fit_rpc`'s. :func:`fit_rpc_delayed` builds one
image's graph (fit-grid tiles -> fit -> check-grid tiles -> report) and
:func:`fit_many` merges the graphs of many images and computes them
together, on a ``distributed.Client`` when given one.

No SPICE is needed on the workers: cameras are plain numpy objects that
pickle (build them from ISDs first, see ``lunarmap.camera.factory``).
They are shipped bit-exact (:class:`ExactCamera`): ``ExteriorOrientation``'s
own pickling re-normalises the quaternions on load, which moves their last
bits on every round trip, so a worker's camera would not be the caller's.

Measured on a 2-core machine: distributed's default worker environment
``MALLOC_TRIM_THRESHOLD_=65536`` doubled the CPU time of a fit (large numpy
temporaries are then mmap-ed and page-faulted afresh each time); clusters
for RPC work are better started without it, e.g. with
``dask.config.set({"distributed.nanny.pre-spawn-environ":
WORKER_ENVIRON})`` (:data:`WORKER_ENVIRON`), as ``bench/bench_rpc.py`` does.
"""

from __future__ import annotations

import copyreg
import io
import pickle
from dataclasses import asdict
from typing import Any, Sequence

import dask
import numpy as np
from dask.delayed import Delayed

from ..camera.sensor import SensorModel
from ..errors import RpcInputError
from .fit import FitOptions, RpcFit, fit_from_grid, fit_rpc
from .grid import GridNodes, GroundGrid, check_grid_nodes, fit_grid_nodes, height_layers, rigorous_grid

__all__ = ["rigorous_grid_delayed", "fit_rpc_delayed", "fit_many", "ExactCamera", "WORKER_ENVIRON"]

#: Worker environment for RPC clusters: one BLAS/OpenMP thread per worker
#: thread, and no ``MALLOC_TRIM_THRESHOLD_`` (see the module notes).
WORKER_ENVIRON = {"OMP_NUM_THREADS": 1, "MKL_NUM_THREADS": 1, "OPENBLAS_NUM_THREADS": 1}


def _restore(cls: type, state: dict[str, Any]) -> Any:
    obj: Any = object.__new__(cls)
    for k, v in state.items():
        object.__setattr__(obj, k, v)
    return obj


def _exact_reduce(obj: Any) -> tuple[Any, ...]:
    return _restore, (type(obj), dict(vars(obj)))


class ExactCamera:
    """A camera that pickles bit-exact (its ExteriorOrientation state is copied, not rebuilt).

    ``ExactCamera(camera).camera`` is the camera; its caches stay behind (the cameras'
    own ``__getstate__``) and are rebuilt where needed. On unpickling, the
    exterior orientation's arrays and interpolants are restored as they
    were instead of being re-normalised (see the module notes).
    """

    def __init__(self, camera: SensorModel) -> None:
        self.camera = camera

    def __reduce__(self) -> tuple[Any, ...]:
        from ..orientation.exterior import ExteriorOrientation  # noqa: PLC0415

        buf = io.BytesIO()
        pickler = pickle.Pickler(buf, protocol=pickle.HIGHEST_PROTOCOL)
        pickler.dispatch_table = copyreg.dispatch_table.copy()
        pickler.dispatch_table[ExteriorOrientation] = _exact_reduce
        pickler.dump(self.camera)
        return _load_exact, (buf.getvalue(),)


def _load_exact(data: bytes) -> "ExactCamera":
    return ExactCamera(pickle.loads(data))


def _unwrap(cam: SensorModel | ExactCamera) -> SensorModel:
    return cam.camera if isinstance(cam, ExactCamera) else cam


def _fit_from_grid_exact(cam: ExactCamera, *args: Any) -> RpcFit:
    return fit_from_grid(cam.camera, *args)


def _fit_exact(cam: ExactCamera, check: bool, options: FitOptions) -> RpcFit:
    return fit_rpc(cam.camera, check=check, options=options)


def _tile(camera: SensorModel | ExactCamera, nodes: GridNodes, max_emission: float) -> GroundGrid:
    return rigorous_grid(_unwrap(camera), nodes, max_emission)


def _stitch(parts: list[GroundGrid], n_heights: int, n_samples: int) -> GroundGrid:
    """Tiles over lines -> one grid in serial (layer, line, sample) order."""
    def cat(k: str) -> np.ndarray:
        return np.concatenate([getattr(p, k).reshape(n_heights, -1, n_samples) for p in parts], axis=1).ravel()
    return GroundGrid(*(cat(k) for k in ("line", "sample", "lon", "lat", "height")))


def rigorous_grid_delayed(camera: SensorModel | Delayed, nodes: GridNodes, tile_lines: int = 32,
                          max_emission: float = 85.0) -> Delayed:
    """A delayed :class:`~lunarmap.rpc.grid.GroundGrid` computed in tiles of ``tile_lines`` grid lines.

    Equal, element for element, to :func:`~lunarmap.rpc.grid.rigorous_grid`
    on the whole grid.
    """
    if int(tile_lines) < 1:
        raise RpcInputError(f"tile_lines must be >= 1, got {tile_lines}")
    parts = []
    for i0 in range(0, nodes.lines.size, int(tile_lines)):
        sub = GridNodes(nodes.lines[i0:i0 + int(tile_lines)], nodes.samples, nodes.heights)
        parts.append(dask.delayed(_tile, pure=True)(camera, sub, max_emission))
    return dask.delayed(_stitch, pure=True)(parts, nodes.heights.size, nodes.samples.size)


def _options(height_range: tuple[float, float] | None, options: FitOptions | None,
             overrides: dict[str, Any]) -> FitOptions:
    opts = options or FitOptions()
    if height_range is not None:
        overrides = {**overrides, "height_range": tuple(height_range)}
    unknown = set(overrides) - set(FitOptions.__dataclass_fields__)
    if unknown:
        raise RpcInputError(f"unknown fit option(s): {', '.join(sorted(unknown))}")
    return FitOptions(**{**asdict(opts), **overrides}) if overrides else opts


def fit_rpc_delayed(camera: SensorModel, height_range: tuple[float, float] | None = None, *, check: bool = True,
                    tile_lines: int | None = None, options: FitOptions | None = None,
                    **option_overrides: Any) -> Delayed:
    """The dask graph of :func:`~lunarmap.rpc.fit.fit_rpc` for one image; computes to an :class:`RpcFit`.

    Parameters
    ----------
    camera : FrameCamera or LineScanCamera
        Rigorous model (pickled once into the graph).
    height_range, check, options, **option_overrides
        As for :func:`~lunarmap.rpc.fit.fit_rpc`.
    tile_lines : int, optional
        Grid lines per rigorous-evaluation tile (fit grid -> fit -> check
        grid -> report as separate tasks); ``None``: the whole fit is one
        task (the right choice when many images already fill the workers).
    """
    opts = _options(height_range, options, option_overrides)
    if tile_lines is None:
        # one task per image: nothing to ship between workers but the result
        return dask.delayed(_fit_exact, pure=True)(ExactCamera(camera), check, opts)
    layers = height_layers(opts.height_range, opts.n_layers, opts.margin)
    nodes = fit_grid_nodes(camera.n_lines, camera.n_samples, layers, opts.short_axis, opts.long_axis_max)
    # the wrapper travels between workers with the tasks that need the camera
    cam = dask.delayed(ExactCamera(camera), traverse=False)
    grid = rigorous_grid_delayed(cam, nodes, tile_lines, opts.max_emission)
    check_grid = None
    if check:
        cnodes = check_grid_nodes(camera.n_lines, camera.n_samples, layers, opts.short_axis, opts.long_axis_max,
                                  opts.check_density, opts.check_outside)
        check_grid = rigorous_grid_delayed(cam, cnodes, tile_lines, 90.0)
    return dask.delayed(_fit_from_grid_exact, pure=True)(cam, grid, nodes, layers, opts, check, check_grid)


def fit_many(cameras: Sequence[SensorModel], height_ranges: Sequence[tuple[float, float] | None] | None = None,
             *, client: Any = None, check: bool = True, tile_lines: int | None = None,
             options: FitOptions | None = None, **option_overrides: Any) -> list[RpcFit]:
    """Fit RFMs to many images as one dask graph.

    Parameters
    ----------
    cameras : sequence of FrameCamera or LineScanCamera
        Rigorous models.
    height_ranges : sequence of (float, float) or None, optional
        Per-image height ranges, metres; ``None`` entries (or no sequence)
        use the options' range.
    client : distributed.Client, optional
        Compute on this cluster; otherwise dask's current scheduler.
    check, tile_lines, options, **option_overrides
        As for :func:`fit_rpc_delayed`.

    Returns
    -------
    list of RpcFit
        In the order of ``cameras``; identical to serial
        :func:`~lunarmap.rpc.fit.fit_rpc` results.
    """
    cameras = list(cameras)
    if height_ranges is None:
        height_ranges = [None] * len(cameras)
    if len(height_ranges) != len(cameras):
        raise RpcInputError(f"{len(height_ranges)} height ranges for {len(cameras)} cameras")
    graphs = [fit_rpc_delayed(c, hr, check=check, tile_lines=tile_lines, options=options, **option_overrides)
              for c, hr in zip(cameras, height_ranges)]
    if client is not None:
        return list(client.gather(client.compute(graphs)))
    return list(dask.compute(*graphs))
