"""Warnings of the image simulator (subclasses of :mod:`lunarmap.errors` classes)."""

from __future__ import annotations

from ..errors import LunarmapWarning

__all__ = ["SimulationWarning"]


class SimulationWarning(LunarmapWarning):
    """A rendered image is incomplete: some pixels see no DTM or orthoimage and are NaN."""
