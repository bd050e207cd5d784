"""LRO LROC Wide Angle Camera (UV and VIS), a push-frame camera; ISIS cube labels (``lrowac2isis`` output).

Times, frames and constants follow USGS ALE's ``LroLrocWacIsisLabelNaifSpiceDriver`` (shared kernel
README 8.1):

* instrument ``LRO_LROCWAC_UV`` -85626 / ``LRO_LROCWAC_VIS`` -85621 (label ``InstrumentId``
  WAC-UV / WAC-VIS); the filter's IK code ``-85640 - n`` (UV) or ``-85628 - n`` (VIS) for the
  first of the label's ``BandBin/FilterNumber`` gives focal length, ``ITRANSS``/``ITRANSL``,
  boresight (minus 0.5: ISIS -> CSM pixels), ``FILTER_OFFSET`` (the starting detector line) and
  ``OD_K`` (radial distortion, sign flipped as ALE does);
* framelets of 16 detector lines summed 4x (UV) or 14 lines unsummed (VIS), ``DataFlipped`` ->
  ``framelets_flipped``, ``NumLinesOverlap`` (default 0);
* ``start = scs2e(SpacecraftClockStartCount) + ExposureDuration / 2``, ``stop = start + frames *
  InterframeDelay``, ``frames = lines // (framelet_height // summing)``; position and pointing at
  ``linspace(start, stop, lines + 1)``; sensor position without aberration correction (IAK).

One deliberate departure from ALE, recorded in the ISD's ``lunarmap`` block: the **starting detector
sample** is the IK's ``INS<filter>_<InstrumentModeId>_SAMPLE_OFFSET`` (264 detector samples for UV in
COLOR mode) where ALE writes 0. The UV framelets (128 samples summed 4x, 512 detector samples) are read
out from sample 264 on (ISIS's ``LroWideAngleCamera`` uses the offset); with ALE's 0 the image's
middle looks 27 degrees off the filter's boresight and outside the IK's field of view (tested against
``INS-85641_FOV_BOUNDARY_CORNERS``).
"""

from __future__ import annotations

from typing import Any

from ...errors import LabelError, UnknownInstrumentError
from ...labels import Label
from ...spice import queries as q
from ..isd_kinds import PushFrameTiming
from .base import Driver

__all__ = ["LroWacDriver"]

#: label InstrumentId -> (NAIF instrument id, filter code base, framelet height, summing)
_CAMERAS = {"WAC-UV": (-85626, -85640, 16, 4), "WAC-VIS": (-85621, -85628, 14, 1)}


