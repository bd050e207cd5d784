"""A driver configured from IK keywords, so a new instrument needs no code.

It reads ISIS-cube-style labels (``Instrument``: ``SpacecraftName``,
``StartTime`` or ``SpacecraftClockStartCount``, ``LineExposureDuration`` [ms]
for line scanners or ``ExposureDuration`` [ms] for framing cameras;
``Kernels``: ``NaifFrameCode``) and the standard NAIF/ISIS IK keywords
(``FOCAL_LENGTH``, ``ITRANSS``, ``ITRANSL``, ``BORESIGHT_SAMPLE``,
``BORESIGHT_LINE``, ``OD_K``) plus three optional lunarmap ones:

``INS<id>_LUNARMAP_CAMERA_TYPE``       ``'FRAME'``, ``'LINESCAN'`` or ``'PUSHFRAME'``
``INS<id>_LUNARMAP_DISTORTION``  ``'none'``, ``'radial'``, ``'lrolrocnac'`` or ``'kaguyalism'``
``INS<id>_LIGHTTIME_CORRECTION``       aberration correction of the position

``'kaguyalism'`` reads the Kaguya TC IK's keywords: ``DISTORTION_COEF_X`` and
``DISTORTION_COEF_Y`` (4 coefficients each, mm based) and the boresight
offsets from ``BORESIGHT`` scaled to the focal plane (``BORESIGHT[0:2] *
FOCAL_LENGTH / BORESIGHT[2]`` mm, which is ``BORESIGHT[0:2]`` itself in the
Kaguya IK, where ``BORESIGHT[2]`` is the focal length).

A push-frame camera (``'PUSHFRAME'``, an LRO-WAC-like stack of framelets) also reads
``INS<id>_FRAMELET_HEIGHT`` (detector lines of a framelet), ``INS<id>_SUMMING`` (line and
sample summing, default 1), ``INS<id>_LINE_OFFSET`` and ``INS<id>_SAMPLE_OFFSET`` (the readout
window's first detector line and sample, default 0; short names: SPICE pool names have at most 32
characters), and from the
label ``ExposureDuration`` and ``InterframeDelay`` [ms], ``DataFlipped`` and ``NumLinesOverlap``
(as ``lrowac2isis`` writes them); the label's start time is the first framelet's exposure start
(the ISD's ``starting_ephemeris_time``), its framelets follow every ``InterframeDelay``.

Boresight keywords are in the ISIS pixel convention (first pixel centre at 1)
and converted to CSM's by subtracting 0.5 on the sample axis (and on the line
axis for framing cameras; a line scanner's detector line is 0 by construction).
"""

from __future__ import annotations

from typing import Any

from ...errors import LabelError, UnknownInstrumentError
from ...labels import Label
from ...spice import queries as q
from .base import Driver

__all__ = ["GenericDriver"]


