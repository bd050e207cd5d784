"""Sensor models from image support data.

:func:`camera_from_isd` turns an :class:`~lunarmap.orientation.isd.ImageSupport`
(what a driver sampled from SPICE) into a :class:`FrameCamera` or
:class:`LineScanCamera`: the ALE -> usgscsm seam, inside one library.
:func:`camera_from_isd_file` does the same from an ISD JSON file (lunarmap's or
ALE's), as usgscsm does, without SPICE.
"""

from __future__ import annotations

import os

import numpy as np

from typing import TYPE_CHECKING

from ..orientation.isd import ImageSupport
from .frame import FrameCamera
from .interior import InteriorOrientation
from .linescan import LineScanCamera, LineTimes
from .shape import Shape

if TYPE_CHECKING:
    from ..spice import KernelSet

__all__ = ["camera_from_isd", "camera_from_isd_file", "load_camera", "interior_from_isd", "shape_from_isd"]


def interior_from_isd(isd: ImageSupport, distortion: bool = True) -> InteriorOrientation:
    """Interior orientation of an image; ``distortion=False`` drops the distortion model."""
    model, coeffs = next(iter(isd.optical_distortion.items())) if isd.optical_distortion else ("none", {})
    if not distortion:
        model, coeffs = "none", {}
    return InteriorOrientation(
        focal_length=float(isd.focal_length),
        focal2pixel_lines=tuple(float(v) for v in isd.focal2pixel_lines),  # type: ignore[arg-type]
        focal2pixel_samples=tuple(float(v) for v in isd.focal2pixel_samples),  # type: ignore[arg-type]
        detector_center_line=float(isd.detector_center_line),
        detector_center_sample=float(isd.detector_center_sample),
        n_lines=int(isd.image_lines), n_samples=int(isd.image_samples),
        starting_detector_line=float(isd.starting_detector_line),
        starting_detector_sample=float(isd.starting_detector_sample),
        line_summing=int(isd.line_summing), sample_summing=int(isd.sample_summing),
        distortion_model=model, distortion_coefficients=dict(coeffs),
        pixel_pitch=_pixel_pitch(isd),
        name=isd.name_sensor,
    )


def _pixel_pitch(isd: ImageSupport) -> float:
    """Square-pixel pitch (mm) of the focal2pixel transform: 1 / sqrt(|det|) (samples along x or y alike)."""
    det = abs(isd.focal2pixel_lines[1] * isd.focal2pixel_samples[2] - isd.focal2pixel_lines[2] * isd.focal2pixel_samples[1])
    return float(1.0 / np.sqrt(det)) if det > 0 else float("nan")


def shape_from_isd(isd: ImageSupport, radius: float | None = None) -> Shape:
    """The body shape of the ISD's radii (km -> m), or a sphere of ``radius`` metres."""
    if radius is not None:
        return Shape.sphere(float(radius))
    a, b, c = (np.asarray(isd.radii, dtype=float) * 1000.0).tolist()
    return Shape.sphere(a) if a == b == c else Shape.ellipsoid(a, b, c)


def camera_from_isd(isd: ImageSupport, shape: Shape | None = None,
                    distortion: bool = True) -> FrameCamera | LineScanCamera:
    """The rigorous sensor model of an image.

    Parameters
    ----------
    isd : ImageSupport
        From :func:`lunarmap.orientation.drivers.image_support`.
    shape : Shape, optional
        Body shape; the ISD's radii by default.
    distortion : bool
        ``False`` builds the model without lens distortion (for comparisons
        with SPICE's pinhole ``sincpt``).
    """
    interior = interior_from_isd(isd, distortion=distortion)
    eo = isd.exterior_orientation()
    shape = shape_from_isd(isd) if shape is None else shape
    if isd.model == "frame":
        return FrameCamera(interior, eo, shape, time=isd.center_ephemeris_time - eo.epoch)
    if isd.line_scan_rates is not None:
        # usgscsm's timing: rows relative to the centre time, several for a variable line rate
        times = LineTimes.from_line_scan_rate(isd.line_scan_rates, time_offset=isd.center_ephemeris_time - eo.epoch)
    else:
        times = LineTimes.uniform(isd.starting_ephemeris_time - eo.epoch, isd.line_period)
    return LineScanCamera(interior, eo, shape, line_times=times)


def camera_from_isd_file(path: str | os.PathLike[str], shape: Shape | None = None,
                         distortion: bool = True) -> FrameCamera | LineScanCamera:
    """The rigorous sensor model of an ISD JSON file (written by lunarmap or USGS ALE); no SPICE.

    Parameters
    ----------
    path : path-like
        The ISD (``USGS_ASTRO_FRAME_SENSOR_MODEL`` or ``USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL``).
    shape : Shape, optional
        Body shape; the ISD's radii by default.
    distortion : bool
        ``False`` builds the model without lens distortion.

    Raises
    ------
    FileNotFoundError
        No such file.
    IsdFormatError
        The file is not a readable ISD; the message names the file and the key.
    """
    return camera_from_isd(ImageSupport.read_json(path), shape=shape, distortion=distortion)


def load_camera(label: str | os.PathLike[str], kernels: str | os.PathLike[str] | "KernelSet",
                shape: Shape | None = None, distortion: bool = True) -> FrameCamera | LineScanCamera:
    """The rigorous camera of an image from its label and kernels (one SPICE pass, then plain numpy).

    Parameters
    ----------
    label : path-like
        ISIS cube/label or PDS3 label (see :func:`lunarmap.orientation.drivers.image_support`).
    kernels : path-like or KernelSet
        Meta-kernel or kernel set.
    shape, distortion
        As for :func:`camera_from_isd`.
    """
    from ..orientation.drivers import image_support

    return camera_from_isd(image_support(label, kernels), shape=shape, distortion=distortion)