class LroWacDriver(Driver):
    name = "lro_wac"
    model = "pushframe"
    isis_camera_version = 3

    @classmethod
    def matches(cls, label: Label) -> bool:
        inst = cls.isis_instrument(label)
        return inst is not None and str(inst.get("SpacecraftName", "")).upper() == "LUNAR RECONNAISSANCE ORBITER" \
            and str(inst.get("InstrumentId", "")).upper() in _CAMERAS

    @property
    def _camera(self) -> tuple[int, int, int, int]:
        return _CAMERAS[str(self.keyword("Instrument", "InstrumentId")).upper()]

    @property
    def ikid(self) -> int:
        return self._camera[0]

    @property
    def spacecraft_id(self) -> int:
        return -85

    @property
    def sensor_name(self) -> str:
        return str(self.keyword("Instrument", "SpacecraftName"))   # ALE's name (the spacecraft's)

    @property
    def filter_number(self) -> int:
        value = self.keyword("BandBin", "FilterNumber")
        first = value[0] if isinstance(value, list) and value else value
        return self.as_int(first, "BandBin/FilterNumber", minimum=1, maximum=7)

    @property
    def filter_ikid(self) -> int:
        """IK code of the filter (``INS<code>_*`` hold its focal length, focal plane and distortion)."""
        return self._camera[1] - self.filter_number

    def filter_ik(self, key: str) -> Any:
        name = f"INS{self.filter_ikid}_{key}"
        if not q.pool_has(name):
            raise UnknownInstrumentError(f"IK keyword {name} is not in the loaded kernels (WAC filter "
                                         f"{self.filter_number}, label {self.source})")
        values = q.pool_values(name)
        return values[0] if len(values) == 1 else values

    def check_instrument(self) -> None:
        self.filter_ik("FOCAL_LENGTH")

    def _seconds(self, key: str) -> float:
        """A label duration (``<ms>`` or no unit: milliseconds, as ALE reads it) in seconds."""
        value = self.keyword("Instrument", key)
        unit = str(getattr(value, "unit", "ms") or "ms").lower()
        scale = 1e-3 if unit in ("ms", "msec", "millisecond", "milliseconds") else 1.0
        return self.as_float(value, f"Instrument/{key}") * scale

    def _timing(self) -> PushFrameTiming:
        _, _, height, summing = self._camera
        overlap = self.as_int(self.group("Instrument").get("NumLinesOverlap", 0), "Instrument/NumLinesOverlap",
                              minimum=0)
        flipped = str(self.group("Instrument").get("DataFlipped", "No")).strip().lower() in ("yes", "true")
        start, stop, _ = self.image_times()
        return PushFrameTiming(exposure_duration=self._seconds("ExposureDuration"),
                               interframe_delay=self._seconds("InterframeDelay"), framelet_height=height,
                               framelets_flipped=flipped, framelet_order_reversed=False, num_lines_overlap=overlap,
                               ending_ephemeris_time=stop)

    def image_times(self) -> tuple[float, float, float]:
        _, _, height, summing = self._camera
        start = q.scs2e(self.spacecraft_id, str(self.keyword("Instrument", "SpacecraftClockStartCount")))
        start += 0.5 * self._seconds("ExposureDuration")
        frames = self.image_lines // (height // summing)
        return start, start + frames * self._seconds("InterframeDelay"), 0.0

    def sensor_keys(self) -> dict[str, Any]:
        timing = self._timing()
        _, _, _, summing = self._camera
        bad = timing.problem(self.image_lines, summing)
        if bad is not None:
            raise LabelError(f"label {self.source}: WAC framelets do not fit the image: {bad[0]} {bad[1]}")
        return {"push_frame": timing}

    def _sample_offset(self) -> float:
        mode = str(self.group("Instrument").get("InstrumentModeId", "")).strip().upper()
        if mode == "BW":
            mode = f"BW{self.as_int(self.group('Instrument').get('Mode', 0), 'Instrument/Mode', minimum=0)}"
        if not mode:
            raise LabelError(f"label {self.source} lacks Instrument/InstrumentModeId: the WAC readout window "
                             "(starting detector sample) depends on it")
        return float(self.filter_ik(f"{mode}_SAMPLE_OFFSET"))

    def interior(self) -> dict[str, Any]:
        _, _, _, summing = self._camera
        offset = self.filter_ik("FILTER_OFFSET")
        offset = offset[0] if isinstance(offset, list) else offset
        return {
            "focal_length": float(self.filter_ik("FOCAL_LENGTH")),
            "focal2pixel_lines": [float(v) for v in self.filter_ik("ITRANSL")],
            "focal2pixel_samples": [float(v) for v in self.filter_ik("ITRANSS")],
            "detector_center_line": float(self.filter_ik("BORESIGHT_LINE")) - 0.5,
            "detector_center_sample": float(self.filter_ik("BORESIGHT_SAMPLE")) - 0.5,
            "starting_detector_line": float(offset),
            "starting_detector_sample": self._sample_offset(),
            "line_summing": summing,
            "sample_summing": summing,
            "optical_distortion": {"radial": {"coefficients": [-float(v) for v in self.filter_ik("OD_K")]}},
        }

    def naif_keywords(self, body_frame_code: int) -> dict[str, Any]:
        out = super().naif_keywords(body_frame_code)
        # the filter's keywords, which hold the interior orientation (ALE adds every filter's)
        out.update({k: (v[0] if len(v) == 1 else v)
                    for k, v in q.instrument_keywords(self.filter_ikid).items()})
        return out

    def image_support(self) -> Any:
        isd = super().image_support()
        isd.provenance["starting_detector_sample"] = (
            "the IK's <mode>_SAMPLE_OFFSET of the filter (ALE writes 0, which puts UV framelets 27 degrees off "
            "the boresight)")
        return isd
