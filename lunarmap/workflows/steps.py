"""The steps of a run: plain, picklable functions of their inputs that write their output into the store.

Every step takes the :class:`~lunarmap.workflows.store.Store`, its key and its inputs (paths, upstream
:class:`Done` records, parameters), returns a :class:`Done` record and does nothing when its output is
already there. Upstream outputs travel as files, not as objects: a camera is always rebuilt from its
stored ISD (:func:`lunarmap.camera_from_isd_file`, identical to the in-memory camera), so a step gives
the same result whether its inputs were computed in this run, in an earlier one, or on another worker.
"""

from __future__ import annotations

import contextlib
import contextvars
import functools
import json
import logging
import threading
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence

import numpy as np
import xarray as xr

from ..blas import single_threaded_blas
from ..camera.geodesy import MOON_GEOGRAPHIC_CRS
from ..errors import LunarmapError, WorkflowError
from .outputs import Exported, Outputs, export_image, export_rpcs, remember_rfm
from .store import Store

_log = logging.getLogger(__name__)

__all__ = ["Done", "ImageJob", "ImageDone", "BatchDone", "MatchJob", "image_steps", "isd_step", "rpc_step", "pyramid_step",
           "detect_step", "footprint_step", "match_batch", "match_step", "tiepoints_step", "adjust_step",
           "kernels_step", "kernel_sets", "adjusted_rpc_batch", "read_pixels", "provenance"]


@dataclass(frozen=True)
class Done:
    """Record of a finished step: where its output is and whether this call computed it.

    Attributes
    ----------
    step, key : str
        Step name and output key.
    item : str
        The image, tile or pair it concerns (``""`` for whole-block steps).
    path : str
        Output file or folder.
    computed : bool
        False when the output was already in the store.
    seconds : float
        Wall time of this call.
    note : str
        A short remark (e.g. why a pair was skipped).
    peak_mb : float
        Peak resident memory of the process while this call computed the step, MB (sampled every
        0.1 s; 0 when reused): what a worker needs for it, including what the process already held.
    """

    step: str
    key: str
    item: str
    path: str
    computed: bool
    seconds: float = 0.0
    note: str = ""
    peak_mb: float = 0.0


#: ``threads=`` of :func:`_step` for a step that runs alone in its run's graph: every core of the process
ALL = "all"


# the threads of an ALL step on this thread (None: every core of the process); a serial run sets 1: it is
# the one-core baseline its parallel runs are measured against (engine._compute)
_BARRIER_THREADS: contextvars.ContextVar[int | None] = contextvars.ContextVar("lunarmap_barrier_threads",
                                                                              default=None)


@contextlib.contextmanager
def barrier_threads(n: int | None) -> Iterator[None]:
    """Context in which a step of ``threads=ALL`` (the adjustment) called from this thread uses ``n`` threads
    (``None``: every core of the process)."""
    token = _BARRIER_THREADS.set(n)
    try:
        yield
    finally:
        _BARRIER_THREADS.reset(token)


def _cores() -> int:
    """The cores this process may run on (or what :func:`barrier_threads` allows)."""
    import os

    limit = _BARRIER_THREADS.get()
    if limit is not None:
        return max(1, int(limit))

    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:     # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


@contextlib.contextmanager
def _threads(threads: int | str, blas: bool = False) -> Iterator[int]:
    """The thread policy of a computing step; yields the threads it may use.

    One thread (BLAS and numba) by default: steps run side by side, one per dask worker thread, and a
    result must not depend on where it ran. :data:`ALL`: the step runs alone (a barrier of the graph: every
    other task waits for it or is done), so it takes every core of its process for numba and the per-image
    work of the adjustment (:func:`lunarmap.adjust.sensors.image_threads`), whatever its dask worker's
    ``nthreads``: on a ``LocalCluster`` of single-threaded workers the others' cores idle meanwhile. Both split
    their work independently of the thread count (no sum is reordered), so the results are identical.
    BLAS keeps one thread unless ``blas``: OpenBLAS's threaded LAPACK factors in another order (measured on
    the 192-image block's adjustment with 2 BLAS threads: posterior sigmas 1.6e-7 relative apart from one
    thread's, corrections 1.8e-10 of their largest), and the solver's own factorisations are single-threaded
    anyway (:mod:`lunarmap.adjust.factor`).
    """
    if threads == 1:
        with single_threaded_blas():
            yield 1
        return
    from ..adjust.sensors import image_threads
    from ..blas import blas_threads

    n = _cores() if threads == ALL else max(1, int(threads))
    with (blas_threads(n) if blas else single_threaded_blas()), _numba_threads(n), image_threads(n):
        yield n


@contextlib.contextmanager
def _numba_threads(n: int) -> Iterator[None]:
    """numba's thread count for this thread (its ``parallel=True`` kernels), restored on exit; nothing
    without numba."""
    try:
        import numba
    except ImportError:       # pragma: no cover - numba is optional
        yield
        return
    before = numba.get_num_threads()
    numba.set_num_threads(max(1, min(n, numba.config.NUMBA_NUM_THREADS)))
    try:
        yield
    finally:
        numba.set_num_threads(before)


def _step(step: str | None, ext: str = "", threads: int | str = 1,
          blas: bool = False) -> Callable[[Callable[..., Done]], Callable[..., Done]]:
    """Decorate a step ``fn(store, key, ...)``: run it under its thread policy (:func:`_threads` of ``threads``
    and ``blas``) and record the
    process's peak resident memory while it computes (``Done.peak_mb``, the run's per-step memory figures).

    With ``step``, a call whose output ``<step>/<key>[.<ext>]`` is stored only calls ``fn`` for its record,
    without setting threads or starting the memory sampler: a rerun of thousands of reused steps does not
    pay for them (measured: 5 ms per reused step on a loaded machine, most of a rerun's per-image time).
    ``step=None``: always under the policy (a step that checks its stored output itself).
    """
    from ..procmem import peak_rss_during, release_free_memory

    def decorate(fn: Callable[..., Done]) -> Callable[..., Done]:
        @functools.wraps(fn)
        def call(store: Store, key: str, *args: Any, **kwargs: Any) -> Done:
            if step is not None and store.has(step, key, ext):
                return fn(store, key, *args, **kwargs)
            with _threads(threads, blas), peak_rss_during(0.1) as memory:
                out = fn(store, key, *args, **kwargs)
            if isinstance(out, Done) and out.computed:
                out = replace(out, peak_mb=round(memory.peak_mb, 1))
                release_free_memory()      # what the step freed leaves the worker, not only its Python heap
            return out
        call.threads = threads      # type: ignore[attr-defined]
        return call
    return decorate


