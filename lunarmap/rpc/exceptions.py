"""Exceptions raised by the rational function model (RPC) package.

Every class derives from :class:`lunarmap.errors.LunarmapError` through the
lunarmap class a caller would expect (bad arguments are
:class:`~lunarmap.errors.InvalidInputError`, hence ``ValueError``; grids
that miss the body are :class:`~lunarmap.errors.NoIntersectionError`).
"""

from __future__ import annotations

from ..errors import ConvergenceError, GeometryError, InvalidInputError, LunarmapError, NoIntersectionError

__all__ = [
    "RpcError",
    "RpcInputError",
    "RpcFormatError",
    "RpcGridError",
    "RpcLimbError",
    "RpcFitError",
    "RpcConvergenceError",
]


class RpcError(LunarmapError):
    """Base class of the RPC package's errors."""


class RpcInputError(RpcError, InvalidInputError):
    """An argument of an RPC function is unusable (NaN, empty height range, wrong shape)."""


class RpcFormatError(RpcError, InvalidInputError):
    """An RPC file or dataset is malformed: missing keyword, wrong count, non-finite value."""


class RpcGridError(RpcError, NoIntersectionError):
    """The virtual control grid cannot be built: its rays miss the body."""


class RpcLimbError(RpcGridError):
    """The image footprint reaches the limb: some grid rays miss the body or graze it."""


class RpcFitError(RpcError, GeometryError):
    """The fitted rational function is unusable (denominator near zero, footprint over a pole)."""


class RpcConvergenceError(RpcError, ConvergenceError):
    """The RFM image-to-ground Newton iteration did not converge."""