class GenericDriver(Driver):
    name = "generic"

    def __init__(self, label: Label, source: str = "") -> None:
        super().__init__(label, source)
        self._model: str | None = None

    @classmethod
    def matches(cls, label: Label) -> bool:
        cube = label.get("IsisCube")
        return cls.isis_instrument(label) is not None and "Kernels" in cube and "NaifFrameCode" in cube["Kernels"]

    @property
    def model(self) -> str:  # type: ignore[override]
        if self._model is None:
            kind = str(self.ik("LUNARMAP_CAMERA_TYPE", "")).upper()
            if kind not in ("FRAME", "LINESCAN", "PUSHFRAME"):
                kind = "LINESCAN" if "LineExposureDuration" in self.group("Instrument") else "FRAME"
            self._model = kind.lower()
        return self._model

    @property
    def sensor_name(self) -> str:
        g = self.group("Instrument")
        return str(g.get("InstrumentName", g.get("InstrumentId", self.ikid)))

    def _start(self) -> float:
        g = self.group("Instrument")
        if "SpacecraftClockStartCount" in g:
            return q.scs2e(self.spacecraft_id, str(g["SpacecraftClockStartCount"]))
        if "StartTime" in g:
            return q.str2et(str(g["StartTime"]))
        raise LabelError(f"label {self.source} has neither SpacecraftClockStartCount nor StartTime")

    def _seconds(self, key: str, default: Any = None) -> float:
        """A label duration in milliseconds (``<ms>`` or no unit), in seconds."""
        g = self.group("Instrument")
        value = g.get(key, default) if default is not None else self.keyword("Instrument", key)
        return self.as_float(value, f"Instrument/{key}") * 1e-3

    @property
    def _summing(self) -> int:
        return self.as_int(self.ik("SUMMING", 1), f"INS{self.ikid}_SUMMING", minimum=1)

    def _push_frame(self) -> Any:
        from ..isd_kinds import PushFrameTiming

        g = self.group("Instrument")
        height = self.as_int(self.ik("FRAMELET_HEIGHT"), f"INS{self.ikid}_FRAMELET_HEIGHT",
                             minimum=1)
        overlap = self.as_int(g.get("NumLinesOverlap", 0), "Instrument/NumLinesOverlap", minimum=0)
        flipped = str(g.get("DataFlipped", "No")).strip().lower() in ("yes", "true")
        _, stop, _ = self.image_times()
        return PushFrameTiming(exposure_duration=self._seconds("ExposureDuration"),
                               interframe_delay=self._seconds("InterframeDelay"), framelet_height=height,
                               framelets_flipped=flipped, framelet_order_reversed=False, num_lines_overlap=overlap,
                               ending_ephemeris_time=stop)

    def sensor_keys(self) -> dict[str, Any]:
        if self.model != "pushframe":
            return {}
        timing = self._push_frame()
        bad = timing.problem(self.image_lines, self._summing)
        if bad is not None:
            raise LabelError(f"label {self.source}: the framelets do not fit the image: {bad[0]} {bad[1]}")
        return {"push_frame": timing}

    def image_times(self) -> tuple[float, float, float]:
        g = self.group("Instrument")
        start = self._start()
        if self.model == "pushframe":
            height = self.as_int(self.ik("FRAMELET_HEIGHT"), f"INS{self.ikid}_FRAMELET_HEIGHT",
                                 minimum=1)
            lines = max(1, height // self._summing)
            frames = -(-self.image_lines // lines)
            return start, start + frames * self._seconds("InterframeDelay"), 0.0
        # each value is read by a named accessor: a catch-all here once reported a missing image size
        # as a "malformed exposure keyword"
        if self.model == "linescan":
            dt = self.as_float(self.keyword("Instrument", "LineExposureDuration"), "LineExposureDuration") * 1e-3
            return start, start + self.image_lines * dt, dt
        exposure = self.as_float(g.get("ExposureDuration", 0.0), "ExposureDuration") * 1e-3
        return start, start + exposure, 0.0

    def interior(self) -> dict[str, Any]:
        io = super().interior()
        io["detector_center_sample"] -= 0.5
        if self.model in ("frame", "pushframe"):
            io["detector_center_line"] -= 0.5
        if self.model == "pushframe":
            io["line_summing"] = io["sample_summing"] = self._summing
            io["starting_detector_line"] = float(self.ik("LINE_OFFSET", 0.0))
            io["starting_detector_sample"] = float(self.ik("SAMPLE_OFFSET", 0.0))
        dist = str(self.ik("LUNARMAP_DISTORTION", "none")).lower()
        if dist == "lrolrocnac":
            k = self.ik("OD_K")
            io["optical_distortion"] = {"lrolrocnac": {"coefficients": [float(k if not isinstance(k, list) else k[0])]}}
        elif dist == "radial":
            io["optical_distortion"] = {"radial": {"coefficients": [float(v) for v in self.ik("OD_K")]}}
        elif dist == "kaguyalism":
            io["optical_distortion"] = {"kaguyalism": self._kaguyalism(io["focal_length"])}
        elif dist == "none":
            io["optical_distortion"] = {"radial": {"coefficients": [0.0, 0.0, 0.0]}}
        else:
            raise UnknownInstrumentError(f"INS{self.ikid}_LUNARMAP_DISTORTION = {dist!r} is not a distortion model "
                                         f"lunarmap knows ('none', 'radial', 'lrolrocnac', 'kaguyalism')")
        return io

    def _kaguyalism(self, focal_length: float) -> dict[str, Any]:
        """ALE's ``kaguyalism`` block from the IK (coefficients, boresight offsets in mm)."""
        bore = self.ik("BORESIGHT", [0.0, 0.0, 1.0])
        if not isinstance(bore, list) or len(bore) != 3 or float(bore[2]) == 0.0:
            raise UnknownInstrumentError(f"INS{self.ikid}_BORESIGHT must be 3 numbers with a non-zero third one "
                                         f"for the kaguyalism distortion (label {self.source}), got {bore!r}")
        scale = focal_length / float(bore[2])
        return {"x": [float(v) for v in self.ik("DISTORTION_COEF_X")],
                "y": [float(v) for v in self.ik("DISTORTION_COEF_Y")],
                "boresight_x": float(bore[0]) * scale, "boresight_y": float(bore[1]) * scale}
