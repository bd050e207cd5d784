"""LRO LROC Narrow Angle Cameras (left and right), ISIS cube labels.

Times and constants follow USGS ALE's ``LroLrocNacIsisLabelNaifSpiceDriver``
(shared kernel README, sections 5.1 and 7):

* line period ``dt = LineExposureDuration * (1 + MULTIPLI_LINE_ERROR) + ADDITIVE_LINE_ERROR``;
* start ``= scs2e(-85, SpacecraftClockPrerollCount) + CONSTANT_TIME_OFFSET + ADDITIONAL_PREROLL * dt``;
* sensor position without aberration correction;
* ``focal2pixel_lines`` negated when the spacecraft flies backwards (x of the
  velocity in LRO_SC_BUS negative): LRO yaws 180 degrees twice a year;
* detector centre sample ``= BORESIGHT_SAMPLE - 0.5`` (ISIS -> CSM pixel convention);
* distortion ``lrolrocnac`` with ``OD_K``.
"""

from __future__ import annotations

from typing import Any


from ...errors import LabelError
from ...labels import Label
from ...spice import queries as q
from .base import Driver

__all__ = ["LroNacDriver"]

_FRAMES = {"NACL": -85600, "NACR": -85610}


class LroNacDriver(Driver):
    name = "lro_nac"
    model = "linescan"
    isis_camera_version = 2

    @classmethod
    def matches(cls, label: Label) -> bool:
        inst = cls.isis_instrument(label)
        return inst is not None and str(inst.get("InstrumentHostId", "")) == "LRO" and \
            str(inst.get("InstrumentId", "")) in _FRAMES

    @property
    def ikid(self) -> int:
        iid = str(self.keyword("Instrument", "InstrumentId"))
        return _FRAMES[iid]

    @property
    def spacecraft_id(self) -> int:
        return -85

    @property
    def sensor_name(self) -> str:
        return str(self.keyword("Instrument", "InstrumentName"))

    @property
    def platform_name(self) -> str:
        return str(self.keyword("Instrument", "SpacecraftName"))

    def position_correction(self) -> str:
        return "NONE"  # ALE's LRO driver overrides the IAK (README 5.2)

    def image_times(self) -> tuple[float, float, float]:
        exposure_ms = self.keyword("Instrument", "LineExposureDuration")
        try:
            exposure = float(exposure_ms) * 1e-3
        except (TypeError, ValueError) as err:
            raise LabelError(f"label {self.source}: LineExposureDuration is not a number") from err
        dt = exposure * (1.0 + float(self.ik("MULTIPLI_LINE_ERROR", 0.0))) + float(self.ik("ADDITIVE_LINE_ERROR", 0.0))
        preroll = q.scs2e(self.spacecraft_id, str(self.keyword("Instrument", "SpacecraftClockPrerollCount")))
        start = preroll + float(self.ik("CONSTANT_TIME_OFFSET", 0.0)) + float(self.ik("ADDITIONAL_PREROLL", 0.0)) * dt
        return start, start + self.image_lines * dt, dt

    def spacecraft_direction(self, et: float) -> float:
        """x component (km/s) of the spacecraft velocity in LRO_SC_BUS at ``et``."""
        vel = q.states(self.spacecraft_id, [et], "J2000", "NONE", self.target_id)[0, 3:]
        rot = q.rotations("J2000", "LRO_SC_BUS", [et])[0]
        return float((rot @ vel)[0])

    def interior(self) -> dict[str, Any]:
        io = super().interior()
        start, _, _ = self.image_times()
        if self.spacecraft_direction(start) < 0:
            io["focal2pixel_lines"] = [-v for v in io["focal2pixel_lines"]]
        io["detector_center_sample"] = float(self.ik("BORESIGHT_SAMPLE")) - 0.5
        summing = int(self.group("Instrument").get("SpatialSumming", 1))
        io["line_summing"] = io["sample_summing"] = summing
        io["starting_detector_sample"] = float(self.group("Instrument").get("SampleFirstPixel", 0))
        io["optical_distortion"] = {"lrolrocnac": {"coefficients": [float(self.ik("OD_K"))]}}
        return io
