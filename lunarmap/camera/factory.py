"""Sensor models from image support data.

:func:`camera_from_isd` turns an :class:`~lunarmap.orientation.isd.ImageSupport`
(what a driver sampled from SPICE) into a :class:`FrameCamera`, :class:`LineScanCamera`,
:class:`PushFrameCamera` or :class:`SarSensor`: the ALE -> usgscsm seam, inside one library.
:func:`camera_from_isd_file` does the same from an ISD JSON file (lunarmap's or
ALE's), as usgscsm does, without SPICE.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import InvalidInputError, IsdConventionWarning, warn
from ..orientation.isd import ImageSupport
from .frame import FrameCamera
from .interior import InteriorOrientation
from .linescan import LineScanCamera, LineTimes
from .pushframe import FrameletTiming, PushFrameCamera
from .sar import SarSensor
from .sensor import SensorModel
from .shape import Shape

if TYPE_CHECKING:
    from ..spice import KernelSet

__all__ = ["camera_from_isd", "camera_from_isd_file", "load_camera", "interior_from_isd", "shape_from_isd"]


#: Distortion models odd in the focal-plane coordinates (``D(-x) = -D(x)``): a camera reflected through
#: its projection centre keeps them unchanged.
_ODD_DISTORTIONS = ("none", "radial", "lrolrocnac", "dawnfc", "kplo_shadowcam")


def interior_from_isd(isd: ImageSupport, distortion: bool = True, reflected: bool = False) -> InteriorOrientation:
    """Interior orientation of an image; ``distortion=False`` drops the distortion model.

    ``reflected=True`` gives the camera reflected through its projection centre (focal length and
    the linear focal-plane terms negated): every pixel's line of sight is the same line, pointing the
    other way; see :func:`camera_from_isd`.
    """
    if isd.model == "sar":
        raise InvalidInputError("a SAR image has no interior orientation (no focal plane)")
    model, coeffs = next(iter(isd.optical_distortion.items())) if isd.optical_distortion else ("none", {})
    if not distortion:
        model, coeffs = "none", {}
    sign = -1.0 if reflected else 1.0
    f2l = [float(v) for v in isd.focal2pixel_lines]
    f2s = [float(v) for v in isd.focal2pixel_samples]
    return InteriorOrientation(
        focal_length=sign * float(isd.focal_length),
        focal2pixel_lines=(f2l[0], sign * f2l[1], sign * f2l[2]),
        focal2pixel_samples=(f2s[0], sign * f2s[1], sign * f2s[2]),
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
                    distortion: bool = True) -> SensorModel:
    """The rigorous sensor model of an image.

    Parameters
    ----------
    isd : ImageSupport
        From :func:`lunarmap.orientation.drivers.image_support` or an ISD file.
    shape : Shape, optional
        Body shape; the ISD's radii by default.
    distortion : bool
        ``False`` builds the model without lens distortion (for comparisons
        with SPICE's pinhole ``sincpt``).

    Returns
    -------
    FrameCamera, LineScanCamera, PushFrameCamera or SarSensor
        By the ISD's ``model``.

    Notes
    -----
    Two readings follow usgscsm where an ISD leaves room:

    * a framing camera whose ISD has a single position sample is exposed at that sample's time (usgscsm
      uses the sample as it is, whatever the centre time);
    * usgscsm intersects a pixel's whole line of sight with the body, in either direction, so an ISD
      whose boresight points away from the body (usgscsm's own test ISDs of line scanners and push
      frames) images the surface behind the camera. Such a camera is read reflected through its
      projection centre (:func:`interior_from_isd` ``reflected=True``: the same lines of sight, pointing
      at the body), with an :class:`~lunarmap.errors.IsdConventionWarning`; a real camera never needs
      it. Only distortion models odd in the focal-plane coordinates allow it.
    """
    shape = shape_from_isd(isd) if shape is None else shape
    if isd.model == "sar":
        return SarSensor.from_image_support(isd, shape)
    camera = _optical_camera(isd, shape, interior_from_isd(isd, distortion=distortion))
    if _boresight_away(camera):
        model = next(iter(isd.optical_distortion), "none") if distortion else "none"
        if str(model).lower() not in _ODD_DISTORTIONS:
            raise InvalidInputError(
                f"the boresight of {isd.name_sensor or 'the image'} points away from the body; usgscsm would image "
                f"the surface behind the camera, which lunarmap models only for distortion models odd in x, y "
                f"({', '.join(_ODD_DISTORTIONS)}), not {model!r}")
        reflected = _optical_camera(isd, shape, interior_from_isd(isd, distortion=distortion, reflected=True))
        if not _boresight_away(reflected):
            warn(f"{isd.provenance.get('isd_file', isd.name_sensor)}: the camera's boresight points away from the "
                 "body; read reflected through the projection centre, as usgscsm sees it (it intersects lines of "
                 "sight in both directions)", IsdConventionWarning)
            camera = reflected
    return camera


def _optical_camera(isd: ImageSupport, shape: Shape, interior: InteriorOrientation) -> SensorModel:
    eo = isd.exterior_orientation()
    if isd.model == "frame":
        # usgscsm's frame model uses a single position sample as it is, whatever its time
        time = float(eo.times[0]) if eo.times.size == 1 else isd.center_ephemeris_time - eo.epoch
        return FrameCamera(interior, eo, shape, time=time)
    if isd.model == "pushframe":
        assert isd.push_frame is not None
        return PushFrameCamera(interior, eo, shape,
                               FrameletTiming.from_isd(isd.push_frame, isd.starting_ephemeris_time - eo.epoch))
    if isd.line_scan_rates is not None:
        # usgscsm's timing: rows relative to the centre time, several for a variable line rate
        times = LineTimes.from_line_scan_rate(isd.line_scan_rates, time_offset=isd.center_ephemeris_time - eo.epoch)
    else:
        times = LineTimes.uniform(isd.starting_ephemeris_time - eo.epoch, isd.line_period)
    return LineScanCamera(interior, eo, shape, line_times=times)


def _boresight_away(camera: Any) -> bool:
    """Whether the image centre's line of sight points into the half-space away from the body centre."""
    origin, look = camera.rays(0.5 * camera.n_lines, 0.5 * camera.n_samples)
    return bool(np.dot(look, -origin) < 0.0)


