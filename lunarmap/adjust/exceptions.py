"""Exceptions raised by the block adjustment.

All derive from :class:`lunarmap.errors.LunarmapError`; input problems also
derive from :class:`lunarmap.errors.InvalidInputError` (hence ``ValueError``).
"""

from __future__ import annotations

from ..errors import ConvergenceError, InvalidInputError, LunarmapError

__all__ = [
    "AdjustmentError",
    "AdjustmentInputError",
    "InsufficientObservationsError",
    "UnobservedParameterError",
    "DatumDefectError",
    "AdjustmentDivergedError",
]


class AdjustmentError(LunarmapError):
    """Base class of block-adjustment errors."""


class AdjustmentInputError(AdjustmentError, InvalidInputError):
    """An adjustment input is unusable (NaN, wrong shape, index out of range, bad sigma)."""


class InsufficientObservationsError(AdjustmentInputError):
    """Fewer observations than unknowns: the problem has no redundancy."""


class UnobservedParameterError(AdjustmentInputError):
    """An image or point has no (or too few) observations to determine its unknowns."""


class DatumDefectError(AdjustmentError):
    """The normal equations are singular: the datum (gauge) is not defined.

    Add control points, navigation observations, or fix parameters.
    """


class AdjustmentDivergedError(AdjustmentError, ConvergenceError):
    """The Levenberg-Marquardt iteration could not reduce the cost any further from a non-finite state."""
