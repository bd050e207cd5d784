"""ISDs for many images on dask: one task per image, every image attempted, failures reported.

Command line::

    python -m workflows.isd_batch META_KERNEL OUT_DIR LABEL [LABEL ...] [--scheduler ADDRESS]
    python -m workflows.isd_batch --list IMAGES OUT_DIR [--scheduler ADDRESS]

The first form uses one meta-kernel for every label; the second reads an image
list, one image per line, ``LABEL META_KERNEL`` (relative paths are taken relative
to the list's folder; ``#`` starts a comment; quote paths with spaces), so one
batch can mix missions.

Each task samples SPICE for one image and writes ``OUT_DIR/<label stem>.isd.json``
atomically: an ISD file that exists is complete. An image that fails (a label no
driver supports, a time outside the kernels, a missing kernel, ...) does not stop
the batch: its error is collected by class name and message, printed in a summary
on standard error and written with every other image's outcome to
``OUT_DIR/isd_batch_report.json`` (see :data:`REPORT_NAME`). lunarmap errors are
reported without a traceback; any other exception (a bug) keeps its traceback in
the report. A failed image's output from an earlier run, if any, is left as it
was: the report is the authority on which files this run produced.

Exit status: 0 when every ISD was written, 1 when at least one image failed, 2 when
the batch could not run at all (bad arguments, unreadable image list, output folder
that cannot be made).

Kernels reach the workers through :class:`lunarmap.parallel.SpiceKernelPlugin`
(the batch's most used kernel set, loaded when a worker starts); a task whose
image needs another set makes that set resident on its worker
(:func:`lunarmap.spice.ensure_loaded`), and tasks are submitted grouped by kernel
set, so a worker switches sets rarely.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import traceback
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence, Union

import dask
from dask.delayed import Delayed

from lunarmap.errors import InvalidInputError, LunarmapError
from lunarmap.orientation.drivers import image_support
from lunarmap.orientation.isd import write_json_atomic
from lunarmap.spice import SPICE_LOCK, KernelSet, clear, ensure_loaded, loaded_kernel_set

__all__ = ["REPORT_NAME", "ImageResult", "BatchReport", "isd_task", "build", "run", "read_image_list", "main"]

#: File name of the machine-readable report written in the output folder.
REPORT_NAME = "isd_batch_report.json"
#: ``scheduler`` value that runs the graph in this process, one task after another.
SYNCHRONOUS = "synchronous"

PathLike = Union[str, "os.PathLike[str]"]
#: One image: a label path (uses the batch's meta-kernel) or a ``(label, meta_kernel)`` pair.
Image = Union[PathLike, tuple[PathLike, PathLike]]


@dataclass(frozen=True)
class ImageResult:
    """What happened to one image of a batch.

    Parameters
    ----------
    label : str
        The label path as given.
    kernels : str
        The meta-kernel used (or meant to be used) for it.
    output : str or None
        The ISD file written; ``None`` when the image failed.
    error : str or None
        Class name of the exception that stopped the image (``"KernelCoverageError"``).
    message : str or None
        The exception's message.
    traceback : str or None
        Only for exceptions that are not lunarmap's (a bug worth reporting).
    """

    label: str
    kernels: str
    output: str | None = None
    error: str | None = None
    message: str | None = None
    traceback: str | None = None

    @property
    def ok(self) -> bool:
        """Whether the ISD was written."""
        return self.error is None and self.output is not None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"label": self.label, "kernels": self.kernels,
                               "status": "written" if self.ok else "failed"}
        if self.ok:
            out["output"] = self.output
        else:
            out["error"] = self.error
            out["message"] = self.message
            if self.traceback:
                out["traceback"] = self.traceback
        return out


@dataclass(frozen=True)
class BatchReport:
    """Outcome of a batch, one :class:`ImageResult` per image in input order.

    Parameters
    ----------
    results : tuple of ImageResult
        Per image, in the order the images were given.
    report_path : str
        The JSON report written in the output folder.
    """

    results: tuple[ImageResult, ...]
    report_path: str = ""

    @property
    def written(self) -> list[str]:
        """Paths of the ISDs written, in input order."""
        return [r.output for r in self.results if r.ok and r.output is not None]

    @property
    def failures(self) -> list[ImageResult]:
        """The images that failed, in input order."""
        return [r for r in self.results if not r.ok]

    @property
    def ok(self) -> bool:
        """Whether every image's ISD was written."""
        return not self.failures

    def to_dict(self) -> dict[str, Any]:
        return {"lunarmap_isd_batch_report": 1, "images": len(self.results), "written": len(self.written),
                "failed": len(self.failures), "results": [r.to_dict() for r in self.results]}

    def summary(self) -> str:
        """Human-readable summary: one line per failure, then the counts."""
        lines = [f"FAILED {r.label}: {r.error}: {r.message}" for r in self.failures]
        lines.append(f"isd_batch: {len(self.written)} of {len(self.results)} ISDs written, "
                     f"{len(self.failures)} failed; report: {self.report_path}")
        return "\n".join(lines)


