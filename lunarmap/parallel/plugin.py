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

__all__ = ["SpiceKernelPlugin", "register_kernels"]


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
