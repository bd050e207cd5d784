"""Every exception and warning that lunarmap raises.

All exceptions derive from :class:`LunarmapError`; most also derive from the
built-in exception a Python user would expect (``FileNotFoundError``,
``ValueError``, ``KeyError``), so ``except ValueError`` keeps working.
Each message names the cause: the file, body, frame, instrument or time
involved.
"""

from __future__ import annotations

import warnings

__all__ = [
    "LunarmapError",
    "KernelError",
    "MissingKernelError",
    "KernelCoverageError",
    "SpiceError",
    "UnknownInstrumentError",
    "LabelError",
    "InvalidInputError",
    "GeometryError",
    "NoIntersectionError",
    "ConvergenceError",
    "LunarmapWarning",
    "warn",
]


class LunarmapError(Exception):
    """Base class of every lunarmap exception."""


class KernelError(LunarmapError):
    """A SPICE kernel could not be loaded or used."""


class MissingKernelError(KernelError, FileNotFoundError):
    """A kernel file (or meta-kernel) named by the user or a meta-kernel does not exist."""


class KernelCoverageError(KernelError):
    """The loaded kernels hold no data for the requested body, frame or time.

    Raised for a time outside SPK or CK coverage, a missing frame chain or a
    missing clock kernel. The message names the object and the epoch.
    """


class SpiceError(LunarmapError):
    """Any other error reported by the SPICE toolkit; the SPICE message is kept."""


class UnknownInstrumentError(LunarmapError, KeyError):
    """No driver or kernel-pool entry exists for the instrument named or implied."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class LabelError(LunarmapError, ValueError):
    """An image label (ISIS cube label, PDS3 label) is malformed or lacks a keyword."""


class InvalidInputError(LunarmapError, ValueError):
    """An argument is unusable: NaN or infinite coordinates, wrong shape, empty range."""


class GeometryError(LunarmapError):
    """The requested geometry cannot be computed."""


class NoIntersectionError(GeometryError):
    """A look ray misses the body (or the DTM) altogether."""


class ConvergenceError(GeometryError):
    """An iterative solution (ground-to-image, DTM intersection) did not converge."""


class LunarmapWarning(UserWarning):
    """Base class of lunarmap warnings."""


def warn(message: str, category: type[Warning] = LunarmapWarning, stacklevel: int = 2) -> None:
    """Issue a lunarmap warning, attributed to the caller's caller."""
    warnings.warn(message, category, stacklevel=stacklevel + 1)