def provenance(config_digest: str, kernels: Sequence[str] = ()) -> dict[str, Any]:
    """Attributes recorded on every output Dataset: software version, configuration digest, kernels, time."""
    from .. import __version__

    return {"lunarmap_version": __version__, "config_sha256": config_digest,
            "kernels": ";".join(str(k) for k in kernels),
            "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}


def _fail(step: str, item: str, err: Exception) -> WorkflowError:
    from ..errors import DiskError

    if isinstance(err, DiskError):   # already names the path and what was written
        return err
    kind = type(err).__name__
    return WorkflowError(f"step {step} of {item or 'the block'} failed: {kind}: {err}")


def _stamp(path: str | Path) -> tuple[str, int, int]:
    st = Path(path).stat()
    return str(path), st.st_size, st.st_mtime_ns


def read_pixels(path: str | Path) -> xr.DataArray:
    """A whole raster as a ``(line, sample)`` DataArray, in memory: for small rasters, never for images
    (they are read by window: :func:`_windowed`); the run's DTM is read once per process as a height
    sampler (:func:`_dtm_sampler`).

    Read once per process (cached by path, size and modification time; at most 4 files).

    Raises
    ------
    WorkflowError
        Unreadable file or a variable that is not 2-D.
    """
    return _read_pixels(*_stamp(path))


@functools.lru_cache(maxsize=4)
def _read_pixels(path: str, size: int, mtime: int) -> xr.DataArray:
    p = Path(path)
    try:
        if p.suffix.lower() in (".nc", ".nc4", ".netcdf"):
            with xr.open_dataarray(p) as da:
                da = da.load()
        else:
            # ISIS cubes, PDS3 images, GeoTIFF (lunarmap.io): special pixels are NaN
            from ..io.raster import open_image

            da = open_image(p)
            if "band" in da.dims:
                if da.sizes["band"] != 1:
                    raise WorkflowError(f"image {p} has {da.sizes['band']} bands; give a single-band image")
                da = da.isel(band=0, drop=True)
            da = da.load()
    except (OSError, ValueError, LunarmapError) as err:
        if isinstance(err, WorkflowError):
            raise
        raise WorkflowError(f"image {p} is not readable: {type(err).__name__}: {err}") from None
    if da.ndim != 2:
        raise WorkflowError(f"image {p} must be 2-D (line, sample), got dims {da.dims}")
    return da


def _dtm_sampler(path: str | Path) -> tuple[Any, float]:
    """The run's DTM as one height sampler per process, and its mean height (metres).

    The matcher's cameras would each copy a DataArray into a sampler of their own (a full-size example's
    DTM is 177 MB: with the DataArray, three copies per pair); one shared sampler is one copy, and the
    DataArray is not kept.
    """
    return _dtm_sampler_cached(*_stamp(path))


@functools.lru_cache(maxsize=1)
def _dtm_sampler_cached(path: str, size: int, mtime: int) -> tuple[Any, float]:
    from ..camera.intersect import DtmSampler

    da = _read_pixels.__wrapped__(path, size, mtime)
    try:
        sampler = DtmSampler(da)
    except LunarmapError as err:
        raise WorkflowError(f"DTM {path}: {err}") from None
    del da
    return sampler, float(np.nanmean(sampler.z))


def altimetry_table(path: str | Path) -> Any:
    """A laser-altimetry shot table (:func:`lunarmap.io.read_altimetry`), read once per process (cached by path,
    size and modification time; at most 4 tables; its arrays read-only).

    The run reads its tables before any work, to name a bad one (:func:`lunarmap.workflows.run`); the
    adjust step of a serial run then finds them here instead of parsing them again.

    Raises
    ------
    AltimetryInputError
        As :func:`lunarmap.io.read_altimetry`.
    """
    try:
        stamp = _stamp(path)
    except OSError:
        from ..io.altimetry import read_altimetry

        return read_altimetry(path)      # names the missing table
    return _altimetry_of(*stamp)


@functools.lru_cache(maxsize=4)
def _altimetry_of(path: str, size: int, mtime: int) -> Any:
    from ..io.altimetry import read_altimetry

    shots = read_altimetry(path)
    for a in (shots.track, shots.time, shots.lon, shots.lat, shots.radius, shots.sigma):
        if a is not None:
            a.setflags(write=False)     # shared by every caller of this process
    return shots


# -- per image -------------------------------------------------------------------------------

@_step("isd", "json")
def isd_step(store: Store, key: str, name: str, label: str, metakernel: str) -> Done:
    """Image support data of one image (one SPICE pass), written as ISD JSON."""
    t = time.perf_counter()
    if store.has("isd", key, "json"):
        return Done("isd", key, name, str(store.path("isd", key, "json")), False)
    from ..orientation.drivers import image_support

    try:
        isd = image_support(label, metakernel)
    except LunarmapError as err:
        raise _fail("isd", name, err) from None
    path = store.write("isd", key, "json", lambda tmp: isd.write_json(tmp))
    return Done("isd", key, name, str(path), True, time.perf_counter() - t)


def _camera(isd: Done) -> Any:
    """The camera of a stored ISD (cached per process: a camera is immutable and used by many pairs)."""
    return _CAMERAS.get(*_stamp(isd.path))


class _CameraCache:
    """The cameras of a process, least recently used first out, bounded in bytes (:data:`CAMERA_CACHE_BYTES`).

    A match task's pairs (``a``, ``b_1`` ... ``b_k``) cycle through the other images of a site: with eight
    cameras per process most pairs built one of theirs again from its ISD (11 ms of a 48-image run's
    ~190 ms per pair). A full-size line scanner's lookup table is ~29 MB (576 bytes per line, built on
    first use), a small image's camera tens of kB: counted by size, the cache holds a full-size block's
    eight cameras as before and a long run's small cameras all.
    """

    def __init__(self, max_bytes: int) -> None:
        from collections import OrderedDict

        self.max_bytes = int(max_bytes)
        self.entries: "OrderedDict[tuple[str, int, int], tuple[Any, int]]" = OrderedDict()
        self.nbytes = 0
        self.lock = threading.Lock()

    def get(self, path: str, size: int, mtime: int) -> Any:
        key = (path, size, mtime)
        with self.lock:
            hit = self.entries.get(key)
            if hit is not None:
                self.entries.move_to_end(key)
                return hit[0]
        from ..camera.factory import camera_from_isd_file

        cam = camera_from_isd_file(path)
        # the ISD's arrays (about its file's size) and a line scanner's per-line table (576 bytes a line)
        cost = int(size) + 576 * int(getattr(cam, "n_lines", 0))
        with self.lock:
            if key not in self.entries:
                self.entries[key] = (cam, cost)
                self.nbytes += cost
                while self.nbytes > self.max_bytes and len(self.entries) > 1:
                    _, (_, c) = self.entries.popitem(last=False)
                    self.nbytes -= c
        return cam

    def clear(self) -> None:
        with self.lock:
            self.entries.clear()
            self.nbytes = 0


#: Bytes of cameras a process keeps (estimated: :class:`_CameraCache`): eight full-size NAC-like cameras.
CAMERA_CACHE_BYTES = 256 << 20
_CAMERAS = _CameraCache(CAMERA_CACHE_BYTES)


@_step("rpc", "nc")
def rpc_step(store: Store, key: str, isd: Done, height_range: tuple[float, float]) -> Done:
    """The cubic RFM of an image's camera, with its independent check report (netCDF)."""
    t = time.perf_counter()
    if store.has("rpc", key, "nc"):
        return Done("rpc", key, isd.item, str(store.path("rpc", key, "nc")), False)
    from ..rpc import fit_rpc, write_netcdf

    try:
        lo, hi = height_range
        fit = fit_rpc(_camera(isd), (lo, hi))
    except LunarmapError as err:
        raise _fail("rpc", isd.item, err) from None
    path = store.write("rpc", key, "nc", lambda tmp: write_netcdf(fit.model, tmp))
    remember_rfm(path, fit.model)
    assert fit.check is not None        # fit_rpc checks by default
    return Done("rpc", key, isd.item, str(path), True, time.perf_counter() - t,
                note=f"check RMS {fit.check.rms:.2e} px")


@_step("rpc_adjusted", "nc")
def adjusted_rpc_step(store: Store, key: str, name: str, adjusted: Done, height_range: tuple[float, float]) -> Done:
    """The cubic RFM of an image's *adjusted* camera (from the adjustment's ISD), with its check report.

    One task per image after the adjustment, so a large run fits them in parallel like the first RFMs.
    """
    t = time.perf_counter()
    if store.has("rpc_adjusted", key, "nc"):
        return Done("rpc_adjusted", key, name, str(store.path("rpc_adjusted", key, "nc")), False)
    from ..camera.factory import camera_from_isd_file
    from ..rpc import fit_rpc, write_netcdf

    try:
        lo, hi = height_range
        fit = fit_rpc(camera_from_isd_file(Path(adjusted.path) / f"{name}.adjusted.json"), (lo, hi))
    except LunarmapError as err:
        raise _fail("rpc_adjusted", name, err) from None
    path = store.write("rpc_adjusted", key, "nc", lambda tmp: write_netcdf(fit.model, tmp))
    remember_rfm(path, fit.model)
    assert fit.check is not None        # fit_rpc checks by default
    return Done("rpc_adjusted", key, name, str(path), True, time.perf_counter() - t,
                note=f"check RMS {fit.check.rms:.2e} px")


def _tiles_by_row(shape: tuple[int, int], tile: int, halo: int) -> list[list[tuple[tuple[int, int, int, int],
                                                                               tuple[int, int, int, int]]]]:
    """The image's detection tiles, grouped by row of tiles (one stripe read serves a row)."""
    from ..matching.tiepoints import tile_windows

    rows: dict[int, list[Any]] = {}
    for core, pad in tile_windows(shape, tile, halo):
        rows.setdefault(core[0], []).append((core, pad))
    return list(rows.values())


@dataclass
class BatchDone:
    """Records of a batch of steps and the manifest rows of the output files the batch wrote."""

    records: list[Done]
    exported: Exported | None = None


def adjusted_rpc_batch(store: Store, jobs: Sequence[tuple[str, str]], adjusted: Done,
                       height_range: tuple[float, float], outputs: Outputs | None = None) -> BatchDone:
    """:func:`adjusted_rpc_step` of several images ``(key, name)`` in one task; with ``outputs``, their RFMs
    are also written to ``outputs/rpc_adjusted`` (netCDF and ``_RPC.TXT``) by this task."""
    records = [adjusted_rpc_step(store, k, n, adjusted, height_range) for k, n in jobs]
    return BatchDone(records, export_rpcs(outputs, records, "rpc_adjusted") if outputs is not None else None)


@_step("detect", "npz")
def detect_step(store: Store, key: str, name: str, pixels: str, params: Any, saturation: float | None) -> Done:
    """Förstner interest points of a whole image, tile by tile (``.npz``).

    The image is read a stripe of one row of tiles (plus the halo) at a time, so memory does not grow
    with the image's length; the points are those of :func:`~lunarmap.matching.tiepoints.detect_tile`
    on each tile's padded window.
    """
    t = time.perf_counter()
    if store.has("detect", key, "npz"):
        return Done("detect", key, name, str(store.path("detect", key, "npz")), False)
    import warnings

    from ..matching.tiepoints import detect_tile, merge_points

    src = _source(pixels)
    halo = params.border + params.window + params.nms
    parts = []
    try:
        for row in _tiles_by_row(src.shape, params.tile, halo):
            p0, p1 = row[0][1][0], row[0][1][1]
            stripe = src.read(p0, p1, 0, src.shape[1])
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")          # blank tiles are expected at rolled images' edges
                for core, pad in row:
                    parts.append(detect_tile(stripe[:, pad[2]:pad[3]], core, pad, params, saturation, name))
    except LunarmapError as err:
        raise _fail("detect", name, err) from None
    pts = merge_points(parts)
    path = store.write("detect", key, "npz", lambda tmp: _savez(tmp, line=pts.line, sample=pts.sample,
                                                                  strength=pts.strength))
    return Done("detect", key, name, str(path), True, time.perf_counter() - t, note=f"{pts.line.size} points")


@_step(None)      # checks its stored pyramid itself (a damaged one is computed again)
def pyramid_step(store: Store, key: str, name: str, pixels: str, levels: int, saturation: float | None,
                 digest: str) -> Done:
    """An image's pyramid levels, computed once and stored chunked (:func:`lunarmap.io.pyramid.write_pyramid`)."""
    t = time.perf_counter()
    if store.has("pyramid", key, "nc"):
        from ..errors import PyramidError
        from ..io.pyramid import Pyramid

        path = store.path("pyramid", key, "nc")
        try:
            Pyramid(path, digest=digest)
            return Done("pyramid", key, name, str(path), False)
        except PyramidError as err:
            _log.warning("%s: recomputing the pyramid: %s", name, err)
            from .store import remove_entry

            remove_entry(path)
    from ..io.pyramid import write_pyramid

    final = store.path("pyramid", key, "nc")
    final.parent.mkdir(parents=True, exist_ok=True)
    try:
        from ..atomic import disk_guard

        with disk_guard(final, f"the pyramid of {name}"):
            path = write_pyramid(_source(pixels), final, levels, saturation, digest=digest)
        store.seal("pyramid", key, "nc")
    except LunarmapError as err:
        raise _fail("pyramid", name, err) from None
    return Done("pyramid", key, name, str(path), True, time.perf_counter() - t)


def _savez(path: Path, **arrays: Any) -> None:
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)


