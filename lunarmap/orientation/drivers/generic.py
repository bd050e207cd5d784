"""A driver configured from IK keywords, so a new instrument needs no code.

It reads ISIS-cube-style labels (``Instrument``: ``SpacecraftName``,
``StartTime`` or ``SpacecraftClockStartCount``, ``LineExposureDuration`` [ms]
for line scanners or ``ExposureDuration`` [ms] for framing cameras;
``Kernels``: ``NaifFrameCode``) and the standard NAIF/ISIS IK keywords
(``FOCAL_LENGTH``, ``ITRANSS``, ``ITRANSL``, ``BORESIGHT_SAMPLE``,
``BORESIGHT_LINE``, ``OD_K``) plus three optional lunarmap ones:

``INS<id>_LUNARMAP_CAMERA_TYPE``       ``'FRAME'`` or ``'LINESCAN'``
``INS<id>_LUNARMAP_DISTORTION``  ``'none'``, ``'radial'``, ``'lrolrocnac'`` or ``'kaguyalism'``
``INS<id>_LIGHTTIME_CORRECTION``       aberration correction of the position

``'kaguyalism'`` reads the Kaguya TC IK's keywords: ``DISTORTION_COEF_X`` and
``DISTORTION_COEF_Y`` (4 coefficients each, mm based) and the boresight
offsets from ``BORESIGHT`` scaled to the focal plane (``BORESIGHT[0:2] *
FOCAL_LENGTH / BORESIGHT[2]`` mm, which is ``BORESIGHT[0:2]`` itself in the
Kaguya IK, where ``BORESIGHT[2]`` is the focal length).

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
            if kind not in ("FRAME", "LINESCAN"):
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

    def image_times(self) -> tuple[float, float, float]:
        g = self.group("Instrument")
        start = self._start()
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
        if self.model == "frame":
            io["detector_center_line"] -= 0.5
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