@dataclass
class _Job:
    index: int
    label: str
    kernels: str
    output: str
    kernel_set: KernelSet | None = None
    failed: ImageResult | None = field(default=None)


def isd_task(label: str, kernel_set: KernelSet, output: str) -> dict[str, Any]:
    """Write one image's ISD to ``output``; never raises for a problem of the image itself.

    Returns
    -------
    dict
        ``{"output": path}`` on success, otherwise ``{"error": class name, "message": text}``
        (plus ``"traceback"`` when the exception is not a lunarmap error or an ``OSError``).
    """
    try:
        with SPICE_LOCK:
            # resident, not just loaded for this call: the worker's next image with the
            # same kernels then loads nothing (image_support's own kernels() is a no-op)
            ensure_loaded(kernel_set)
            isd = image_support(label, kernel_set)
        isd.write_json(output)
        return {"output": output}
    except (LunarmapError, OSError) as err:
        return {"error": type(err).__name__, "message": str(err)}
    except Exception as err:  # a bug: this image fails, the batch goes on, the report keeps the traceback
        return {"error": type(err).__name__, "message": str(err), "traceback": traceback.format_exc()}


def build(labels: Sequence[PathLike], kernel_set: KernelSet | Sequence[KernelSet],
          out_dir: PathLike) -> list[Delayed]:
    """One delayed :func:`isd_task` per label (one kernel set for all, or one per label)."""
    sets = [kernel_set] * len(labels) if isinstance(kernel_set, KernelSet) else list(kernel_set)
    if len(sets) != len(labels):
        raise InvalidInputError(f"{len(labels)} labels but {len(sets)} kernel sets")
    task = dask.delayed(isd_task, pure=True)
    return [task(os.fspath(lab), kset, _output_path(lab, out_dir)) for lab, kset in zip(labels, sets)]


def _output_path(label: PathLike, out_dir: PathLike) -> str:
    return str(Path(out_dir) / (Path(label).stem + ".isd.json"))


def _plan(images: Sequence[Image], metakernel: PathLike | None, out_dir: PathLike) -> list[_Job]:
    """Resolve each image's meta-kernel and output; images that cannot start fail here, by name."""
    jobs: list[_Job] = []
    sets: dict[str, KernelSet | LunarmapError] = {}
    owner: dict[str, str] = {}
    for i, image in enumerate(images):
        if isinstance(image, tuple):
            label, mk = os.fspath(image[0]), os.fspath(image[1])
        elif metakernel is None:
            raise InvalidInputError(f"image {os.fspath(image)} has no meta-kernel and the batch has none")
        else:
            label, mk = os.fspath(image), os.fspath(metakernel)
        job = _Job(i, label, mk, _output_path(label, out_dir))
        key = os.path.abspath(mk)
        if key not in sets:
            try:
                sets[key] = KernelSet.from_metakernel(mk)
            except LunarmapError as err:
                sets[key] = err
        kset = sets[key]
        if isinstance(kset, LunarmapError):
            job.failed = ImageResult(label, mk, error=type(kset).__name__, message=str(kset))
        elif job.output in owner:
            job.failed = ImageResult(label, mk, error=InvalidInputError.__name__,
                                     message=f"output {job.output} is already the ISD of label {owner[job.output]} "
                                             f"in this batch (labels with the same file stem)")
        else:
            owner[job.output] = label
            job.kernel_set = kset
        jobs.append(job)
    return jobs