def _load_points(detect: Done) -> Any:
    from ..matching.interest import InterestPoints

    with np.load(detect.path) as z:
        return InterestPoints(z["line"], z["sample"], z["strength"])


def _source(pixels: str) -> Any:
    """The window source of an image file (cached per process by path, size and modification time)."""
    return _source_of(*_stamp(pixels))


@functools.lru_cache(maxsize=256)
def _source_of(path: str, size: int, mtime: int) -> Any:
    from ..io.window import PixelSource

    try:
        return PixelSource(path)
    except LunarmapError as err:
        raise WorkflowError(f"image {path} is not readable: {err}") from None


def _windowed(store: Store, name: str, pixels: str, digest: str, params: Any, pyramid: Done | None) -> Any:
    """The image as the matcher reads it: by window, with its stored pyramid (cached per process; the
    cached objects hold no pixels, the region cache of :mod:`lunarmap.matching.windowed` is bounded in bytes).

    A pyramid store that went missing or was damaged since its step ran is computed again (logged).
    """
    from ..errors import PyramidError

    sat = params.match.saturation
    if pyramid is None:
        return _windowed_of(*_stamp(pixels), sat, None, 0, 0)
    try:
        return _windowed_of(*_stamp(pixels), sat, *_stamp(pyramid.path))
    except (OSError, PyramidError) as err:
        _log.warning("%s: computing its pyramid again: %s", name, err)
        Path(pyramid.path).unlink(missing_ok=True)
        _windowed_of.cache_clear()
        again = pyramid_step(store, pyramid.key, name, pixels, params.match.pyramid_levels, sat, digest)
        return _windowed_of(*_stamp(pixels), sat, *_stamp(again.path))


