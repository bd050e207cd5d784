"""SPICE access: the only lunarmap package that imports spiceypy."""

from .kernelset import KernelSet, parse_text_kernel_data
from .pool import SPICE_LOCK, clear, ensure_loaded, kernels, loaded_kernel_set, spice_errors

__all__ = ["KernelSet", "parse_text_kernel_data", "SPICE_LOCK", "clear", "ensure_loaded", "kernels",
           "loaded_kernel_set", "spice_errors"]