def _from_outcome(job: _Job, outcome: dict[str, Any]) -> ImageResult:
    if "output" in outcome:
        return ImageResult(job.label, job.kernels, output=outcome["output"])
    return ImageResult(job.label, job.kernels, error=outcome["error"], message=outcome["message"],
                       traceback=outcome.get("traceback"))


def _compute(runnable: list[_Job], out_dir: PathLike, scheduler: str | None, n_workers: int) -> list[ImageResult]:
    """Run the tasks of ``runnable``; one result per job, in the same order."""
    tasks = build([j.label for j in runnable], [j.kernel_set for j in runnable], out_dir)  # type: ignore[misc]
    if scheduler == SYNCHRONOUS:
        previous = loaded_kernel_set()
        try:
            outcomes = list(dask.compute(*tasks, scheduler="synchronous"))
        finally:  # leave the caller's kernel pool as it was
            if previous is None:
                clear()
            else:
                ensure_loaded(previous)
        return [_from_outcome(j, o) for j, o in zip(runnable, outcomes)]

    from distributed import Client, LocalCluster, wait

    from lunarmap.parallel import register_kernels

    cluster = None if scheduler else LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                                                  dashboard_address=":0")
    try:
        with Client(scheduler or cluster) as client:
            primary = Counter(j.kernel_set for j in runnable).most_common(1)[0][0]
            register_kernels(client, primary)  # type: ignore[arg-type]
            futures = client.compute(tasks)
            wait(futures)
            results = []
            for job, fut in zip(runnable, futures):
                if fut.status == "finished":
                    results.append(_from_outcome(job, fut.result()))
                else:  # the task itself never raises: this is the cluster (a worker died, ...)
                    exc = fut.exception() if fut.status == "error" else None
                    results.append(ImageResult(job.label, job.kernels, error=type(exc).__name__ if exc else fut.status,
                                               message=str(exc) if exc else f"task {fut.status}"))
            return results
    finally:
        if cluster is not None:
            cluster.close()


def run(labels: Sequence[Image], metakernel: PathLike | None, out_dir: PathLike,
        scheduler: str | None = None, n_workers: int = 2) -> BatchReport:
    """Compute the ISDs of ``labels``, attempting every one, and write the report.

    Parameters
    ----------
    labels : sequence
        Label paths (using ``metakernel``) and/or ``(label, meta_kernel)`` pairs.
    metakernel : path-like or None
        Meta-kernel for the bare label paths; may be ``None`` when every image is a pair.
    out_dir : path-like
        Output folder (created if needed): ``<label stem>.isd.json`` per image and
        :data:`REPORT_NAME`.
    scheduler : str, optional
        Address of a dask-distributed scheduler; default a local cluster of
        ``n_workers`` single-threaded processes; ``"synchronous"`` runs in this
        process (debugging, tests) and restores its kernel pool afterwards.
    n_workers : int
        Processes of the local cluster.

    Returns
    -------
    BatchReport
        One result per image, in input order; ``report.ok`` is False if any failed.

    Raises
    ------
    InvalidInputError
        A bare label path and no ``metakernel``.
    OSError
        The output folder cannot be created or the report cannot be written.
    """
    jobs = _plan(labels, metakernel, out_dir)
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    runnable = [j for j in jobs if j.failed is None]
    # grouped by kernel set (first appearance), so each worker switches sets rarely
    first_seen: dict[KernelSet, int] = {}
    for j in runnable:
        first_seen.setdefault(j.kernel_set, len(first_seen))  # type: ignore[arg-type]
    runnable.sort(key=lambda j: (first_seen[j.kernel_set], j.index))  # type: ignore[index]
    results: list[ImageResult | None] = [j.failed for j in jobs]
    if runnable:
        for job, res in zip(runnable, _compute(runnable, out_dir, scheduler, n_workers)):
            results[job.index] = res
    report_path = str(Path(out_dir) / REPORT_NAME)
    report = BatchReport(tuple(r for r in results if r is not None), report_path)
    write_json_atomic(report.to_dict(), report_path)
    return report