@functools.lru_cache(maxsize=64)
def _windowed_of(path: str, size: int, mtime: int, saturation: float | None, pyramid: str | None,
                 pyramid_size: int, pyramid_mtime: int) -> Any:
    from ..io.pyramid import Pyramid
    from ..matching.windowed import WindowedImage

    src = _source_of(path, size, mtime)
    return WindowedImage(src, saturation, pyramid=Pyramid(pyramid, shape=src.shape) if pyramid else None)


def _overlap(cam_a: Any, cam_b: Any, height: float) -> float:
    """Fraction of an 11 x 11 grid of image ``a`` (at ``height`` metres) that image ``b`` sees."""
    L, S = np.meshgrid(np.linspace(0.5, cam_a.n_lines - 0.5, 11), np.linspace(0.5, cam_a.n_samples - 0.5, 11),
                       indexing="ij")
    g = cam_a.image_to_ground(L.ravel(), S.ravel(), height=height, on_miss="nan")
    ok = np.all(np.isfinite(g), axis=1)
    if not ok.any():
        return 0.0
    li, sa = cam_b.ground_to_image(g[ok], on_miss="nan")
    return float(np.count_nonzero(np.isfinite(li) & np.isfinite(sa))) / L.size


def footprint_step(store: Store, key: str, isd: Done, heights: tuple[float, ...]) -> list[Any] | None:
    """An image's footprints at the given heights (metres), for choosing the pairs to match; ``None`` when
    its border misses the Moon (the image is then paired with every other). Stored (``.npz``), so a rerun
    does not rebuild the camera."""
    from ..errors import NoOverlapError
    from ..evaluate.footprint import Footprint, footprint

    if store.has("footprint", key, "npz"):
        with np.load(store.path("footprint", key, "npz")) as z:
            if not bool(z["seen"]):
                return None
            return [Footprint(np.array(z["xyz"][k]), float(z["radius"][k]), float(z["height"][k]))
                    for k in range(z["xyz"].shape[0])]
    cam = _camera(isd)
    try:
        feet: list[Any] | None = [footprint(cam, height=float(h), per_side=8, name=isd.item) for h in heights]
    except NoOverlapError:
        feet = None
    arrays = ({"seen": np.array(False)} if feet is None else
              {"seen": np.array(True), "xyz": np.stack([f.xyz for f in feet]),
               "radius": np.array([f.radius for f in feet]), "height": np.array([f.height for f in feet])})
    store.write("footprint", key, "npz", lambda tmp: _savez(tmp, **arrays))
    return feet


@dataclass(frozen=True)
class ImageJob:
    """Everything the per-image steps of one image need (keys computed by the engine)."""

    name: str
    label: str
    pixels: str
    digest: str
    isd_key: str
    footprint_key: str
    rpc_key: str | None
    pyramid_key: str
    detect_key: str


@dataclass
class ImageDone:
    """The per-image steps' records, the image's footprints and the manifest rows of the output files its
    task wrote (or found fresh) in the run's ``outputs`` folder."""

    records: list[Done]
    footprints: list[Any] | None
    exported: Exported | None = None

    def get(self, step: str) -> Done | None:
        return next((d for d in self.records if d.step == step), None)


def image_steps(store: Store, job: ImageJob, metakernel: str, heights: tuple[float, ...],
                rpc_height_range: tuple[float, float] | None, detect: Any, pyramid_levels: int,
                saturation: float | None, outputs: Outputs | None = None) -> ImageDone:
    """One task per image: its ISD, footprints, RFM, pyramid and interest points, each stored under its own
    key (a rerun or a resumed run computes only the missing ones); with ``outputs``, also the image's files
    of the run's outputs folder (its ISD and RFM: :func:`lunarmap.workflows.outputs.export_image`), on the
    worker that ran it, not after the graph."""
    isd = isd_step(store, job.isd_key, job.name, job.label, metakernel)
    stored = all(store.has(*k) for k in (("footprint", job.footprint_key, "npz"), ("pyramid", job.pyramid_key, "nc"),
                                         ("detect", job.detect_key, "npz")))
    if not stored:      # before any pixel work (a rerun of stored steps does not build the camera for it)
        cam, src = _camera(isd), _source(job.pixels)
        if tuple(src.shape) != (int(cam.n_lines), int(cam.n_samples)):
            raise WorkflowError(f"image {job.name}: its pixels {job.pixels} are {src.shape[0]} x {src.shape[1]}, its "
                                f"label {job.label} says {int(cam.n_lines)} x {int(cam.n_samples)} (lines x samples)")
    feet = footprint_step(store, job.footprint_key, isd, heights)
    records = [isd]
    if job.rpc_key is not None and rpc_height_range is not None:
        records.append(rpc_step(store, job.rpc_key, isd, rpc_height_range))
    records.append(pyramid_step(store, job.pyramid_key, job.name, job.pixels, pyramid_levels, saturation, job.digest))
    records.append(detect_step(store, job.detect_key, job.name, job.pixels, detect, saturation))
    return ImageDone(records, feet, export_image(outputs, records) if outputs is not None else None)


@dataclass(frozen=True)
class MatchJob:
    """One pair of a match batch: its key, names, pixel files and the upstream records it reads."""

    key: str
    pair: tuple[str, str]
    pixels: tuple[str, str]
    isds: tuple[Done, Done]
    pyramids: tuple[Done, Done]
    points: Done
    digests: tuple[str, str] = ("", "")


def match_batch(store: Store, jobs: Sequence[MatchJob], dtm: str | None, params: Any,
                min_overlap: float) -> list[Done]:
    """Several pairs in one task (the graph stays small: about one match task per image)."""
    return [match_step(store, j.key, j.pair, j.pixels, j.isds, j.pyramids, j.points, dtm, params, min_overlap,
                       j.digests) for j in jobs]


@_step("match", "npz")
def match_step(store: Store, key: str, pair: tuple[str, str], pixels: tuple[str, str], isds: tuple[Done, Done],
               pyramids: tuple[Done | None, Done | None], points: Done, dtm: str | None, params: Any,
               min_overlap: float, digests: tuple[str, str] = ("", "")) -> Done:
    """Matches of one image pair (prediction, pyramid NCC, LSM, RANSAC), or a skip when they do not overlap.

    Both images are read by window through their stored pyramids (:mod:`lunarmap.matching.windowed`):
    never a whole image in memory.
    """
    t = time.perf_counter()
    item = f"{pair[0]} -> {pair[1]}"
    if store.has("match", key, "npz"):
        path = store.path("match", key, "npz")
        with np.load(path) as z:
            note = str(z["note"])
        return Done("match", key, item, str(path), False, note=note)
    import warnings

    from ..matching.tiepoints import match_pair

    cam_a, cam_b = _camera(isds[0]), _camera(isds[1])
    height: Any = 0.0
    mean_h = 0.0
    if dtm is not None:
        height, mean_h = _dtm_sampler(dtm)
    frac = _overlap(cam_a, cam_b, mean_h)
    if frac < min_overlap:
        note = f"skipped: {frac:.0%} of {pair[0]} is seen by {pair[1]} (< {min_overlap:.0%})"
        path = store.write("match", key, "npz", lambda tmp: _savez(tmp, note=np.array(note), n=np.array(0)))
        return Done("match", key, item, str(path), True, time.perf_counter() - t, note)
    try:
        img_a = _windowed(store, pair[0], pixels[0], digests[0], params, pyramids[0])
        img_b = _windowed(store, pair[1], pixels[1], digests[1], params, pyramids[1])
        pts = _load_points(points)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m = match_pair(img_a, img_b, cam_a, cam_b, pts, height, params, item)
    except LunarmapError as err:
        raise _fail("match", item, err) from None
    ok = m.ok
    thinned = f", thinned from {ok.size}" if m.meta.get("thinned") else ""
    note = f"{int(ok.sum())}/{ok.size - int(m.meta.get('thinned', 0))} matched ({frac:.0%} overlap{thinned})"
    arrays = {"line1": m.line1[ok], "sample1": m.sample1[ok], "line2": m.line2[ok], "sample2": m.sample2[ok],
              "sigma_line": m.sigma_line[ok], "sigma_sample": m.sigma_sample[ok],
              "correlation": m.correlation[ok], "index": np.flatnonzero(ok), "n_points": np.array(ok.size),
              "note": np.array(note), "n": np.array(int(ok.sum()))}
    path = store.write("match", key, "npz", lambda tmp: _savez(tmp, **arrays))
    return Done("match", key, item, str(path), True, time.perf_counter() - t, note)


