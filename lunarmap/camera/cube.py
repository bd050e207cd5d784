"""Cameras from ``spiceinit``-ed ISIS cubes, without kernels (as ISIS's own camera works from the cube).

:func:`camera_from_cube` = :func:`lunarmap.orientation.cube.image_support_from_cube` +
:func:`lunarmap.camera.factory.camera_from_isd`.
"""

from __future__ import annotations

import os

from ..orientation.cube import image_support_from_cube
from .factory import camera_from_isd
from .sensor import SensorModel
from .shape import Shape

__all__ = ["camera_from_cube"]


def camera_from_cube(path: str | os.PathLike[str], shape: Shape | None = None, distortion: bool = True,
                     image_size: tuple[int, int] | None = None) -> SensorModel:
    """The rigorous camera of a ``spiceinit``-ed ISIS cube, from its tables alone.

    Parameters
    ----------
    path : path-like
        The cube.
    shape : Shape, optional
        Body shape; the radii in the cube's ``NaifKeywords`` by default.
    distortion : bool
        ``False`` builds the camera without lens distortion.
    image_size : (int, int), optional
        ``(lines, samples)`` of the image the tables describe, for stand-in cubes (see
        :func:`~lunarmap.orientation.cube.image_support_from_cube`).

    Returns
    -------
    FrameCamera or LineScanCamera
        The cube's rigorous camera.

    Raises
    ------
    MissingSpiceTablesError, UnknownInstrumentError, CubeFormatError
        See :func:`~lunarmap.orientation.cube.image_support_from_cube`.
    """
    return camera_from_isd(image_support_from_cube(path, image_size=image_size), shape=shape, distortion=distortion)
