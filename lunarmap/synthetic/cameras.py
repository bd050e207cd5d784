"""The two cameras of the synthetic mission: an LRO-NAC-like pushbroom and a Clementine-UVVIS-like frame camera."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from . import ids

__all__ = ["CameraSpec", "NAC", "FRAME_CAMERA"]


@dataclass(frozen=True)
class CameraSpec:
    """Interior geometry of one camera as written into its IK.

    Parameters
    ----------
    name : str
        Instrument (and frame) name.
    naif_id : int
        Instrument id, which is also its frame id.
    camera_type : str
        ``'LINESCAN'`` or ``'FRAME'``.
    samples, lines : int
        Detector size, pixels.
    focal_length_mm, pixel_pitch_mm : float
        mm.
    boresight_sample, boresight_line : float
        Principal point, ISIS pixel convention (first pixel centre is 1.0).
    transx, transy : tuple of 3 float
        Pixel (1, sample, line offsets from the boresight) to focal plane, mm.
    distortion_model : str
        lunarmap / ALE distortion model name.
    od_k : tuple of float
        Distortion coefficients.
    description : str
        One line for the IK comments.
    """

    name: str
    naif_id: int
    camera_type: str
    samples: int
    lines: int
    focal_length_mm: float
    pixel_pitch_mm: float
    boresight_sample: float
    boresight_line: float
    transx: tuple[float, float, float]
    transy: tuple[float, float, float]
    distortion_model: str
    od_k: tuple[float, ...]
    description: str

    @property
    def frame_name(self) -> str:
        """The instrument's NAIF frame name."""
        return self.name

    @property
    def ifov(self) -> float:
        """Angular size of one pixel, rad."""
        return self.pixel_pitch_mm / self.focal_length_mm

    @property
    def itranss(self) -> tuple[float, float, float]:
        """Focal plane (1, x, y) mm to sample offset, pixels: the inverse of TRANSX/TRANSY."""
        return self._inverse()[0]

    @property
    def itransl(self) -> tuple[float, float, float]:
        """Focal plane (1, x, y) mm to line offset, pixels."""
        return self._inverse()[1]

    def _inverse(self) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        a = np.array([[self.transx[1], self.transx[2]], [self.transy[1], self.transy[2]]])
        off = np.array([self.transx[0], self.transy[0]])
        inv = np.linalg.inv(a)  # rows: sample, line as functions of (x, y)
        c = -inv @ off
        return ((float(c[0]) + 0.0, float(inv[0, 0]) + 0.0, float(inv[0, 1]) + 0.0),
                (float(c[1]) + 0.0, float(inv[1, 0]) + 0.0, float(inv[1, 1]) + 0.0))

    def focal_plane(self, sample: NDArray[np.float64], line: NDArray[np.float64]) -> NDArray[np.float64]:
        """Undistorted focal-plane ``(x, y)`` (mm) of ISIS pixel coordinates, shape (..., 2)."""
        ds = np.asarray(sample, float) - self.boresight_sample
        dl = np.asarray(line, float) - self.boresight_line
        x = self.transx[0] + self.transx[1] * ds + self.transx[2] * dl
        y = self.transy[0] + self.transy[1] * ds + self.transy[2] * dl
        return np.stack([x, y], axis=-1)

    def fov_corners(self) -> NDArray[np.float64]:
        """Four FOV corner vectors ``(x/f, y/f, 1)`` at the detector's outer pixel edges, shape (4, 3)."""
        if self.lines == 1:
            # a single detector line: half a pixel either side of the boresight line
            top, bottom = self.boresight_line - 0.5, self.boresight_line + 0.5
        else:
            top, bottom = 0.5, self.lines + 0.5
        s = np.array([0.5, self.samples + 0.5, self.samples + 0.5, 0.5])
        ln = np.array([top, top, bottom, bottom])
        xy = self.focal_plane(s, ln) / self.focal_length_mm
        return np.column_stack([xy, np.ones(4)])

_NAC_PITCH = 0.007
#: LRO NAC-Left-like pushbroom: the detector line runs along the frame's +y axis
#: (sample), time/lines along +x, as in LRO's IK (TRANSX=(0,0,p), TRANSY=(0,p,0)).
NAC = CameraSpec(
    name=ids.NAC_NAME, naif_id=ids.NAC_ID, camera_type="LINESCAN", samples=5064, lines=1,
    focal_length_mm=699.62, pixel_pitch_mm=_NAC_PITCH, boresight_sample=2548.0, boresight_line=0.0,
    transx=(0.0, 0.0, _NAC_PITCH), transy=(0.0, _NAC_PITCH, 0.0),
    distortion_model="lrolrocnac", od_k=(1.81e-5,),
    description="pushbroom, 5064 samples, f = 699.62 mm, 7 um pixels (like LRO NAC-L).",
)

_FRAME_PITCH = 0.023
#: Clementine-UVVIS-like framing camera: samples along +x, lines along +y.
FRAME_CAMERA = CameraSpec(
    name=ids.FRAME_CAMERA_NAME, naif_id=ids.FRAME_CAMERA_ID, camera_type="FRAME", samples=384, lines=288,
    focal_length_mm=89.874, pixel_pitch_mm=_FRAME_PITCH, boresight_sample=192.5, boresight_line=144.5,
    transx=(0.0, _FRAME_PITCH, 0.0), transy=(0.0, 0.0, _FRAME_PITCH),
    distortion_model="radial", od_k=(0.0, -2.42e-5, 0.0),
    description="framing, 384 x 288 pixels, f = 89.874 mm, 23 um pixels (like Clementine UVVIS).",
)