@_step("tiepoints", "nc")
def tiepoints_step(store: Store, key: str, names: Sequence[str], pairs: Sequence[tuple[str, str]],
                   matches: Sequence[Done], track_tol: float, attrs: dict[str, Any]) -> Done:
    """Multi-image tracks of all pairs' matches: the tie-point table (netCDF).

    Pairs are read one at a time and only their matched rows are kept (:class:`~lunarmap.matching.tiepoints.TrackRows`).
    """
    t = time.perf_counter()
    if store.has("tiepoints", key, "nc"):
        return Done("tiepoints", key, "", str(store.path("tiepoints", key, "nc")), False)
    from ..matching.tiepoints import TrackRows, write_tiepoints

    index = {n: k for k, n in enumerate(names)}
    rows = TrackRows()
    for (a, b), d in zip(pairs, matches):
        with np.load(d.path) as z:
            if int(z["n"]) == 0:
                continue
            rows.add(index[a], index[b], z["index"], z["line1"], z["sample1"], z["line2"], z["sample2"],
                     z["sigma_line"], z["sigma_sample"], z["correlation"], n_points=int(z["n_points"]))
    if not rows.n_pairs:
        raise WorkflowError("tie points: no image pair overlaps (every pair was skipped or matched nothing)")
    ds = rows.table(list(names), track_tol)
    ds.attrs.update(attrs)
    path = store.write("tiepoints", key, "nc", lambda tmp: write_tiepoints(ds, tmp))
    return Done("tiepoints", key, "", str(path), True, time.perf_counter() - t,
                note=f"{int(np.unique(ds['point_id'].values).size)} points, {ds.sizes['observation']} observations")


# -- the block -------------------------------------------------------------------------------

