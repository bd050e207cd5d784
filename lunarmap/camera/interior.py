"""Interior orientation: detector geometry, focal plane and distortion.

Pixel convention (the one of USGS CSM / usgscsm): image coordinates
``(line, sample)`` are continuous; the **centre** of the first pixel is
``(0.5, 0.5)`` and the image's outer corner is ``(0, 0)``. ISIS puts that
centre at ``(1, 1)``: ``isis = csm + 0.5``.

Focal-plane coordinates ``(x, y)`` are millimetres in the sensor frame's
x-y plane (the NAIF instrument frame, boresight along +z); the look vector of
an undistorted focal-plane point in the sensor frame is ``(x, y, f)``.
``focal2pixel_lines`` / ``focal2pixel_samples`` are the affine transforms
of ALE's ISD (pixels per mm): ``detector_line = a0 + a1*x + a2*y`` measured from
``detector_center_line``; the same for samples.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

__all__ = ["InteriorOrientation"]


@dataclass(frozen=True)
class InteriorOrientation:
    """Camera constants of one image (frame or line-scan).

    Parameters
    ----------
    focal_length : float
        Focal length, millimetres. Negative for a camera that looks along ``-z`` of its sensor frame
        (ISIS's focal-plane z direction -1: Lunar Orbiter and Apollo metric); the look vector is
        ``(x, y, f)`` either way.
    focal2pixel_lines, focal2pixel_samples : tuple of 3 float
        Affine focal-plane (mm) to detector (pixels) coefficients, as in ALE's ISD.
    detector_center_line, detector_center_sample : float
        Detector position of the principal point, pixels (CSM convention).
    n_lines, n_samples : int
        Image size, pixels.
    starting_detector_line, starting_detector_sample : float
        Detector coordinate of the image's first line / sample (cropped or
        windowed readouts), pixels.
    line_summing, sample_summing : int
        Detector pixels summed into one image pixel.
    distortion_model : str
        ``"none"``, ``"radial"`` (ISIS/Clementine ``OD_K`` polynomial),
        ``"lrolrocnac"`` (LRO NAC ``k1``) or ``"kaguyalism"``; the names of ALE's ISD.
    distortion_coefficients : mapping
        Coefficients keyed as in ALE's ``optical_distortion`` block (mm-based).
    pixel_pitch : float
        Detector pixel pitch, millimetres (informational).
    name : str
        Instrument name, for messages.
    """

    focal_length: float
    focal2pixel_lines: tuple[float, float, float]
    focal2pixel_samples: tuple[float, float, float]
    detector_center_line: float
    detector_center_sample: float
    n_lines: int
    n_samples: int
    starting_detector_line: float = 0.0
    starting_detector_sample: float = 0.0
    line_summing: int = 1
    sample_summing: int = 1
    distortion_model: str = "none"
    distortion_coefficients: Mapping[str, Any] = field(default_factory=dict)
    pixel_pitch: float = float("nan")
    name: str = ""

    @property
    def pixel2focal(self) -> np.ndarray:
        """2x3 matrix ``[[x0, xl, xs], [y0, yl, ys]]`` inverting the focal2pixel affine.

        ``(x, y) = M @ (1, dline, dsample)`` where ``dline``/``dsample`` are
        detector coordinates relative to the detector centre, pixels; result mm.
        """
        a = np.array([[self.focal2pixel_lines[1], self.focal2pixel_lines[2]],
                      [self.focal2pixel_samples[1], self.focal2pixel_samples[2]]])
        inv = np.linalg.inv(a)
        off = -inv @ np.array([self.focal2pixel_lines[0], self.focal2pixel_samples[0]])
        return np.column_stack([off, inv])
