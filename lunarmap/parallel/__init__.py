"""dask integration: worker plugin for SPICE kernels."""

from .plugin import SpiceKernelPlugin, register_kernels

__all__ = ["SpiceKernelPlugin", "register_kernels"]
