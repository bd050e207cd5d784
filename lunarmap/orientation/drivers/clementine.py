"""Clementine UVVIS framing camera (filters A-F), ISIS cube labels.

Times follow ALE (``start = str2et(StartTime)``, exposure from
``ExposureDuration``, one epoch at mid-exposure). Interior orientation departs
from ALE on purpose, and says so in the ISD's ``lunarmap`` block:

* ALE leaves the UVVIS distortion-free; ISIS models it with the IK's ``OD_K``
  through ``CameraDistortionMap`` (``undistorted = distorted * (1 - (k0 + k1 r^2 + k2 r^4))``),
  which is usgscsm's ``radial`` model with the same coefficients - used here.
* ALE copies ``BORESIGHT_SAMPLE/LINE`` (ISIS pixel convention, first pixel
  centre at 1) into the CSM detector centre, half a pixel off; here 0.5 is
  subtracted as ALE's LRO, MRO and Dawn drivers do.
"""

from __future__ import annotations

from typing import Any

from ...labels import Label
from ...spice import queries as q
from .base import Driver

__all__ = ["ClementineUvvisDriver"]


class ClementineUvvisDriver(Driver):
    name = "clementine_uvvis"
    model = "frame"
    isis_camera_version = 1

    @classmethod
    def matches(cls, label: Label) -> bool:
        inst = cls.isis_instrument(label)
        return inst is not None and str(inst.get("SpacecraftName", "")).upper().startswith("CLEMENTINE") and \
            str(inst.get("InstrumentId", "")) == "UVVIS"

    @property
    def spacecraft_id(self) -> int:
        return -40

    @property
    def platform_name(self) -> str:
        return str(self.keyword("Instrument", "SpacecraftName")).replace(" ", "_")

    def image_times(self) -> tuple[float, float, float]:
        start = q.str2et(str(self.keyword("Instrument", "StartTime")))
        exposure = self.as_float(self.keyword("Instrument", "ExposureDuration"), "ExposureDuration") * 1e-3
        return start, start + exposure, 0.0

    def interior(self) -> dict[str, Any]:
        io = super().interior()
        io["detector_center_line"] -= 0.5
        io["detector_center_sample"] -= 0.5
        io["optical_distortion"] = {"radial": {"coefficients": [float(v) for v in self.ik("OD_K")]}}
        return io
