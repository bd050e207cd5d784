"""Kaguya (SELENE) Terrain Cameras TC1/TC2, PDS3 level-2B0 labels.

Follows ALE's ``KaguyaTcPds3NaifSpiceDriver`` (shared kernel README 5.1, 5.2, 7):
start from ``CORRECTED_SC_CLOCK_START_COUNT`` used as encoded SCLK (``sct2e``),
line period ``CORRECTED_SAMPLING_INTERVAL``, sensor position with ISIS's
light-time-to-the-surface correction, sensor frame ``LISM_TC<n>_HEAD``, IK keys
of ``LISM_TC<n>``, focal2pixel from ``PIXEL_SIZE``, starting detector sample
``FIRST_PIXEL_NUMBER - 0.5`` and line 1, distortion ``kaguyalism``.
"""

from __future__ import annotations

from typing import Any

from ...labels import Label
from ...spice import queries as q
from .base import Driver

__all__ = ["KaguyaTcDriver", "KaguyaMiDriver"]


class KaguyaTcDriver(Driver):
    name = "kaguya_tc"
    model = "linescan"
    isis_camera_version = 2

    @classmethod
    def matches(cls, label: Label) -> bool:
        return str(label.get("MISSION_NAME", "")) == "SELENE" and str(label.get("INSTRUMENT_ID", "")) in ("TC1", "TC2")

    @property
    def _tc(self) -> str:
        return str(self.label["INSTRUMENT_ID"])

    @property
    def ikid(self) -> int:
        return q.body_code(f"LISM_{self._tc}")

    @property
    def sensor_frame(self) -> int:
        return q.frame_id(f"LISM_{self._tc}_HEAD")

    @property
    def spacecraft_id(self) -> int:
        return q.body_code(str(self.label["MISSION_NAME"]))

    @property
    def platform_name(self) -> str:
        return str(self.label["MISSION_NAME"])

    @property
    def sensor_name(self) -> str:
        return str(self.label["INSTRUMENT_ID"])

    def position_correction(self) -> str:
        return "SURFACE"

    def image_times(self) -> tuple[float, float, float]:
        clock = self.as_float(self.value_at("CORRECTED_SC_CLOCK_START_COUNT"), "CORRECTED_SC_CLOCK_START_COUNT")
        interval = self.value_at("CORRECTED_SAMPLING_INTERVAL")
        interval = interval[0] if isinstance(interval, list) and interval else interval
        dt = self.as_float(interval, "CORRECTED_SAMPLING_INTERVAL") * 1e-3
        start = q.sct2e(self.spacecraft_id, clock)
        return start, start + self.image_lines * dt, dt

    def interior(self) -> dict[str, Any]:
        pixel = self.ik("PIXEL_SIZE")
        pixel = float(pixel[0] if isinstance(pixel, list) else pixel)
        bore = self.ik("BORESIGHT")
        return {
            "focal_length": float(self.ik("FOCAL_LENGTH")),
            "focal2pixel_lines": [0.0, 1.0 / pixel, 0.0],
            "focal2pixel_samples": [0.0, 0.0, -1.0 / pixel],
            "detector_center_line": float(self.ik("BORESIGHT_LINE")),
            "detector_center_sample": float(self.ik("BORESIGHT_SAMPLE")),
            "starting_detector_line": 1.0,
            "starting_detector_sample": self.as_float(self.value_at("FIRST_PIXEL_NUMBER"), "FIRST_PIXEL_NUMBER") - 0.5,
            "line_summing": 1,
            "sample_summing": 1,
            "optical_distortion": {"kaguyalism": {
                "x": [float(v) for v in self.ik("DISTORTION_COEF_X")],
                "y": [float(v) for v in self.ik("DISTORTION_COEF_Y")],
                "boresight_x": float(bore[0]), "boresight_y": float(bore[1])}},
        }


class KaguyaMiDriver(Driver):
    """Kaguya Multiband Imager (VIS or NIR), ISIS cube labels; ALE's ``KaguyaMiIsisLabelNaifSpiceDriver``.

    Instrument = label ``NaifFrameCode`` (e.g. -131341 LISM_MI-NIR1, the base band), sensor frame
    ``LISM_MI_<V|N>_HEAD``; ``start = str2et(StartTime)`` (UTC, not the clock counts), line period
    ``CorrectedSamplingInterval`` (ms, not LineExposureDuration); detector centre ``INS<id>_CENTER - 0.5``;
    focal plane ``[0, 1/p, 0]`` / ``[0, 0, -1/p]`` with ``p = PIXEL_SIZE``; ``kaguyalism`` distortion;
    ``LT+S`` without surface correction (the MI IK has no ISIS light-time keywords, unlike TC's).
    """

    name = "kaguya_mi"
    model = "linescan"
    isis_camera_version = 2

    @classmethod
    def matches(cls, label: Label) -> bool:
        inst = cls.isis_instrument(label)
        return inst is not None and str(inst.get("SpacecraftName", "")).upper() in ("KAGUYA", "SELENE") and \
            str(inst.get("InstrumentId", "")).upper() in ("MI-VIS", "MI-NIR")

    @property
    def _spectra(self) -> str:
        return "V" if str(self.keyword("Instrument", "InstrumentId")).upper() == "MI-VIS" else "N"

    @property
    def sensor_frame(self) -> int:
        return q.frame_id(f"LISM_MI_{self._spectra}_HEAD")

    @property
    def spacecraft_id(self) -> int:
        return -131

    @property
    def sensor_name(self) -> str:
        return str(self.keyword("Instrument", "InstrumentId"))

    def image_times(self) -> tuple[float, float, float]:
        interval = self.keyword("Instrument", "CorrectedSamplingInterval")
        interval = interval[0] if isinstance(interval, list) and interval else interval
        dt = self.as_float(interval, "Instrument/CorrectedSamplingInterval") * 1e-3
        start = q.str2et(str(self.keyword("Instrument", "StartTime")))
        return start, start + self.image_lines * dt, dt

    def interior(self) -> dict[str, Any]:
        pixel = self.ik("PIXEL_SIZE")
        pixel = float(pixel[0] if isinstance(pixel, list) else pixel)
        centre = self.ik("CENTER")
        bore = self.ik("BORESIGHT")
        return {
            "focal_length": float(self.ik("FOCAL_LENGTH")),
            "focal2pixel_lines": [0.0, 1.0 / pixel, 0.0],
            "focal2pixel_samples": [0.0, 0.0, -1.0 / pixel],
            "detector_center_line": float(centre[1]) - 0.5,
            "detector_center_sample": float(centre[0]) - 0.5,
            "starting_detector_line": 0.0,
            "starting_detector_sample": 0.0,
            "line_summing": 1,
            "sample_summing": 1,
            "optical_distortion": {"kaguyalism": {
                "x": [float(v) for v in self.ik("DISTORTION_COEF_X")],
                "y": [float(v) for v in self.ik("DISTORTION_COEF_Y")],
                "boresight_x": float(bore[0]), "boresight_y": float(bore[1])}},
        }