@_step("adjust", threads=ALL)     # a barrier of the graph: nothing runs beside it
def adjust_step(store: Store, key: str, names: Sequence[str], groups: Sequence[str], isds: Sequence[Done],
                ties: Done, points: str | None, degree: int, navigation: dict[str, Any] | None,
                estimate_tie_variance: bool, ftol: float, attrs: dict[str, Any],
                qc: dict[str, Any] | None = None, other_images: str = "error",
                terrain: Sequence[dict[str, Any]] | None = None, jitter: dict[str, Any] | None = None,
                altimetry: Sequence[dict[str, Any]] | None = None) -> Done:
    """Adjust the block on the images' rigorous cameras; write the results as netCDF and adjusted ISDs.

    With ``qc`` (the fields of :class:`~lunarmap.workflows.config.QCConfig`) the adjustment is quality
    controlled (:func:`lunarmap.adjust.quality_control`, image groups = the images' navigation groups); the
    report is written as ``qc.nc`` and ``qc.txt``. The tie points' variance factor is then estimated on
    what quality control kept, unless its ``variance`` step estimated every group's. With
    ``other_images="ignore"`` the points' measures in images not in ``names`` are dropped
    (:func:`lunarmap.workflows.checks.restrict_network`).

    ``terrain`` (the fields of :class:`~lunarmap.workflows.config.TerrainDtmConfig`, one dict per DTM):
    reference DTM heights observe the tie points inside each DTM (:mod:`lunarmap.adjust.terrain`), one
    observation group ``"terrain <name>"`` each (variance component, w-tests); the summary's ``terrain``
    section and ``terrain_residuals.nc`` report them. A DTM without a Moon CRS or covering no tie point
    raises its own error (:class:`~lunarmap.errors.DtmCrsError`, :class:`~lunarmap.errors.DtmCoverageError`),
    and nothing of the step is written.

    ``jitter`` (the fields of :class:`~lunarmap.workflows.config.JitterConfig`): the line-scan images get a
    cubic B-spline attitude correction with its smoothness prior (:class:`~lunarmap.adjust.JitterSpec`), the
    prior an observation group ``"jitter smoothness"``; the adjusted ISDs then carry the spline's attitude.
    ``altimetry`` (the fields of :class:`~lunarmap.workflows.config.TerrainAltimetryConfig`, one dict per
    altimeter): laser-altimetry shots observe the tie points' triangulated surface, with an offset (and
    drift) per track (:mod:`lunarmap.adjust.altimetry`), one group ``"altimetry <name>"`` each; the summary's
    ``altimetry`` section reports its tracks' offsets with their sigma and its residual RMS. A bad shot table
    or one missing the block raises :class:`~lunarmap.errors.AltimetryInputError` /
    :class:`~lunarmap.errors.AltimetryCoverageError`.
    """
    t = time.perf_counter()
    if store.has("adjust", key):
        return Done("adjust", key, "", str(store.path("adjust", key)), False)
    from ..adjust import (
        NavigationSpec,
        SolverOptions,
        build_block,
        merge_networks,
        network_from_tiepoints,
        read_network,
    )
    from ..adjust.altimetry import LaserAltimetry
    from ..adjust.block import Block, BlockResult
    from ..adjust.export import adjusted_image_support
    from ..adjust.terrain import ReferenceDtm
    from ..adjust.variance import estimate_image_variances
    from ..camera.factory import camera_from_isd
    from ..errors import TerrainInputError
    from ..matching.tiepoints import read_tiepoints
    from ..orientation.isd import ImageSupport
    from ..procmem import peak_rss_during

    # the step's own peak memory, sampled while it runs, goes into summary.json
    with peak_rss_during() as memory:
        try:
            # each ISD read once, for its camera and for its adjusted copy (a 192-image block read them twice:
            # 0.1-0.2 s each, most of it checking the arrays)
            supports = {n: ImageSupport.read_json(d.path) for n, d in zip(names, isds)}
            cams = {n: camera_from_isd(supports[n]) for n in names}
            net = network_from_tiepoints(read_tiepoints(ties.path))
            if points is not None:
                pts_net = read_network(points)
                if other_images == "ignore":
                    from .checks import restrict_network

                    pts_net = restrict_network(pts_net, names)[0]
                net = merge_networks(net, pts_net)
            spec = None
            if navigation is not None:
                spec = NavigationSpec(orbit={n: g or n for n, g in zip(names, groups)}, **navigation)
            refs = [ReferenceDtm(d["path"], d["sigma"], name=f"terrain {d['name']}",
                                 slope_baseline_m=d.get("slope_baseline")) for d in terrain or ()]
            jspec = None
            if jitter is not None:
                from ..adjust.jitter import JitterSpec

                jspec = JitterSpec(jitter["knot_lines"], jitter["sigma"], jitter.get("zero_sigma"),
                                   jitter.get("images"))
            alts = [LaserAltimetry(altimetry_table(a["path"]), a["sigma"], interpolation_sigma_m=a.get("interpolation_sigma", 0.0),
                                   offset_sigma_m=a.get("offset_sigma"), drift=bool(a.get("drift", False)),
                                   name=f"altimetry {a['name']}") for a in altimetry or ()]
            block = build_block(cams, net, degree=degree, navigation=spec, terrain=refs, jitter=jspec, altimetry=alts)
            for a, alt_term in zip(altimetry or (), block.altimetry):
                _log.info("adjust: altimeter %s: %d shots on %d tracks observed, %d outside the tie points",
                          a["name"], alt_term.n_shots, alt_term.n_tracks, alt_term.skipped)
            for d, term in zip(terrain or (), block.terrain):
                _log.info("adjust: reference DTM %s: %d tie point heights observed (sigma %.3g m), %d outside it",
                          d["name"], term.n_obs_scalar, term.sigma, term.skipped)
            _log.info("adjust: block of %d images, %d points, %d image observations%s", len(names),
                      block.problem.n_points, block.problem.obs.n,
                      f", quality control {' -> '.join(qc['steps'])}" if qc is not None and qc["steps"] else "")
            x0 = block.problem.points.copy()
            opts = SolverOptions(ftol=ftol, progress=2.0)    # an iteration line at most every 2 s
            qc_out = None
            problem = block.problem
            if qc is not None and qc["steps"]:
                qc_out = _quality_control(block, names, groups, qc, opts)
                problem = qc_out.problem
            groups_obs = np.where(block.network.point_type[problem.obs.pt_idx] == "tie", 0, 1)
            tie_variance = estimate_tie_variance and not (qc_out is not None and qc is not None
                                                          and "variance" in qc["steps"])
            if qc_out is not None and not tie_variance:
                est = None
                result = qc_out.result
            else:
                # without control or check points the tie points are the only group (a second, empty
                # group would have no redundancy)
                both = bool(np.any(groups_obs == 1))
                est = estimate_image_variances(problem, groups_obs, np.array([tie_variance, False][:1 + both]), opts,
                                               rounds=5 if tie_variance else 1)
                result = est.result
            res = BlockResult(Block(block.names, block.model, block.network, result.problem, block.navigation), result)
            _log.info("adjust: sigma0 %.4f after %d iterations; writing adjusted ISDs, posterior precision, "
                      "check points", res.sigma0, int(res.result.iterations))
            adjusted_isds = adjusted_image_support(res, supports)
        except TerrainInputError:
            raise           # named as it is (DtmCrsError, DtmCoverageError): the DTM is the user's to fix
        except LunarmapError as err:
            raise _fail("adjust", "", err) from None

        quad = res.result.group_quadratic_forms()
        summary: dict[str, Any] = {"sigma0": res.sigma0, "iterations": int(res.result.iterations), "converged": bool(res.converged),
                                   "message": res.result.message, "tie_sigma_scale": float(est.scale[0]) if est is not None else 1.0,
                                   "variance_factors": [h.tolist() for h in est.history] if est is not None else [], "images": list(names),
                                   "n_points": int(block.problem.n_points), "n_observations": int(block.problem.obs.n),
                                   "groups": {k: list(v) for k, v in quad.items()},
                                   # per observation group, sqrt(v'Pv / n): the RMS of residual / a-priori sigma
                                   "group_normalized_rms": {k: float(np.sqrt(q / n)) if n else float("nan")
                                                            for k, (q, n) in quad.items()},
                                   "rms_px": res.result.rms_px(), "solve_seconds": float(res.result.solve_seconds)}
        check_res = res
        if qc_out is not None:
            summary["qc"] = _qc_summary(qc_out, block, names)
            # a check point that quality control left with fewer than 2 rays is not adjusted: it is reported, not scored
            rays = np.bincount(block.problem.obs.pt_idx[qc_out.ledger.active], minlength=block.problem.n_points)
            lost = (block.network.point_type == "check") & (rays < 2)
            if lost.any():
                summary["qc"]["check_points_without_rays"] = block.network.point_id[lost].astype(str).tolist()
                net_eval = replace(block.network, point_type=np.where(lost, "tie", block.network.point_type))
                check_res = BlockResult(Block(block.names, block.model, net_eval, result.problem, block.navigation), result)
        has_check = bool(np.any(check_res.block.network.point_type == "check"))
        terrain_ds = None
        if block.terrain:
            summary["terrain"], terrain_ds = _terrain_outputs(block, res, qc_out, est, list(terrain or ()))
        if block.altimetry:
            summary["altimetry"] = _altimetry_outputs(block, res, qc_out, list(altimetry or ()))
        if jspec is not None:
            from ..evaluate.jitter import jitter_spectra

            # the adjusted splines' attitude correction per image and axis: RMS, posterior sigma, spectrum
            summary["jitter"] = jitter_spectra(block.model, res.result.cam_params, res.result.precision().cam_cov,
                                               names)

        def write(folder: Path) -> None:
            geo = {"crs": MOON_GEOGRAPHIC_CRS, **attrs}
            corr = res.corrections()
            corr.attrs.update(attrs)
            corr.to_netcdf(folder / "corrections.nc")
            pts = res.points()
            pts.attrs.update(geo)
            pts["lon"].attrs["standard_name"], pts["lat"].attrs["standard_name"] = "longitude", "latitude"
            pts.to_netcdf(folder / "points.nc")
            resid = res.result.residuals_dataset()
            resid["image_name"] = ("obs", np.asarray(names, dtype=object)[resid["image"].values])
            resid["point_type"] = ("obs", block.network.point_type[resid["point"].values].astype(object))
            resid["point_id"] = ("obs", block.network.point_id[resid["point"].values].astype(object))
            # the measured image coordinates (line, sample), e.g. to compare with a simulation's truth
            resid["observed"] = (("obs", "coord"), np.asarray(res.result.problem.obs.xy, float))
            if qc_out is not None:
                status = qc_out.image_status()
                resid["qc_status"] = ("obs", status)
                resid["qc_removed"] = ("obs", status != "in")
                qc_out.report.write(folder / "qc.nc")
                (folder / "qc.txt").write_text(qc_out.report.table() + "\n")
            resid.attrs.update(attrs)
            resid.to_netcdf(folder / "residuals.nc")
            if terrain_ds is not None:
                terrain_ds.attrs.update(attrs)
                terrain_ds.to_netcdf(folder / "terrain_residuals.nc")
            if has_check:
                from ..evaluate import block_check_errors

                before, after = block_check_errors(check_res, x0), block_check_errors(check_res)
                ds = xr.Dataset({"error_before": before["error"], "error_after": after["error"],
                                 "sigma_after": after["sigma"], "normalized_after": after["normalized"],
                                 "error_enu_before": before["error_enu"], "error_enu_after": after["error_enu"],
                                 "sigma_enu_after": after["sigma_enu"]},
                                attrs={**geo, "components": "along-track, cross-track, height (m)",
                                       "along_track_azimuth_deg": after.attrs["along_track_azimuth"],
                                       "rms_before_m": before.attrs["rms"], "rms_after_m": after.attrs["rms"],
                                       "normalized_rms": after.attrs["normalized_rms"]})
                ds.to_netcdf(folder / "check_points.nc")
                summary["check_rms_before_m"] = np.asarray(before.attrs["rms"]).tolist()
                summary["check_rms_after_m"] = np.asarray(after.attrs["rms"]).tolist()
                summary["check_sigma_after_m"] = np.asarray(after.attrs["expected_rms"]).tolist()
                summary["check_normalized_rms"] = float(after.attrs["normalized_rms"])
                summary["check_components"] = ["along-track", "cross-track", "height"]
            for n, isd in adjusted_isds.items():
                isd.write_json(folder / f"{n}.adjusted.json")
            summary["memory"] = {"rss_start_mb": memory.start_mb, "peak_mb": memory.peak_mb,
                                 "bytes_per_observation": memory.added_mb * 2 ** 20 / max(1, block.problem.obs.n)}
            (folder / "summary.json").write_text(json.dumps(summary, indent=1))

        path = store.write_dir("adjust", key, write)
        return Done("adjust", key, "", str(path), True, time.perf_counter() - t,
                    note=f"sigma0 {summary['sigma0']:.3f}")