def read_image_list(path: PathLike) -> list[tuple[str, str]]:
    """Read an image list: one ``LABEL META_KERNEL`` pair per line.

    Relative paths are taken relative to the list's folder; ``#`` starts a comment;
    paths with spaces are quoted as in a shell.

    Raises
    ------
    InvalidInputError
        The file is missing or unreadable, or a line does not hold exactly two paths
        (the message names the file and line).
    """
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as err:
        raise InvalidInputError(f"cannot read image list {p}: {err.strerror or err}") from err
    except UnicodeDecodeError as err:
        raise InvalidInputError(f"image list {p} is not text in the locale's encoding: {err}") from err
    base = p.resolve().parent
    images = []
    for n, line in enumerate(text.splitlines(), 1):
        try:
            fields = shlex.split(line, comments=True)
        except ValueError as err:
            raise InvalidInputError(f"{p}:{n}: {err}") from err
        if not fields:
            continue
        if len(fields) != 2:
            raise InvalidInputError(f"{p}:{n}: expected 'LABEL META_KERNEL', got {len(fields)} field(s): {line.strip()!r}")
        images.append((str(base / fields[0]), str(base / fields[1])))
    if not images:
        raise InvalidInputError(f"image list {p} names no image")
    return images


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry point; returns the exit status (0 all written, 1 some failed, 2 not run)."""
    ap = argparse.ArgumentParser(prog="python -m workflows.isd_batch", description=__doc__.split("\n\n")[0],
                                 usage="%(prog)s META_KERNEL OUT_DIR LABEL [LABEL ...] [--scheduler ADDRESS]\n"
                                       "       %(prog)s --list IMAGES OUT_DIR [--scheduler ADDRESS]")
    ap.add_argument("paths", nargs="+", help="META_KERNEL OUT_DIR LABEL..., or OUT_DIR with --list")
    ap.add_argument("--list", dest="image_list", metavar="IMAGES",
                    help="file of 'LABEL META_KERNEL' lines (one image per line)")
    ap.add_argument("--scheduler", help="address of a dask-distributed scheduler (default: a local cluster)")
    args = ap.parse_args(argv)
    if args.image_list and len(args.paths) != 1:
        ap.error("with --list give only OUT_DIR")
    if not args.image_list and len(args.paths) < 3:
        ap.error("give META_KERNEL OUT_DIR LABEL [LABEL ...] (or --list IMAGES OUT_DIR)")
    try:
        if args.image_list:
            report = run(read_image_list(args.image_list), None, args.paths[0], args.scheduler)
        else:
            report = run(args.paths[2:], args.paths[0], args.paths[1], args.scheduler)
    except (LunarmapError, OSError) as err:
        print(f"isd_batch: error: {type(err).__name__}: {err}", file=sys.stderr)
        return 2
    for path in report.written:
        print(path)
    print(report.summary(), file=sys.stderr)
    return 0 if report.ok else 1


if __name__ == "__main__":
    # Run the module's own copy, not __main__'s: cloudpickle ships functions of
    # __main__ by value (with their globals, e.g. the SPICE lock, which cannot be
    # pickled) but functions of an importable module by reference.
    from workflows.isd_batch import main as _main

    sys.exit(_main())
