"""Clementine framing cameras: UVVIS (filters A-F), HIRES, NIR, LWIR; ISIS cube labels.

Times follow ALE's ``ClementineIsisLabelNaifSpiceDriver`` (``start = str2et(StartTime)``, exposure
from ``ExposureDuration``, one epoch at mid-exposure); instrument = label ``NaifFrameCode``; pointing of
``CLEM_SC_BUS`` and the camera's frame. Aberration correction: the IAK's (UVVIS: ``NONE`` + swap); the
HIRES, NIR and LWIR IAKs have none, so ``LT+S`` (shared kernel README 8.8-8.10). Focal length from the
IAK, except NIR: ALE's per-filter focal lengths in pixels times the 0.038 mm pitch.

Interior orientation departs from ALE on purpose, and says so in the ISD's ``lunarmap`` block:

* ALE leaves the UVVIS distortion-free; ISIS models it with the IK's ``OD_K`` through
  ``CameraDistortionMap`` (``undistorted = distorted * (1 - (k0 + k1 r^2 + k2 r^4))``),
  which is usgscsm's ``radial`` model with the same coefficients - used here. The HIRES, NIR and
  LWIR IAKs give no ``OD_K``: no distortion, as ALE.
* ALE copies ``BORESIGHT_SAMPLE/LINE`` (ISIS pixel convention, first pixel
  centre at 1) into the CSM detector centre, half a pixel off; here 0.5 is
  subtracted as ALE's LRO, MRO and Dawn drivers do.
"""

from __future__ import annotations

from typing import Any

from ...errors import LabelError
from ...labels import Label
from ...spice import queries as q
from .base import Driver

__all__ = ["ClementineDriver", "ClementineUvvisDriver"]

#: ALE's NIR focal lengths per filter, pixels (ClementineIsisLabelNaifSpiceDriver)
_NIR_FOCAL_PX = {"A": 2548.2642, "B": 2530.8958, "C": 2512.6589, "D": 2509.0536, "E": 2490.7378, "F": 2487.8694}
_NIR_PITCH_MM = 0.038
_CAMERAS = ("UVVIS", "HIRES", "NIR", "LWIR")


class ClementineDriver(Driver):
    name = "clementine"
    model = "frame"
    isis_camera_version = 1

    @classmethod
    def matches(cls, label: Label) -> bool:
        inst = cls.isis_instrument(label)
        return inst is not None and str(inst.get("SpacecraftName", "")).upper().startswith("CLEMENTINE") and \
            str(inst.get("InstrumentId", "")).upper() in _CAMERAS

    @property
    def camera(self) -> str:
        return str(self.keyword("Instrument", "InstrumentId")).upper()

    @property
    def spacecraft_id(self) -> int:
        return -40

    @property
    def platform_name(self) -> str:
        return str(self.keyword("Instrument", "SpacecraftName")).replace(" ", "_")

    def check_instrument(self) -> None:
        if self.camera != "NIR":   # NIR's focal length is not in the IAK (ALE's table)
            super().check_instrument()

    def image_times(self) -> tuple[float, float, float]:
        start = q.str2et(str(self.keyword("Instrument", "StartTime")))
        exposure = self.as_float(self.keyword("Instrument", "ExposureDuration"), "ExposureDuration") * 1e-3
        return start, start + exposure, 0.0

    def _focal_length(self) -> float:
        if self.camera != "NIR":
            return float(self.ik("FOCAL_LENGTH"))
        band = str(self.keyword("BandBin", "FilterName")).strip().upper()
        if band not in _NIR_FOCAL_PX:
            raise LabelError(f"label {self.source}: Clementine NIR filter {band!r} is not one of A-F")
        return _NIR_FOCAL_PX[band] * _NIR_PITCH_MM

    def interior(self) -> dict[str, Any]:
        io = {
            "focal_length": self._focal_length(),
            "focal2pixel_lines": [float(v) for v in self.ik("ITRANSL")],
            "focal2pixel_samples": [float(v) for v in self.ik("ITRANSS")],
            "detector_center_line": float(self.ik("BORESIGHT_LINE")) - 0.5,
            "detector_center_sample": float(self.ik("BORESIGHT_SAMPLE")) - 0.5,
            "starting_detector_line": 0.0,
            "starting_detector_sample": 0.0,
            "line_summing": 1,
            "sample_summing": 1,
            "optical_distortion": {"radial": {"coefficients": [0.0, 0.0, 0.0]}},
        }
        if q.pool_has(f"INS{self.ikid}_OD_K"):
            io["optical_distortion"] = {"radial": {"coefficients": [float(v) for v in self.ik("OD_K")]}}
        return io

    def image_support(self) -> Any:
        isd = super().image_support()
        isd.provenance["detector_center"] = "BORESIGHT - 0.5 (ISIS -> CSM pixels; ALE copies the ISIS value)"
        return isd


#: The UVVIS driver of earlier versions: every Clementine camera is now :class:`ClementineDriver`.
ClementineUvvisDriver = ClementineDriver