def _altimetry_outputs(block: Any, res: Any, qc_out: Any, altimetry: list[dict[str, Any]]) -> dict[str, Any]:
    """The summary's ``altimetry`` section: per altimeter its shots (observed, outside the tie points,
    down-weighted by quality control), the RMS of the final shot residuals (metres), its group's sigma scale
    and, per track, the estimated offset (and drift) with its posterior sigma."""
    base_terms = list(block.problem.terms)
    result = res.result
    prec = result.precision()
    weights = qc_out.ledger.weights if qc_out is not None else None
    vc = qc_out.variance if qc_out is not None else None
    section: dict[str, Any] = {}
    for a, term in zip(altimetry, block.altimetry):
        t = next(i for i, x in enumerate(base_terms) if x is term)
        s0 = sum(x.n_extra for x in base_terms[:t])
        extra = np.asarray(result.state.extra[s0:s0 + term.n_extra], float)
        sig = np.sqrt(np.clip(np.diag(prec.extra_cov)[s0:s0 + term.n_extra], 0.0, None))
        r = np.asarray(term.residuals_m(result.points, extra), float)
        down = np.zeros(term.n_obs_scalar, bool) if weights is None else np.asarray(weights.term_downweighted(t), bool)
        ok = ~down[:term.n_shots]
        scale = 1.0
        if vc is not None and term.name in vc.names:
            scale = float(vc.scale[vc.names.index(term.name)])
        tracks = {str(n): {"offset_m": float(extra[k]), "offset_sigma_m": float(sig[k]),
                           **({"drift_m_per_s": float(extra[term.n_tracks + k]),
                               "drift_sigma_m_per_s": float(sig[term.n_tracks + k])} if term.drift else {}),
                           "shots": int(np.sum(term.track_of == k))}
                  for k, n in enumerate(term.track_names)}
        section[a["name"]] = {
            "group": term.name, "shots": int(term.n_shots), "outside_tie_points": int(term.skipped),
            "dropped_tracks": int(term.dropped_tracks), "downweighted": int(down.sum()),
            "rms_residual_m": float(np.sqrt(np.mean(r[ok] ** 2))) if ok.any() else float("nan"),
            "sigma_apriori_m": float(a["sigma"]), "interpolation_sigma_m": float(a.get("interpolation_sigma", 0.0)),
            "sigma_scale": scale, "tracks": tracks}
    return section


def _terrain_outputs(block: Any, res: Any, qc_out: Any, est: Any,
                     terrain: list[dict[str, Any]]) -> tuple[dict[str, Any], xr.Dataset]:
    """The summary's ``terrain`` section and ``terrain_residuals.nc`` of a block with reference DTMs.

    Per DTM: observations, RMS of the final residuals (point height minus DTM height, metres), its group's
    sigma scale (the square root of its variance component: the a-priori sigma times it is the estimated
    sigma of one DTM height) with its standard deviation, and the rows quality control down-weighted.
    Per observation: point id, DTM name, residual (metres), normalised residual (residual over the row's
    final sigma: a-priori sigma x sigma scale x down-weighting) and status (``"in"``, ``"down-weighted"``,
    ``"point out"`` when quality control took its point out, ``"lost"`` when the point left the DTM).
    """
    base_terms = list(block.problem.terms)
    points = np.asarray(res.result.points, float)
    weights = qc_out.ledger.weights if qc_out is not None else None
    vc = qc_out.variance if qc_out is not None else None
    section: dict[str, Any] = {}
    cols: dict[str, list[Any]] = {k: [] for k in ("point_id", "dtm", "residual", "normalized", "status")}
    for d, term in zip(terrain, block.terrain):
        t = next(i for i, x in enumerate(base_terms) if x is term)
        r = np.asarray(term.residuals_m(points), float)
        factor = np.ones(r.size) if weights is None else np.asarray(weights.term_sigma[t], float)
        down = np.zeros(r.size, bool) if weights is None else np.asarray(weights.term_downweighted(t), bool)
        # out with its point: the rule the QC status table uses (Weights.term_rows_out)
        out_pt = np.zeros(r.size, bool) if weights is None else weights.term_rows_out(term)
        status = np.where(~np.isfinite(r), "lost", np.where(out_pt, "point out", np.where(down, "down-weighted", "in")))
        scale, scale_sd, estimated = 1.0, float("nan"), False
        if vc is not None and term.name in vc.names:
            j = vc.names.index(term.name)
            estimated = bool(vc.estimated[j])
            scale = float(vc.scale[j])
            joint = vc.scale_sigma_joint
            scale_sd = float(joint[j]) if joint is not None and np.isfinite(joint[j]) else float(vc.scale_sigma[j])
        ok = status == "in"
        section[d["name"]] = {
            "group": term.name, "observations": int(r.size), "outside_dtm": int(term.skipped),
            "rms_residual_m": float(np.sqrt(np.mean(r[ok] ** 2))) if ok.any() else float("nan"),
            "sigma_apriori_m": float(term.sigma), "variance_component_estimated": estimated,
            "sigma_scale": scale, "sigma_scale_sd": scale_sd,
            "variance_component": scale ** 2,
            "sigma_estimated_m": float(term.sigma * scale), "sigma_estimated_sd_m": float(term.sigma * scale_sd),
            "removed": int(np.sum(status != "in")), "downweighted": int(down.sum()),
            "slope_baseline_m": d.get("slope_baseline"),
        }
        ids = term.point_ids if term.point_ids is not None else block.network.point_id[term.point_index]
        cols["point_id"] += [str(x) for x in ids]
        cols["dtm"] += [d["name"]] * r.size
        cols["residual"] += r.tolist()
        cols["normalized"] += (r / (term.sigma * factor)).tolist()
        cols["status"] += status.tolist()
    ds = xr.Dataset(
        {"point_id": ("observation", np.asarray(cols["point_id"], dtype=object)),
         "dtm": ("observation", np.asarray(cols["dtm"], dtype=object)),
         "residual": ("observation", np.asarray(cols["residual"], float), {"units": "m",
                      "long_name": "adjusted point height minus reference DTM height"}),
         "normalized_residual": ("observation", np.asarray(cols["normalized"], float),
                                 {"long_name": "residual / final sigma (a-priori x sigma scale x down-weighting)"}),
         "status": ("observation", np.asarray(cols["status"], dtype=object))},
        coords={"observation": np.arange(len(cols["dtm"]))})
    return section, ds


