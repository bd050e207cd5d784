"""Warnings and exceptions of tie-point matching (subclasses of :mod:`lunarmap.errors` classes)."""

from __future__ import annotations

from ..errors import LunarmapWarning

__all__ = ["MatchingWarning", "BlankTileWarning", "NoOverlapWarning", "InvalidPixelsWarning"]


class MatchingWarning(LunarmapWarning):
    """Base class of matching warnings: some points could not be detected or matched."""


class BlankTileWarning(MatchingWarning):
    """A tile has no usable texture (constant, saturated or mostly NaN); no interest points there."""


class NoOverlapWarning(MatchingWarning):
    """Two images do not overlap (no predicted conjugate inside the second image)."""


class InvalidPixelsWarning(MatchingWarning):
    """An image holds NaN, infinite or saturated pixels; windows touching them are not matched."""
