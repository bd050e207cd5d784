"""Body shape: a triaxial ellipsoid (a sphere when the axes are equal).

Heights ``h`` are realised by enlarging every semi-axis by ``h``; for a sphere
this is exactly the sphere of radius ``R + h``. For a true triaxial ellipsoid
the enlarged ellipsoid is not the surface of constant geodetic height, but
it is what the ray intersection uses (as usgscsm's ``losEllipsoidIntersect``
does); for the Moon, which lunarmap treats as a sphere, the two agree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..errors import InvalidInputError

__all__ = ["Shape", "MOON_RADIUS", "MOON_RADIUS_HISTORICAL"]

#: Mean lunar radius of the IAU WGCCRE 2015 report (and LOLA products), metres.
MOON_RADIUS = 1737400.0
#: Historical lunar reference radius (pre-LOLA products), metres.
MOON_RADIUS_HISTORICAL = 1736600.0


@dataclass(frozen=True)
class Shape:
    """A triaxial ellipsoid body shape.

    Parameters
    ----------
    a, b, c : float
        Semi-axes along body-fixed x, y, z, metres.
    reference_radius : float, optional
        Radius of the reference sphere that heights (geodesy, DTMs) are
        measured from, metres; defaults to ``a`` for a sphere and to the
        mean ``(a + b + c) / 3`` otherwise.
    name : str
        Label for messages.
    """

    a: float
    b: float
    c: float
    reference_radius: float = float("nan")
    name: str = ""

    def __post_init__(self) -> None:
        axes = np.array([self.a, self.b, self.c], dtype=float)
        if not np.all(np.isfinite(axes)) or np.any(axes <= 0.0):
            raise InvalidInputError(f"ellipsoid semi-axes must be finite and positive, got {axes.tolist()}")
        ref = float(self.reference_radius)
        if np.isnan(ref):
            ref = float(axes.mean())
        if not np.isfinite(ref) or ref <= 0.0:
            raise InvalidInputError(f"reference radius must be finite and positive, got {ref}")
        for name, value in zip("abc", axes):
            object.__setattr__(self, name, float(value))
        object.__setattr__(self, "reference_radius", ref)

    @classmethod
    def sphere(cls, radius: float = MOON_RADIUS, name: str = "") -> "Shape":
        """A sphere of ``radius`` metres, which is also the height reference."""
        return cls(radius, radius, radius, radius, name)

    @classmethod
    def ellipsoid(cls, a: float, b: float, c: float, reference_radius: float | None = None,
                  name: str = "") -> "Shape":
        """A triaxial ellipsoid with semi-axes ``a, b, c`` metres."""
        return cls(a, b, c, float("nan") if reference_radius is None else reference_radius, name)

    @classmethod
    def moon(cls, radius: float = MOON_RADIUS) -> "Shape":
        """The Moon as a sphere of 1737.4 km (IAU 2015) or ``radius`` metres."""
        return cls.sphere(radius, name="Moon")

    @property
    def axes(self) -> NDArray[np.float64]:
        """Semi-axes ``(a, b, c)``, metres."""
        return np.array([self.a, self.b, self.c])

    @property
    def is_sphere(self) -> bool:
        """True when the three semi-axes are equal."""
        return self.a == self.b == self.c

    def axes_at_height(self, height: float | NDArray[np.float64] = 0.0) -> NDArray[np.float64]:
        """Semi-axes of the ellipsoid enlarged by ``height`` metres; shape ``height.shape + (3,)``."""
        h = np.asarray(height, dtype=float)
        return self.axes + h[..., None]