def _quality_control(block: Any, names: Sequence[str], groups: Sequence[str], qc: dict[str, Any], opts: Any) -> Any:
    """Quality-controlled adjustment of a run's block (see :func:`adjust_step`)."""
    from ..adjust.qc import QCOptions, quality_control

    labels = [g or n for n, g in zip(names, groups)]
    uniq = list(dict.fromkeys(labels))
    image_group = np.array([uniq.index(g) for g in labels], np.int64)
    options = QCOptions(
        sequent_limit_km=qc["sequent_limit_km"], units_per_km=1000.0, solver=opts,
        # the matcher's tie points; measured control and check points are left to the w-tests
        robust={"function": qc["robust_function"], "scale": qc["robust_scale"],
                "observations": block.network.point_type[block.problem.obs.pt_idx] == "tie"},
        baarda={"limit": qc["baarda_limit"], "per_round": qc["baarda_per_round"], "factor": qc["downweight_factor"],
                "sigma0": qc["baarda_sigma0"], "separable": qc["baarda_separable"]},
        # groups the data cannot estimate (e.g. a navigation group without redundancy) keep their sigma
        variance={"on_weak": "keep", "rounds": 20},
        # the paper's two stages (candidates from the residuals, then only the significant ones): the forward
        # selection adjusts once per candidate and round, too slow for a run's dozens of navigation groups
        offsets={"select": "all"},
        max_rounds=qc.get("max_rounds"), max_seconds=qc.get("max_seconds"))
    import warnings

    from ..errors import QualityControlWarning

    # a run that ends without a clean block is flagged in its summary and report (the flags are in the QC
    # report); the warning is logged, not raised into the run
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", QualityControlWarning)
        out = quality_control(block.problem, qc["steps"], image_group, [f"image {g}" for g in uniq], options)
    for w in caught:
        if issubclass(w.category, QualityControlWarning):
            _log.warning("adjust: %s", w.message)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return out


def _qc_summary(qc_out: Any, block: Any, names: Sequence[str]) -> dict[str, Any]:
    """The run summary's quality-control figures: counts per step and action, removed per point type."""
    rep = qc_out.report
    removed = qc_out.image_status() != "in"
    ptype = block.network.point_type[block.problem.obs.pt_idx]
    out: dict[str, Any] = {
        "steps": list(rep.summary.get("steps", [])),
        "first_adjustment": str(rep.summary.get("first_adjustment", "least squares")),
        "sigma0_first": float(rep.summary.get("sigma0_first", np.nan)),
        "sigma0_last": float(rep.summary.get("sigma0_last", np.nan)),
        "actions": {" ".join(k): int(v) for k, v in sorted(rep.counts().items())},
        "image_observations": int(removed.size),
        "image_observations_removed": int(removed.sum()),
        "removed_by_point_type": {t: int(np.sum(removed & (ptype == t))) for t in np.unique(ptype)},
        "removed_by_image": {n: int(np.sum(removed & (block.problem.obs.cam_idx == i))) for i, n in enumerate(names)},
        # every observation's final status, counted (the table itself is in qc.nc, status_*)
        "final_status": {f"{k} {st}": int(n) for (k, st), n in sorted(rep.status_counts().items())},
        "clean": bool(rep.clean),
        "flags": [str(f) for f in rep.summary.get("flags", [])],
    }
    for k in ("baarda_rounds", "max_w", "untestable", "sequent_points_removed"):
        if k in rep.summary:
            v = rep.summary[k]
            out[k] = float(v) if isinstance(v, (float, np.floating)) else int(v)
    return out


def kernel_sets(isds: Sequence[Any]) -> list[list[int]]:
    """Indices of images grouped so that no two images of one platform in a group overlap in time.

    One SPK holds one trajectory per spacecraft and one CK one attitude per frame: images taken at the
    same time by one spacecraft (LRO NAC-L and NAC-R) whose adjusted orientations differ cannot share
    a kernel set. Greedy in time order: each image joins the first set without a simultaneous image of
    its platform, so images that follow each other stay together.
    """
    order = sorted(range(len(isds)), key=lambda i: (float(np.min(isds[i].times)), i))
    sets: list[list[int]] = []
    for i in order:
        a0, a1 = float(np.min(isds[i].times)), float(np.max(isds[i].times))
        for group in sets:
            if all(isds[j].name_platform != isds[i].name_platform or float(np.max(isds[j].times)) < a0
                   or float(np.min(isds[j].times)) > a1 for j in group):
                group.append(i)
                break
        else:
            sets.append([i])
    return [sorted(g) for g in sets]


@_step(None)      # beside the adjusted RFMs' tasks: one thread
def kernels_step(store: Store, key: str, names: Sequence[str], adjusted: Done, isds: Sequence[Done],
                 metakernel: str) -> Done:
    """The adjusted orientation as SPK + CK + a meta-kernel layered over the run's kernels.

    ``kernels.json`` names each image's meta-kernel: ``adjusted.tm`` for all, or, when simultaneous images of
    one spacecraft were adjusted apart (their trajectories or attitudes then disagree), one set per group
    of :func:`kernel_sets` (``adjusted_1.tm``, ``adjusted_2.tm``, ...; a warning says so).
    """
    t = time.perf_counter()
    folder = store.path("kernels", key)
    if (folder / "kernels.json").exists():
        return Done("kernels", key, "", str(folder / "kernels.json"), False)
    from ..errors import OrientationConflictError
    from ..orientation.isd import ImageSupport
    from ..orientation.kernels import write_orientation_kernels

    isd_list = [ImageSupport.read_json(Path(adjusted.path) / f"{n}.adjusted.json") for n in names]
    try:
        folder.mkdir(parents=True, exist_ok=True)
        try:
            mk = write_orientation_kernels(isd_list, folder, metakernel, name="adjusted")
            index = {n: mk.name for n in names}
        except OrientationConflictError as err:
            sets = kernel_sets(isd_list)
            _log.warning("adjusted kernels in %d sets, one per group of images that do not overlap in time: %s",
                         len(sets), err)
            index = {}
            for k, group in enumerate(sets, start=1):
                mk = write_orientation_kernels([isd_list[i] for i in group], folder, metakernel, name=f"adjusted_{k}")
                index.update({names[i]: mk.name for i in group})
    except (LunarmapError, OSError) as err:
        import shutil

        from ..atomic import disk_error

        shutil.rmtree(folder, ignore_errors=True)      # nothing half-written stays behind
        named = disk_error(err, folder, "the adjusted kernels")
        if named is not None:
            raise named from err
        if not isinstance(err, LunarmapError):
            raise
        raise _fail("kernels", "", err) from None
    from ..atomic import atomic_write, disk_guard

    with disk_guard(folder, "the adjusted kernels"):
        path = atomic_write(folder / "kernels.json", lambda tmp: tmp.write_text(json.dumps(index, indent=1)))
        store.seal("kernels", key)
    return Done("kernels", key, "", str(path), True, time.perf_counter() - t,
                note=f"{len(set(index.values()))} kernel set(s)")


def as_dict(done: Done) -> dict[str, Any]:
    """A record as plain data (for the run's log and summary)."""
    return asdict(done)
