"""Loading SPICE kernels on dask workers.

SPICE's kernel pool lives in each worker *process*. :class:`SpiceKernelPlugin`
carries only a picklable :class:`~lunarmap.spice.KernelSet` (a list of paths)
and furnishes it when a worker starts, under lunarmap's SPICE lock, so tasks
find their kernels loaded and never furnish them per task. Tasks running in
several threads of one worker still serialise their SPICE calls on
:data:`lunarmap.spice.SPICE_LOCK`.
"""

from __future__ import annotations

from typing import Any

from distributed.diagnostics.plugin import WorkerPlugin

from ..spice import KernelSet, clear, ensure_loaded, loaded_kernel_set

__all__ = ["SpiceKernelPlugin", "register_kernels", "DaskLogsToFile", "dask_logs_to_file"]


class SpiceKernelPlugin(WorkerPlugin):
    """Furnish a kernel set on every worker (present and future).

    Parameters
    ----------
    kernel_set : KernelSet
        The kernels to load; paths must be valid on the workers' file system.
    """

    idempotent = True

    def __init__(self, kernel_set: KernelSet) -> None:
        self.kernel_set = kernel_set
        self.name = f"lunarmap-spice-{kernel_set.fingerprint[:16]}"

    def setup(self, worker: Any) -> None:
        ensure_loaded(self.kernel_set)

    def teardown(self, worker: Any) -> None:
        if loaded_kernel_set() == self.kernel_set:
            clear()


def register_kernels(client: Any, kernel_set: KernelSet | str) -> SpiceKernelPlugin:
    """Register :class:`SpiceKernelPlugin` with a ``distributed.Client``.

    ``kernel_set`` may be a meta-kernel path.
    """
    kset = kernel_set if isinstance(kernel_set, KernelSet) else KernelSet.from_metakernel(kernel_set)
    plugin = SpiceKernelPlugin(kset)
    client.register_plugin(plugin)
    return plugin


def dask_logs_to_file(path: str) -> list[tuple[Any, list[Any], bool]]:
    """Send the ``distributed`` loggers of this process to the file ``path`` instead of the terminal.

    Returns what :func:`restore_dask_logs` needs to put the former handlers back.
    """
    import logging

    handler = logging.FileHandler(path)
    handler.setFormatter(logging.Formatter("%(asctime)s %(process)d %(name)s %(levelname)s %(message)s"))
    saved = []
    names = ["distributed"] + [n for n in logging.root.manager.loggerDict
                               if n.startswith(("distributed.", "tornado", "bokeh"))]
    for name in names:
        log = logging.getLogger(name)
        streams = [h for h in log.handlers if isinstance(h, logging.StreamHandler)
                   and not isinstance(h, logging.FileHandler)]
        if not streams and name != "distributed":
            continue
        saved.append((log, list(log.handlers), log.propagate))
        for h in streams:
            log.removeHandler(h)
        log.addHandler(handler)
    return saved


def restore_dask_logs(saved: list[tuple[Any, list[Any], int]]) -> None:
    """Undo :func:`dask_logs_to_file`."""
    for log, handlers, propagate in saved:
        for h in list(log.handlers):
            if h not in handlers:
                log.removeHandler(h)
                h.close()
        for h in handlers:
            if h not in log.handlers:
                log.addHandler(h)
        log.propagate = propagate


class DaskLogsToFile(WorkerPlugin):
    """On every worker, ``distributed``'s log lines (a failed task's "Compute Failed" block, shutdown
    notices) go to a file instead of the terminal; the client reports the failure itself.

    Parameters
    ----------
    path : str
        Log file (appended to), on the workers' file system.
    """

    idempotent = True

    def __init__(self, path: str) -> None:
        self.path = str(path)
        self.name = "lunarmap-dask-logs"

    def setup(self, worker: Any) -> None:
        import logging

        dask_logs_to_file(self.path)
        # lunarmap's progress lines (adjustment iterations, QC rounds) reach the client
        # (Client.forward_logging("lunarmap")) only if the worker's logger lets them through
        log = logging.getLogger("lunarmap")
        if log.level == logging.NOTSET or log.level > logging.INFO:
            log.setLevel(logging.INFO)
