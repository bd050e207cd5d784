"""``lunarmap.workflows.run``: the whole chain of a configuration as one dask graph, resumable, with progress.

The graph (every node a task of :mod:`.steps`, named ``<stage>-<key>``)::

    per image      image: isd -> footprints, rpc, pyramid, interest points (one task, each step stored)
    pair batches   match  (about one task per image; a pair is skipped, and recorded as such, when its
                   images overlap too little)
    block          tiepoints -> adjust (quality control: the tie points' variance factor) -> kernels,
                   adjusted RFMs (at most 16 tasks)

:func:`run` computes it in two phases: the per-image steps first, then the pairs whose footprints can
meet (:func:`lunarmap.evaluate.candidate_pairs`, a k-d tree over footprint caps) and the block. A block
of n images thus has about ``n x neighbours`` match steps rather than ``n (n - 1) / 2``, in about n
tasks; pairs found apart are counted in the summary (``pairs_apart``), not listed. Pixels are read by
window (:mod:`lunarmap.matching.windowed`) through each image's stored pyramid: no task holds a whole
image, and a worker's pixel cache is bounded in bytes.

Keys are computed before anything runs, from the inputs' content and the parameters
(:mod:`.store`), so a rerun skips every finished step and a changed parameter reruns exactly what
depends on it. The graph runs serially (``scheduler="sync"``), on a ``distributed.LocalCluster``
(the default: ``workers`` processes) or on a running ``dask scheduler`` given its address; kernels reach
the workers through :class:`lunarmap.parallel.SpiceKernelPlugin`. Progress goes to the ``lunarmap``
logger per stage (tasks done / total, stage wall time) and to ``<run>/run.log``.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import dask

from ..errors import ConfigError, LunarmapError
from ..procmem import peak_rss_mb
from .config import RunConfig, load_config
from .outputs import Outputs, image_files, read_manifest
from .steps import (
    BatchDone,
    Done,
    ImageDone,
    ImageJob,
    MatchJob,
    _dtm_sampler,
    adjust_step,
    adjusted_rpc_batch,
    as_dict,
    barrier_threads,
    image_steps,
    kernels_step,
    match_batch,
    provenance,
    tiepoints_step,
)
from .store import (
    Store,
    add_digests,
    digest_rows,
    file_digest,
    files_digest,
    load_digests,
    save_digests,
    step_key,
)

__all__ = ["RunResult", "RunPlan", "run", "plan", "build_graph", "STAGES"]

_log = logging.getLogger(__name__)

#: Stages in graph order.
STAGES = ("image", "match", "tiepoints", "adjust", "kernels", "rpc_adjusted")


@dataclass
class RunResult:
    """What a run produced.

    Attributes
    ----------
    config : RunConfig
    folder : pathlib.Path
        The run folder.
    summary : dict
        The adjustment's figures (``<run>/outputs/adjustment/summary.json``).
    outputs : dict name -> pathlib.Path
        Files and folders in ``<run>/outputs``.
    done : list of Done
        Every step's record.
    stage_seconds : dict
        Wall time from the start of the graph to each stage's last task.
    report : pathlib.Path or None
        The HTML report.
    tasks : int
        Tasks of the run's two graphs.
    peak_rss_mb : dict
        Peak resident memory (``VmHWM``, MB) of this process (``"main"``) and of every worker process
        that ran tasks (by worker address).
    """

    config: RunConfig
    folder: Path
    summary: dict[str, Any]
    outputs: dict[str, Path]
    done: list[Done]
    stage_seconds: dict[str, float] = field(default_factory=dict)
    report: Path | None = None
    tasks: int = 0
    peak_rss_mb: dict[str, float] = field(default_factory=dict)

    def counts(self) -> dict[str, tuple[int, int]]:
        """Per stage: (steps computed in this run, steps found in the store)."""
        out: dict[str, tuple[int, int]] = {}
        for d in self.done:
            c, s = out.get(d.step, (0, 0))
            out[d.step] = (c + int(d.computed), s + int(not d.computed))
        return out

    @property
    def computed(self) -> int:
        """Number of steps this run computed (0 when everything was already done)."""
        return sum(int(d.computed) for d in self.done)


@dataclass
class _Graph:
    tasks: dict[str, Any]            # dask key -> Delayed, every step
    stage_of: dict[str, str]         # dask key -> stage
    names: list[str]
    pairs: list[tuple[str, str]]
    apart: int = 0                   # pairs left out because their footprints cannot meet
    outputs: dict[str, list[Path]] = field(default_factory=dict)   # dask key -> files the task writes
    jobs: dict[str, Any] = field(default_factory=dict)             # image -> its ImageJob (keys of its steps)
    heights: tuple[float, ...] = ()                                # of the footprints
    # dask key -> (step function, its arguments): the same calls without dask (:func:`call_steps`)
    calls: dict[str, tuple[Callable[..., Any], tuple[Any, ...]]] = field(default_factory=dict)

    def computes(self) -> bool:
        """Whether any task has an output missing from the store (else every task only reads it)."""
        return any(not p.exists() for paths in self.outputs.values() for p in paths)


def verify_outputs(store: Store, graph: _Graph) -> list[str]:
    """Verify every stored entry the graph's tasks would reuse; a damaged one is removed (its step then
    computes it again) with a :class:`~lunarmap.errors.StoreDamageWarning` naming it. Returns the problems."""
    import warnings

    from ..errors import StoreDamageWarning
    from .store import entry_of, remove_entry, sidecar, verify_entry

    problems = []
    seen: set[Path] = set()
    for paths in graph.outputs.values():
        for p in paths:
            entry = entry_of(store.root, p)
            if entry in seen:
                continue
            seen.add(entry)
            if not entry.exists():
                if sidecar(entry).exists():
                    sidecar(entry).unlink(missing_ok=True)
                continue
            why = verify_entry(entry)
            if why is not None:
                problems.append(why)
                msg = f"store entry damaged, computing it again: {why}"
                _log.warning(msg)
                warnings.warn(msg, StoreDamageWarning, stacklevel=2)
                remove_entry(entry)
    return problems


def _batches(items: list[Any], per_task: int) -> list[list[Any]]:
    return [items[k:k + per_task] for k in range(0, len(items), per_task)]


def _tiepoints(store: Store, key: str, names: list[str], pairs: list[tuple[str, str]],
               batches: list[list[Done]], track_tol: float, attrs: dict[str, Any]) -> Done:
    """The tie-point step over the match batches' records (in pair order)."""
    return tiepoints_step(store, key, names, pairs, [d for b in batches for d in b], track_tol, attrs)


