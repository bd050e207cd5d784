"""The one sensor-model interface of lunarmap: what RPC fitting, matching and the adjustment need.

A :class:`SensorModel` maps body-fixed ground points (metres) to image coordinates
``(line, sample)`` (pixels, USGS CSM convention: the centre of the first pixel is at
``(0.5, 0.5)``) and back, and exposes its partial derivatives and the correction parameters an
adjustment may estimate. :class:`~lunarmap.camera.FrameCamera`,
:class:`~lunarmap.camera.LineScanCamera`, :class:`~lunarmap.rpc.RationalFunctionModel` and the
affine-corrected sensors of :mod:`lunarmap.camera.corrections` implement it.

The corrections a sensor offers are a :class:`Corrections` object (``sensor.corrections()``):
a fixed number of parameters with names and units, the projection of ground points for given
parameter values with its analytic partials, and :meth:`Corrections.apply`, which returns a
*new* sensor model with the corrections applied (the original is never modified). Zero
parameters reproduce the sensor itself:

=========================  ===========================================================
sensor                     correction parameters
=========================  ===========================================================
frame camera               6: attitude ``w`` (rotation vector, radians, sensor frame) and
                           position ``c`` (metres, body-fixed)
line-scan camera           ``6 (degree + 1)``: ``w_k, c_k`` polynomial coefficients in
                           normalised image time ``tau`` in [-1, 1] (radians, metres)
RFM (or any sensor)        6 affine image-space parameters (seeds/001 Eq. 13)
=========================  ===========================================================
"""

from __future__ import annotations

from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["SensorModel", "Corrections"]

Array = NDArray[np.float64]


@runtime_checkable
class SensorModel(Protocol):
    """A sensor model: ground <-> image mapping, rays, partials and correction parameters.

    Attributes
    ----------
    n_lines, n_samples : int
        Image size, pixels.
    reference_radius : float
        Radius of the sphere heights refer to, metres.
    """

    @property
    def n_lines(self) -> int: ...

    @property
    def n_samples(self) -> int: ...

    @property
    def reference_radius(self) -> float: ...

    def ground_to_image(self, xyz: ArrayLike, on_miss: Literal["raise", "nan"] = "nan",
                        within_image: bool = True) -> tuple[Array, Array]:
        """``(line, sample)`` pixels of body-fixed points ``(..., 3)`` metres; NaN where not seen."""

    def image_to_ground(self, line: ArrayLike, sample: ArrayLike, height: ArrayLike = 0.0,
                        dtm: Any = None, on_miss: Literal["raise", "nan"] = "raise") -> Array:
        """Body-fixed points ``(..., 3)`` metres seen at image coordinates, at ``height`` metres or on a DTM."""

    def rays(self, line: ArrayLike, sample: ArrayLike) -> tuple[Array, Array]:
        """Origins (metres, body-fixed) and unit directions towards the scene of image coordinates."""

    def look_vector(self, line: ArrayLike, sample: ArrayLike) -> Array:
        """Unit look vectors ``(..., 3)``, body-fixed, towards the scene."""

    def ground_partials(self, xyz: ArrayLike) -> tuple[Array, Array, Array]:
        """``line, sample`` and ``d(line, sample) / d(x, y, z)`` ``(..., 2, 3)``, pixels per metre."""

    def corrections(self, degree: int | None = None) -> "Corrections":
        """The correction parameters an adjustment estimates for this sensor.

        ``degree`` is the polynomial degree in time of time-dependent corrections
        (line-scan cameras); single-exposure sensors ignore it.
        """


@runtime_checkable
class Corrections(Protocol):
    """Correction parameters of one sensor, their projection, partials and application.

    Attributes
    ----------
    sensor : SensorModel
        The sensor the parameters correct (zero parameters reproduce it).
    names : tuple of str
        Parameter names, in order.
    units : tuple of str
        Unit of every parameter (``"rad"``, ``"m"``, ``"px"``, ``"1"``).
    n_params : int
        Number of parameters.
    """

    sensor: Any
    names: tuple[str, ...]
    units: tuple[str, ...]
    n_params: int

    def project(self, params: ArrayLike, xyz: ArrayLike) -> Array:
        """``(line, sample)`` pixels ``(n, 2)`` of points ``(n, 3)`` metres for parameters ``(n_params,)``."""

    def partials(self, params: ArrayLike, xyz: ArrayLike) -> tuple[Array, Array, Array]:
        """Pixels ``(n, 2)``, ``d/d params (n, 2, n_params)`` and ``d/d xyz (n, 2, 3)`` (pixels per metre)."""

    def apply(self, params: ArrayLike) -> Any:
        """A new sensor model with the corrections applied."""