def camera_from_isd_file(path: str | os.PathLike[str], shape: Shape | None = None,
                         distortion: bool = True) -> SensorModel:
    """The rigorous sensor model of an ISD JSON file (written by lunarmap or USGS ALE); no SPICE.

    Parameters
    ----------
    path : path-like
        The ISD (``USGS_ASTRO_FRAME_SENSOR_MODEL``, ``..._LINE_SCANNER_...``, ``..._PUSH_FRAME_...`` or
        ``USGS_ASTRO_SAR_SENSOR_MODEL``; ``.json`` or ``.json.gz``).
    shape : Shape, optional
        Body shape; the ISD's radii by default.
    distortion : bool
        ``False`` builds the model without lens distortion.

    Returns
    -------
    SensorModel
        A ``FrameCamera``, ``LineScanCamera``, ``PushFrameCamera`` or ``SarSensor``.

    Raises
    ------
    FileNotFoundError
        No such file.
    IsdFormatError
        The file is not a readable ISD; the message names the file and the key.
    """
    return camera_from_isd(ImageSupport.read_json(path), shape=shape, distortion=distortion)


def load_camera(label: str | os.PathLike[str], kernels: str | os.PathLike[str] | "KernelSet",
                shape: Shape | None = None, distortion: bool = True) -> SensorModel:
    """The rigorous camera of an image from its label and kernels (one SPICE pass, then plain numpy).

    Parameters
    ----------
    label : path-like
        ISIS cube/label or PDS3 label (see :func:`lunarmap.orientation.drivers.image_support`).
    kernels : path-like or KernelSet
        Meta-kernel or kernel set.
    shape, distortion
        As for :func:`camera_from_isd`.

    Returns
    -------
    SensorModel
        The image's rigorous camera (as :func:`camera_from_isd` of its :func:`lunarmap.image_support`).
    """
    from ..orientation.drivers import image_support

    return camera_from_isd(image_support(label, kernels), shape=shape, distortion=distortion)