class _Value:
    """A task's argument that holds no upstream task (see :func:`_call`)."""

    __slots__ = ("value",)

    def __init__(self, value: Any) -> None:
        self.value = value


def _has_task(arg: Any) -> bool:
    from dask.delayed import Delayed

    return isinstance(arg, Delayed) or (isinstance(arg, (list, tuple)) and any(isinstance(a, Delayed) for a in arg))


def _call(fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)`` with the :class:`_Value` arguments unwrapped (the graph's task function).

    A step runs with dask's synchronous scheduler as the default: on a distributed worker xarray otherwise
    finds the worker's client and takes a cluster-wide ``distributed.Lock`` (a scheduler round trip) for every
    netCDF file it writes, which serialises the workers' writes. Measured on 48 RFM steps, 2 workers: 0.181 s
    per step with the lock, 0.089 s without (0.084 s serially); a step never computes a dask graph of its own
    on the cluster, so nothing else changes.
    """
    with dask.config.set(scheduler="sync"):
        return fn(*(a.value if isinstance(a, _Value) else a for a in args))


def navigation_args(cfg: RunConfig) -> dict[str, Any] | None:
    """The adjust step's navigation argument of a configuration (plain values: part of its store key)."""
    if cfg.navigation is None:
        return None
    n = cfg.navigation
    return {"position_sigma": n.position_sigma, "attitude_sigma": n.attitude_sigma,
            "position_rate_sigma": n.position_rate_sigma, "attitude_rate_sigma": n.attitude_rate_sigma,
            "offset": n.offset, "drift": n.drift,
            "offset_sigma": list(n.offset_sigma) if n.offset_sigma else None,
            "drift_sigma": list(n.drift_sigma) if n.drift_sigma else None}


def qc_args(cfg: RunConfig) -> dict[str, Any] | None:
    """The adjust step's quality-control argument of a configuration (None without QC steps)."""
    return None if cfg.qc is None or not cfg.qc.steps else {**asdict(cfg.qc), "steps": list(cfg.qc.steps)}


def build_graph(cfg: RunConfig, store: Store, done: dict[str, Any] | None = None,
                images_only: bool = False, export: Outputs | None = None) -> _Graph:
    """The run's graph of store-aware steps (nothing is computed).

    Parameters
    ----------
    cfg : RunConfig
    store : Store
    done : dict dask key -> result, optional
        Results of steps already computed in this run (the per-image phase). They enter the graph as
        values, not tasks; given the footprints among them, only the pairs whose footprints can meet
        get match steps. Without, every pair of images gets one.
    images_only : bool
        Only the per-image tasks (ISD, footprints, RFM, pyramid, interest points): the first phase of
        :func:`run`.
    export : lunarmap.workflows.outputs.Outputs, optional
        The run's outputs folder and its manifest: the per-image tasks and the adjusted RFMs' batches then
        write their images' output files themselves (:mod:`.outputs`).
    """
    from ..io.window import PixelSource
    from ..spice import KernelSet

    kset = KernelSet.from_metakernel(cfg.metakernel)
    kset.check_files()
    kernels_digest = files_digest([cfg.metakernel, *kset.paths])
    params = tiepoint_params(cfg)
    sat = params.match.saturation
    digest = cfg.digest()
    attrs = provenance(digest, kset.paths)
    tasks: dict[str, Any] = {}
    calls: dict[str, tuple[Callable[..., Any], tuple[Any, ...]]] = {}
    stage_of: dict[str, str] = {}
    outputs: dict[str, list[Path]] = {}

    def node(stage: str, key: str, fn: Callable[..., Any], *args: Any, out: Sequence[Path] = ()) -> Any:
        name = f"{stage}-{key}"
        if done is not None and name in done:
            return done[name]
        if name not in tasks:
            # arguments without an upstream task travel as they are: dask would search every record,
            # footprint and job in them for collections (1.9 of a 48-image rerun's 8 s, profiled)
            plain = [a if _has_task(a) else _Value(a) for a in args]
            tasks[name] = dask.delayed(_call, pure=False)(fn, *plain, dask_key_name=name)
            calls[name] = (fn, args)
            stage_of[name] = stage
            outputs[name] = list(out)
        return tasks[name]

    names = [im.name for im in cfg.images]
    heights = [float(min(cfg.rpc_height_range)), float(max(cfg.rpc_height_range))]
    if cfg.dtm is not None:
        # the matcher's own sampler (one copy of the grid per process; a serial run shares it with the matching)
        dtm = _dtm_sampler(cfg.dtm)[0]
        heights = [min(heights[0], dtm.min_height), max(heights[1], dtm.max_height)]
    rpc_range = cfg.rpc_height_range if cfg.rpc_enabled else None
    image: dict[str, Any] = {}
    jobs_of: dict[str, ImageJob] = {}
    isd_key: dict[str, str] = {}
    pix: dict[str, str] = {}
    for im in cfg.images:
        try:
            if done is None:                     # the images' phase read them already
                PixelSource(im.pixels)           # the header only: is it an image at all?
            pix[im.name] = file_digest(im.pixels)
        except (OSError, LunarmapError) as err:
            raise ConfigError(f"{cfg.source}: image {im.name}: pixels {im.pixels} are not a readable image "
                              f"({err})") from None
        isd_key[im.name] = step_key("isd", None, [file_digest(im.label), kernels_digest])
        job = ImageJob(
            name=im.name, label=str(im.label), pixels=str(im.pixels), digest=pix[im.name], isd_key=isd_key[im.name],
            footprint_key=step_key("footprint", heights, [isd_key[im.name]]),
            rpc_key=step_key("rpc", list(cfg.rpc_height_range), [isd_key[im.name]]) if cfg.rpc_enabled else None,
            pyramid_key=step_key("pyramid", [params.match.pyramid_levels, sat], [pix[im.name]]),
            detect_key=step_key("detect", [repr(params.detect), sat], [pix[im.name]]))
        out = [store.path("isd", job.isd_key, "json"), store.path("footprint", job.footprint_key, "npz"),
               store.path("pyramid", job.pyramid_key, "nc"), store.path("detect", job.detect_key, "npz")]
        if job.rpc_key is not None:
            out.append(store.path("rpc", job.rpc_key, "nc"))
        jobs_of[im.name] = job
        image[im.name] = node("image", isd_key[im.name], image_steps, store, job, str(cfg.metakernel),
                              tuple(heights), rpc_range, params.detect, params.match.pyramid_levels, sat,
                              export.subset(image_files(im.name, cfg.rpc_enabled)) if export is not None else None,
                              out=out)
    if images_only:
        return _Graph(tasks, stage_of, names, [], outputs=outputs, jobs=jobs_of, heights=tuple(heights), calls=calls)
    candidates = [(a, b) for i, a in enumerate(names) for b in names[i + 1:]]
    apart = 0
    if done is not None and all(isinstance(v, ImageDone) for v in image.values()):
        from ..evaluate.footprint import candidate_pairs

        n_all = len(candidates)
        candidates = candidate_pairs({n: image[n].footprints for n in names})
        apart = n_all - len(candidates)
        rec = {n: {s: image[n].get(s) for s in ("isd", "pyramid", "detect")} for n in names}
    else:   # a graph built before the images' phase ran (inspection): records are placeholders
        rec = {n: {s: Done(s, "", n, "", False) for s in ("isd", "pyramid", "detect")} for n in names}
    dtm = str(cfg.dtm) if cfg.dtm is not None else None
    dtm_digest = file_digest(cfg.dtm) if cfg.dtm is not None else ""
    spec = {im.name: im for im in cfg.images}
    jobs, match_keys = [], []
    for a, b in candidates:
        k = step_key("match", [repr(params.match), repr(params.ransac), cfg.min_overlap, params.max_points],
                     [pix[a], pix[b], isd_key[a], isd_key[b], dtm_digest, rec[a]["detect"].key])
        jobs.append(MatchJob(k, (a, b), (str(spec[a].pixels), str(spec[b].pixels)),
                             (rec[a]["isd"], rec[b]["isd"]), (rec[a]["pyramid"], rec[b]["pyramid"]),
                             rec[a]["detect"], (pix[a], pix[b])))
        match_keys.append(k)
    # about one match task per image: the graph of 10,000 images stays at ~20,000 tasks
    per_task = max(1, -(-len(jobs) // max(1, len(names))))
    batches = []
    for group in _batches(jobs, per_task):
        bk = step_key("match_batch", None, [j.key for j in group])
        batches.append(node("match", bk, match_batch, store, group, dtm, params, cfg.min_overlap,
                            out=[store.path("match", j.key, "npz") for j in group]))
    pairs = [j.pair for j in jobs]
    # the table names its images: a renamed image is another table
    k_tie = step_key("tiepoints", [params.track_tol, names], match_keys)
    ties = node("tiepoints", k_tie, _tiepoints, store, k_tie, names, pairs, batches, params.track_tol, attrs,
                out=[store.path("tiepoints", k_tie, "nc")])
    nav = navigation_args(cfg)
    groups = [im.group for im in cfg.images]
    points = str(cfg.points) if cfg.points is not None else None
    qc = qc_args(cfg)
    # the reference DTMs: their parameters and their files' content (a changed DTM reruns the adjustment)
    terrain = [{"name": d.name, "path": str(d.path), "sigma": d.sigma, "slope_baseline": d.slope_baseline}
               for d in cfg.terrain]
    jitter = None
    if cfg.jitter is not None:
        jitter = {"knot_lines": cfg.jitter.knot_lines, "sigma": cfg.jitter.sigma, "zero_sigma": cfg.jitter.zero_sigma,
                  "images": list(cfg.jitter.images) if cfg.jitter.images is not None else None}
    # the altimeters alike (their shot tables' content in the key)
    altimetry = [{"name": a.name, "path": str(a.path), "sigma": a.sigma, "interpolation_sigma": a.interpolation_sigma,
                  "offset_sigma": a.offset_sigma, "drift": a.drift} for a in cfg.altimetry]
    k_adj = step_key("adjust", [cfg.degree, nav, cfg.estimate_tie_variance, cfg.ftol, groups, names]
                     + ([qc] if qc is not None else [])
                     + ([{"jitter": jitter}] if jitter is not None else [])
                     + ([cfg.points_other_images] if points and cfg.points_other_images != "error" else [])
                     + ([[{k: v for k, v in d.items() if k != "path"} for d in terrain]] if terrain else [])
                     + ([[{k: v for k, v in a.items() if k != "path"} for a in altimetry]] if altimetry else []),
                     [isd_key[n] for n in names] + [k_tie, file_digest(cfg.points) if cfg.points is not None else ""]
                     + [file_digest(d.path) for d in cfg.terrain] + [file_digest(a.path) for a in cfg.altimetry])
    adj = node("adjust", k_adj, adjust_step, store, k_adj, names, groups, [rec[n]["isd"] for n in names], ties,
               points, cfg.degree, nav, cfg.estimate_tie_variance, cfg.ftol, attrs, qc, cfg.points_other_images,
               terrain or None, jitter, altimetry or None, out=[store.path("adjust", k_adj)])
    k_ker = step_key("kernels", None, [k_adj, kernels_digest])
    node("kernels", k_ker, kernels_step, store, k_ker, names, adj, [rec[n]["isd"] for n in names],
         str(cfg.metakernel), out=[store.path("kernels", k_ker) / "kernels.json"])
    if cfg.rpc_enabled:
        rjobs = [(step_key("rpc_adjusted", [list(cfg.rpc_height_range), n], [k_adj]), n) for n in names]
        per = max(1, -(-len(rjobs) // 16))
        for group in _batches(rjobs, per):
            rels = [f"rpc_adjusted/{n}{ext}" for _, n in group for ext in (".nc", "_RPC.TXT")]
            node("rpc_adjusted", step_key("rpc_adjusted_batch", None, [k for k, _ in group]), adjusted_rpc_batch,
                 store, group, adj, cfg.rpc_height_range, export.subset(rels) if export is not None else None,
                 out=[store.path("rpc_adjusted", k, "nc") for k, _ in group])
    return _Graph(tasks, stage_of, names, pairs, apart, outputs, jobs_of, tuple(heights), calls)


@dataclass
class RunPlan:
    """What :func:`run` would do (``lunarmap run --dry-run``), found without running any step.

    Attributes
    ----------
    config : RunConfig
    images : list of str
    pairs : list of (str, str)
        The candidate pairs: those whose footprints can meet (each gets a match step).
    pairs_apart : int
        Pairs left out because their footprints cannot meet.
    steps : dict stage -> (int, int)
        Per stage of :data:`STAGES`: tasks to compute, tasks whose outputs are all in the store (reused).
    points : lunarmap.workflows.checks.PointsCheck
        The points file's usable control and check points.
    """

    config: RunConfig
    images: list[str]
    pairs: list[tuple[str, str]]
    pairs_apart: int
    steps: dict[str, tuple[int, int]]
    points: Any = None

    def text(self) -> str:
        """The plan as printed by ``lunarmap run --dry-run``."""
        c = self.config
        n = len(self.images)
        lines = [f"run {c.name or c.source} -> {c.output}",
                 f"  images ({n}): {', '.join(self.images)}",
                 f"  candidate pairs: {len(self.pairs)} of {n * (n - 1) // 2} (footprints can meet; "
                 f"{self.pairs_apart} apart): {', '.join(f'{a}/{b}' for a, b in self.pairs[:8])}"
                 + (", ..." if len(self.pairs) > 8 else "")]
        if c.points is not None and self.points is not None:
            p = self.points
            lines.append(f"  points {c.points}: {p.control} control, {p.check} check points"
                         + (f" ({p.dropped_measures} measures in other images dropped)" if p.dropped_measures else ""))
        lines.append("  steps (tasks to compute / reused from the store):")
        lines += [f"    {s:<13} {k:4d} compute {r:4d} reuse" for s, (k, r) in self.steps.items() if k or r]
        lines.append("nothing was run (--dry-run)")
        return "\n".join(lines)


def plan(config: RunConfig | str | os.PathLike[str]) -> RunPlan:
    """The plan of a run: its checks (:func:`lunarmap.workflows.checks.check_before_work`), images,
    candidate pairs and steps to compute or reuse; nothing is computed or written.

    Footprints come from the store where it has them, else from each image's label and kernels (one
    SPICE pass per image, in this process; no pixel is read).

    Parameters
    ----------
    config : RunConfig or path-like

    Returns
    -------
    RunPlan

    Raises
    ------
    ConfigError
        As :func:`run` before any step.
    """
    from ..camera.factory import camera_from_isd
    from ..errors import NoOverlapError
    from ..evaluate.footprint import footprint
    from ..orientation.drivers import image_support
    from .checks import check_before_work
    from .steps import Done, ImageDone, footprint_step

    cfg = config if isinstance(config, RunConfig) else load_config(config)
    found = check_before_work(cfg)
    store = Store(cfg.output / "store")
    first = build_graph(cfg, store, images_only=True)
    feet: dict[str, Any] = {}
    done: dict[str, Any] = {}
    spec = {im.name: im for im in cfg.images}
    for name, job in first.jobs.items():
        isd = Done("isd", job.isd_key, name, str(store.path("isd", job.isd_key, "json")), False)
        if store.has("footprint", job.footprint_key, "npz"):
            feet[name] = footprint_step(store, job.footprint_key, isd, first.heights)
        else:
            cam = camera_from_isd(image_support(spec[name].label, cfg.metakernel))
            try:
                feet[name] = [footprint(cam, height=h, per_side=8, name=name) for h in first.heights]
            except NoOverlapError:
                feet[name] = None
        records = [isd] + [Done(s, k, name, "", False) for s, k in (("pyramid", job.pyramid_key),
                                                                     ("detect", job.detect_key))]
        done[f"image-{job.isd_key}"] = ImageDone(records, feet[name])
    graph = build_graph(cfg, store, done=done)
    steps = {s: [0, 0] for s in STAGES}
    for g in (first, graph):
        for k, st in g.stage_of.items():
            steps[st][0 if any(not p.exists() for p in g.outputs.get(k, [])) else 1] += 1
    return RunPlan(cfg, list(first.names), list(graph.pairs), graph.apart,
                   {s: (a, b) for s, (a, b) in steps.items()}, found)


def tiepoint_params(cfg: RunConfig) -> Any:
    """The tie-point chain's settings of a run configuration."""
    from ..matching import DetectParams, MatchParams, TiePointParams

    return TiePointParams(detect=DetectParams(cell=cfg.cell), match=MatchParams(search=cfg.search),
                          max_points=cfg.max_points)


class _Progress:
    """Tasks done per stage, logged when a stage completes and at most every ``every`` seconds."""

    def __init__(self, stage_of: dict[str, str], every: float = 5.0) -> None:
        self.stage_of: dict[str, str] = {}
        self.total = {s: 0 for s in STAGES}
        self.add(stage_of)
        self.done = {s: 0 for s in STAGES}
        self.records: list[Done] = []
        self.start = time.perf_counter()
        self.stage_seconds: dict[str, float] = {}
        self.every = every
        self._last = 0.0
        self.seen = 0.0           # perf_counter of the last lunarmap log line (any step's, forwarded or not)
        self.exported: dict[str, str] = {}    # manifest rows of the output files the tasks wrote

    def heartbeat(self) -> None:
        """Log the progress if nothing was logged for ``every`` seconds (tasks that run long)."""
        now = time.perf_counter() - self.start
        if now - max(self._last, self.seen - self.start) > self.every:
            self._last = now
            _log.info("progress at %.0f s: %s", now, "  ".join(f"{s} {self.done[s]}/{self.total[s]}" for s in STAGES
                                                               if self.total[s]))

    def add(self, stage_of: dict[str, str]) -> None:
        """Count the tasks of another phase."""
        for k, st in stage_of.items():
            if k not in self.stage_of:
                self.stage_of[k] = st
                self.total[st] += 1

    def finished(self, key: str, result: Any) -> None:
        stage = self.stage_of.get(key)
        if stage is None:
            return
        self.done[stage] += 1
        if isinstance(result, Done):
            self.records.append(result)
        elif isinstance(result, (ImageDone, BatchDone)):
            self.records.extend(result.records)
            if result.exported is not None:
                self.exported.update(result.exported.rows)
        elif isinstance(result, list):
            self.records.extend(d for d in result if isinstance(d, Done))
        now = time.perf_counter() - self.start
        if self.done[stage] == self.total[stage]:
            self.stage_seconds[stage] = now
            _log.info("%-9s %4d/%-4d done at %6.1f s", stage, self.done[stage], self.total[stage], now)
            self._last = now
        else:
            self.heartbeat()


class _Heartbeat(logging.Handler):
    """A thread that calls ``progress.heartbeat()`` every second while a phase computes; as a handler of the
    ``lunarmap`` logger it notes when any line was logged, so that it only fills silences."""

    def __init__(self, progress: _Progress) -> None:
        import threading

        super().__init__(logging.INFO)
        self.progress = progress
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._loop, name="lunarmap-progress", daemon=True)

    def _loop(self) -> None:
        while not self.stop.wait(1.0):
            self.progress.heartbeat()

    def emit(self, record: logging.LogRecord) -> None:
        self.progress.seen = time.perf_counter()

    def __enter__(self) -> "_Heartbeat":
        logging.getLogger("lunarmap").addHandler(self)
        self.thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop.set()
        self.thread.join()
        logging.getLogger("lunarmap").removeHandler(self)


def _execute(graph: _Graph, scheduler: Any, progress: _Progress) -> dict[str, Any]:
    """Compute every task of ``graph``; returns dask key -> result."""
    with _Heartbeat(progress):
        return _compute(graph, scheduler, progress)


def call_steps(graph: _Graph, seconds: dict[str, float] | None = None) -> dict[str, Any]:
    """Every step of ``graph`` called in this process, in the order the graph was built (upstream first),
    without dask: the run's own step functions on the same store (the baseline of the scheduler's
    overhead, ``bench/bench_run.py``). Returns dask key -> result, as the scheduler's; ``seconds``, when
    given, gathers the wall time of the calls per stage (seconds)."""
    from dask.delayed import Delayed

    results: dict[str, Any] = {}

    def value(a: Any) -> Any:
        if isinstance(a, Delayed):
            return results[a.key]
        if isinstance(a, (list, tuple)) and any(isinstance(x, Delayed) for x in a):
            return type(a)(value(x) for x in a)
        return a

    for name, (fn, args) in graph.calls.items():
        t = time.perf_counter()
        with dask.config.set(scheduler="sync"):        # as _call: what a step computes of its own, serially
            results[name] = fn(*(value(a) for a in args))
        if seconds is not None:
            stage = graph.stage_of[name]
            seconds[stage] = seconds.get(stage, 0.0) + time.perf_counter() - t
    return results


def _compute(graph: _Graph, scheduler: Any, progress: _Progress) -> dict[str, Any]:
    keys = list(graph.tasks)
    results: dict[str, Any] = {}
    delayed = [graph.tasks[k] for k in keys]
    if hasattr(scheduler, "compute") and hasattr(scheduler, "submit"):   # a distributed.Client
        from distributed import as_completed

        futures = scheduler.compute(delayed)
        by_key = {f.key: k for f, k in zip(futures, keys)}
        try:
            for fut in as_completed(futures):
                err = fut.exception()
                if err is not None:
                    raise err
                results[by_key[fut.key]] = fut.result()
                progress.finished(by_key[fut.key], results[by_key[fut.key]])
        except BaseException:
            for f in futures:
                f.cancel()
            raise
        return results
    from dask.callbacks import Callback

    def post(key: Any, result: Any, dsk: Any, state: Any, worker_id: Any) -> None:
        progress.finished(key if isinstance(key, str) else str(key), result)

    serial = scheduler in ("sync", "synchronous")
    if serial:
        # the function itself: given the name, dask imports distributed to look for a client first (a second
        # of a rerun that computes nothing)
        from dask.local import get_sync

        scheduler = get_sync
    # a serial run is one core, also in its adjustment (a step that may otherwise take every core: steps.ALL)
    with Callback(posttask=post), barrier_threads(1 if serial else None):
        values = dask.compute(*delayed, scheduler=scheduler)
    return dict(zip(keys, values))


def _export(cfg: RunConfig, graph: _Graph, records: list[Done],
            exported: dict[str, str]) -> tuple[dict[str, Path], dict[str, Any]]:
    """The block's outputs (tie points, adjustment, kernels' index and meta-kernels) copied to ``<run>/outputs``
    unless fresh, and the manifest of every output file; the per-image files were written by their tasks
    (``exported``: their manifest rows), any a task left out are written here."""
    from .outputs import MANIFEST, Exported, Outputs, read_manifest

    out = cfg.output / "outputs"
    out.mkdir(parents=True, exist_ok=True)
    by_stage: dict[str, list[Done]] = {}
    for d in records:
        by_stage.setdefault(d.step, []).append(d)
    files: dict[str, Path] = {}
    # which store entry each output was made from: a rerun writes only what changed
    copied = read_manifest(out)
    outputs = Outputs(str(out), copied)
    done = Exported(dict(exported))
    files["tiepoints"] = outputs.copy(by_stage["tiepoints"][0].path, "tiepoints.nc", done)
    files["adjustment"] = outputs.copy(by_stage["adjust"][0].path, "adjustment", done)
    # each image's adjusted meta-kernel (one for all, or one per set of images that do not overlap in time)
    kfolder = Path(by_stage["kernels"][0].path).parent
    index = json.loads(Path(by_stage["kernels"][0].path).read_text())
    files["kernels"] = outputs.copy(by_stage["kernels"][0].path, "kernels.json", done)
    files["metakernels"] = out / "kernels.json"
    for mk in sorted(set(index.values())):
        files[mk[:-3]] = outputs.copy(kfolder / mk, mk, done)
    if set(index.values()) == {"adjusted.tm"}:
        files["metakernel"] = out / "adjusted.tm"
    # the navigation cameras' RFMs, the adjusted cameras' and the ISDs: written by their tasks; a file no task
    # reported (a task run without the outputs folder) is written here
    for stage, folder in (("rpc", "rpc"), ("rpc_adjusted", "rpc_adjusted"), ("isd", "isd")):
        if stage not in by_stage:
            continue
        for d in by_stage[stage]:
            if stage == "isd":
                if f"isd/{d.item}.json" not in done.rows:
                    outputs.copy(d.path, f"isd/{d.item}.json", done)
                continue
            if f"{folder}/{d.item}.nc" not in done.rows:
                outputs.copy(d.path, f"{folder}/{d.item}.nc", done)
            if f"{folder}/{d.item}_RPC.TXT" not in done.rows:
                outputs.rpc_text(d.path, f"{folder}/{d.item}_RPC.TXT", done)
        files[stage] = out / folder
    summary = json.loads((files["adjustment"] / "summary.json").read_text())
    steps = [as_dict(d) for d in records]
    skipped = [d for d in by_stage.get("match", []) if d.note.startswith("skipped")]
    summary["skipped_pairs"] = [f"{d.item}: {d.note}" for d in skipped]
    summary["pairs_apart"] = int(graph.apart)
    summary["pairs_candidate"] = len(graph.pairs)
    from ..atomic import atomic_write

    atomic_write(cfg.output / "steps.json", lambda tmp: tmp.write_text(json.dumps(steps, indent=1)))
    # rows in a fixed order (tasks finish in any order): the same outputs give the same manifest, and a rerun
    # that changed nothing leaves it as it is
    text = json.dumps(dict(sorted(done.rows.items())), indent=0)
    if not (out / MANIFEST).exists() or (out / MANIFEST).read_text() != text:
        atomic_write(out / MANIFEST, lambda tmp: tmp.write_text(text))
    return files, summary


def run(config: RunConfig | str | os.PathLike[str], scheduler: Any = None, workers: int = 2,
        report: bool | None = None, wait: bool = False, force: bool = False) -> RunResult:
    """Run the chain of a configuration (see the module docstring).

    Parameters
    ----------
    config : RunConfig or path-like
        A validated configuration or the path of its TOML file.
    scheduler : None, "sync", "threads", a scheduler address (``"tcp://host:8786"``) or a ``distributed.Client``
        ``None`` starts a ``LocalCluster`` of ``workers`` processes for the run.
    workers : int
        Processes of the local cluster.
    report : bool, optional
        Write the HTML report (default: the configuration's ``report.html``).
    wait : bool
        When another run holds the folder's lock (:mod:`.lock`), wait for it (it then finds that run's
        outputs stored) instead of stopping with :class:`~lunarmap.errors.RunLockedError`.
    force : bool
        Take the folder whatever its lock says (a run known to be gone, on another host).

    Raises
    ------
    ConfigError
        Invalid configuration or inputs, found before any work starts.
    DiskWriteError, DiskFullError
        The run folder is not writable, or its disk has too little space for what the run would store
        (both checked before any work), or filled up while writing (the path is named; no file is left
        half-written).
    RunLockedError
        Another run uses the folder.
    WorkflowError
        A step failed (named); finished steps stay in the store, and a rerun resumes.
    """
    from ..atomic import check_writable
    from .lock import RunLock

    cfg = config if isinstance(config, RunConfig) else load_config(config)
    check_writable(cfg.output, "the run folder")
    with RunLock(cfg.output, wait=wait, force=force):
        return _run_locked(cfg, scheduler, workers, report)


def _space_needed(cfg: RunConfig, graph: _Graph) -> int:
    """Bytes the store will need for the per-image entries still missing: ~0.6 x each such image's pixel
    file (pyramid levels of 1/4 + 1/16 + ... of the image in float32 for 8-bit images are ~1/3 x 4 bytes per
    pixel, fewer for wider types) + 1 MB per image; the block's outputs are small."""
    need = 0
    keys = [k for k in graph.outputs if k.startswith("image-")]
    for i, im in enumerate(cfg.images):
        paths = graph.outputs[keys[i]] if len(keys) == len(cfg.images) else [Path("/nonexistent")]
        if any(not p.exists() for p in paths):
            try:
                need += int(0.6 * os.path.getsize(im.pixels)) + (1 << 20)
            except OSError:
                pass
    return need


def _run_locked(cfg: RunConfig, scheduler: Any, workers: int, report: bool | None) -> RunResult:
    from ..atomic import disk_guard

    store = Store(cfg.output / "store")
    with disk_guard(cfg.output / "run.log", "the run's log"):
        store.root.mkdir(parents=True, exist_ok=True)
        handler = logging.FileHandler(cfg.output / "run.log")
    handler.setFormatter(logging.Formatter("%(asctime)s %(name)s %(levelname)s %(message)s"))
    root = logging.getLogger("lunarmap")
    root.addHandler(handler)
    if root.level == logging.NOTSET or root.level > logging.INFO:
        root.setLevel(logging.INFO)
    client = cluster = None
    dask_logs: list[Any] = []
    digests = store.root / "digests.json"
    load_digests(digests)
    try:
        from .checks import check_before_work

        check_before_work(cfg)     # what the steps would find late in the files, before any of them runs
        # the per-image output files are written by the per-image tasks, from the manifest's rows of them
        outputs = Outputs(str(cfg.output / "outputs"), read_manifest(cfg.output / "outputs"))
        first = build_graph(cfg, store, images_only=True, export=outputs)
        _log.info("run %s: %d images, %d per-image tasks -> %s", cfg.name or cfg.source, len(first.names),
                  len(first.tasks), cfg.output)
        verify_outputs(store, first)
        need = _space_needed(cfg, first)
        free = shutil.disk_usage(store.root).free
        if need > free:
            from ..errors import DiskFullError

            raise DiskFullError(f"writing the run's store {store.root}: about {need >> 20} MB needed for the "
                                f"images' pyramids and points, {free >> 20} MB free")
        progress = _Progress(first.stage_of)
        local = scheduler in ("sync", "threads", "synchronous", "processes")

        def scheduler_for(graph: _Graph) -> Any:
            # a phase whose every output is stored only reads the store: no cluster is started for it
            nonlocal client, cluster
            if not graph.computes() and not hasattr(scheduler, "submit"):
                return "sync"
            if scheduler is None or (isinstance(scheduler, str) and not local):
                if client is None:
                    from ..parallel.plugin import dask_logs_to_file

                    # distributed's own lines (a failed task's "Compute Failed" block, shutdown notices) go
                    # to <run>/dask.log: the terminal gets lunarmap's one error line
                    dask_logs.extend(dask_logs_to_file(str(cfg.output / "dask.log")))
                    client, cluster = _client(scheduler, workers, cfg)
                    _log.info("dask dashboard: %s", client.dashboard_link)
                return client
            return scheduler

        if cfg.altimetry:
            from .steps import altimetry_table

            # a bad shot table (missing column, NaN, a track of one shot) is named before any work; read into
            # the process's cache, where a serial run's adjust step finds it
            for a in cfg.altimetry:
                altimetry_table(a.path)
        done = _execute(first, scheduler_for(first), progress)
        if cfg.terrain:
            from .checks import check_terrain_coverage

            # a DTM of another area is named before any pair is matched
            image_done = {n: done.get(f"image-{job.isd_key}") for n, job in first.jobs.items()}
            check_terrain_coverage(cfg, {n: v.footprints or [] for n, v in image_done.items()
                                         if isinstance(v, ImageDone)})
        graph = build_graph(cfg, store, done=done, export=outputs)
        n_all = len(graph.names) * (len(graph.names) - 1) // 2
        _log.info("pairs: %d of %d whose footprints can meet; %d block tasks", len(graph.pairs), n_all,
                  len(graph.tasks))
        progress.add(graph.stage_of)
        verify_outputs(store, graph)
        _execute(graph, scheduler_for(graph), progress)
        peaks = {"main": peak_rss_mb()}
        if client is not None:
            peaks.update(client.run(peak_rss_mb))
            # what the workers hashed writing the store and the outputs: a rerun need not read it again
            for rows in client.run(digest_rows, str(cfg.output.resolve())).values():
                add_digests(rows)
        _log.info("copying the block's outputs to %s", cfg.output / "outputs")
        with disk_guard(cfg.output / "outputs", "the run's outputs"):
            files, summary = _export(cfg, graph, progress.records, progress.exported)
        save_digests(digests)
        summary["tasks"] = len(first.tasks) + len(graph.tasks)
        summary["peak_rss_mb"] = peaks
        # per step: the largest process peak while one of its tasks computed (which step sets a worker's size)
        by_step: dict[str, float] = {}
        for d in progress.records:
            if d.computed and d.peak_mb:
                by_step[d.step] = max(by_step.get(d.step, 0.0), d.peak_mb)
        summary["peak_rss_mb_by_step"] = by_step
        result = RunResult(cfg, cfg.output, summary, files, progress.records, progress.stage_seconds,
                           tasks=summary["tasks"], peak_rss_mb=peaks)
        if cfg.html if report is None else report:
            from .report import write_report

            # a rerun that computed nothing keeps the report of the same adjustment (only its stage
            # timings would differ)
            page, stamp = cfg.output / "report" / "index.html", cfg.output / "report" / ".adjustment"
            adjusted = next(d.key for d in progress.records if d.step == "adjust")
            if result.computed == 0 and page.exists() and stamp.exists() and stamp.read_text() == adjusted:
                result.report = page
            else:
                t_report = time.perf_counter()
                _log.info("writing the report (plots, tables)")
                result.report = write_report(result)
                stamp.write_text(adjusted)
                _log.info("report %s written in %.1f s", result.report, time.perf_counter() - t_report)
        counts = result.counts()
        _log.info("run finished: %s", ", ".join(f"{s} {c} computed / {k} reused" for s, (c, k) in counts.items()))
        return result
    except BaseException as err:
        # the details go to run.log only (the command line prints one line)
        handler.handle(logging.LogRecord(_log.name, logging.ERROR, __file__, 0, "run failed: %s: %s",
                                         (type(err).__name__, err), (type(err), err, err.__traceback__)))
        if isinstance(err, LunarmapError):
            err.run_log = cfg.output / "run.log"     # type: ignore[attr-defined]  # named by the command line
        raise
    finally:
        if client is not None:
            _log.info("stopping the local dask cluster" if cluster is not None else "closing the dask client")
        _shutdown(client, cluster)
        if dask_logs:
            from ..parallel.plugin import restore_dask_logs

            restore_dask_logs(dask_logs)
        root.removeHandler(handler)
        try:
            handler.close()
        except OSError:     # run.log on a full disk cannot take its last lines: the run's own error says why
            pass


def check_run(config: RunConfig | str | os.PathLike[str]) -> tuple[int, list[str]]:
    """Verify a run folder's store against its checksums, reading every byte afresh; nothing is computed
    or changed (``lunarmap run CONFIG --check``). Returns ``(entries checked, problems)``; the digest
    cache (``digests.json``) is checked too."""
    from .store import verify_store

    cfg = config if isinstance(config, RunConfig) else load_config(config)
    n, problems = verify_store(cfg.output / "store", fresh=True)
    digests = cfg.output / "store" / "digests.json"
    if digests.exists():
        try:
            doc = json.loads(digests.read_text())
            import hashlib

            if not isinstance(doc, dict) or hashlib.sha256(json.dumps(doc["rows"]).encode()).hexdigest() != doc["sha256"]:
                raise ValueError("checksum mismatch")
        except (OSError, ValueError, KeyError, TypeError) as err:
            problems.append(f"{digests}: damaged ({err}); a run recomputes the input digests")
    return n, problems


def _shutdown(client: Any, cluster: Any) -> None:
    """Close the client, then the cluster (its workers first), each with a timeout."""
    if client is not None:
        try:
            client.close(timeout=10)
        except Exception as err:          # a scheduler already gone: nothing left to close
            _log.debug("client close: %s", err)
    if cluster is not None:
        try:
            cluster.close(timeout=30)
        except Exception as err:
            _log.debug("cluster close: %s", err)


def _client(address: Any, workers: int, cfg: RunConfig) -> tuple[Any, Any]:
    from distributed import Client, LocalCluster

    from ..matching import WORKER_ENVIRON
    from ..parallel import register_kernels

    cluster = None
    if address is None:
        with dask.config.set({"distributed.nanny.pre-spawn-environ": WORKER_ENVIRON}):
            cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                                   dashboard_address=":0")
        client = Client(cluster)
    else:
        try:
            client = Client(address, timeout="10s")
        except (OSError, TimeoutError) as err:
            raise ConfigError(f"no dask scheduler at {address}: {err}") from None
    register_kernels(client, str(cfg.metakernel))
    from ..parallel.plugin import DaskLogsToFile

    client.register_plugin(DaskLogsToFile(str(cfg.output / "dask.log")))
    client.forward_logging("lunarmap", level=logging.INFO)     # steps' progress lines, on the client's handlers
    return client, cluster

