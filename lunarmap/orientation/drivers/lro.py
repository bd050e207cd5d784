"""LRO LROC Narrow Angle Cameras (left and right): ISIS cube labels and PDS3 EDR labels.

Times and constants follow USGS ALE's ``LroLrocNacIsisLabelNaifSpiceDriver`` and
``LroLrocNacPds3LabelNaifSpiceDriver`` (shared kernel README, sections 5.1 and 7):

* line period ``dt = LineExposureDuration * (1 + MULTIPLI_LINE_ERROR) + ADDITIVE_LINE_ERROR``;
* start ``= scs2e(-85, SpacecraftClockPrerollCount) + CONSTANT_TIME_OFFSET + ADDITIONAL_PREROLL * dt``;
* sensor position without aberration correction;
* ``focal2pixel_lines`` negated when the spacecraft flies backwards (x of the
  velocity in LRO_SC_BUS negative): LRO yaws 180 degrees twice a year;
* detector centre sample ``= BORESIGHT_SAMPLE - 0.5`` (ISIS -> CSM pixel convention);
* distortion ``lrolrocnac`` with ``OD_K``.

Both label kinds go through :class:`_LroNac`; the two drivers differ only in
where they read the handful of label values. The PDS3 driver reads them the way
ISIS's ``lronac2isis`` translates them (``FRAME_ID`` LEFT/RIGHT -> NACL/NACR and
NAIF frame -85600/-85610, ``LRO:SPACECRAFT_CLOCK_PREROLL_COUNT`` ->
``SpacecraftClockPrerollCount``, ``CROSSTRACK_SUMMING`` -> ``SpatialSumming``,
``SampleFirstPixel`` = 0), so an EDR and the cube ``lronac2isis`` makes of it get
the same ISD. The sensor name is ISIS's (``... NARROW ANGLE CAMERA LEFT``), not the
EDR's ``INSTRUMENT_NAME`` (``LUNAR RECONNAISSANCE ORBITER CAMERA``, which ALE's PDS3
driver copies): the EDR name does not say which of the two cameras took the image.
"""

from __future__ import annotations

from typing import Any

from ...errors import LabelError, UnknownInstrumentError
from ...labels import Label
from ...spice import queries as q
from .base import Driver

__all__ = ["LroNacDriver", "LroNacPds3Driver"]

_FRAMES = {"NACL": -85600, "NACR": -85610}
#: PDS3 ``FRAME_ID`` -> ISIS ``InstrumentId`` (lronac2isis's translation)
_PDS3_FRAMES = {"LEFT": "NACL", "RIGHT": "NACR"}
#: NAC-R EDRs older than this product version store their samples mirrored;
#: lronac2isis flips them, so the camera model describes the flipped image.
_NACR_FLIP_BEFORE = 1.30


class _LroNac(Driver):
    """Everything the LRO NAC drivers share; subclasses supply the label values."""

    model = "linescan"
    isis_camera_version = 2

    # -- label values (per label kind) -------------------------------------------
    @property
    def nac(self) -> str:
        """``"NACL"`` or ``"NACR"``."""
        raise NotImplementedError

    def line_exposure(self) -> Any:
        """Label value of the line exposure duration (ms)."""
        raise NotImplementedError

    def preroll_count(self) -> str:
        """Spacecraft clock count of the preroll (``"1/270649237:07208"``)."""
        raise NotImplementedError

    def summing(self) -> Any:
        """Label value of the cross-track (spatial) summing."""
        raise NotImplementedError

    def sample_first_pixel(self) -> Any:
        """Label value of the first detector sample read out (0-based)."""
        raise NotImplementedError

    # -- shared -------------------------------------------------------------------
    @property
    def ikid(self) -> int:
        return _FRAMES[self.nac]

    @property
    def spacecraft_id(self) -> int:
        return -85

    def position_correction(self) -> str:
        return "NONE"  # ALE's LRO driver overrides the IAK (README 5.2)

    def _line_exposure_s(self) -> float:
        value = self.line_exposure()
        unit = str(getattr(value, "unit", "ms")).lower()
        if unit not in ("ms", "msec", "millisecond", "milliseconds"):
            raise LabelError(f"label {self.source}: line exposure duration is in {unit!r}, expected ms")
        try:
            return float(value) * 1e-3
        except (TypeError, ValueError) as err:
            raise LabelError(f"label {self.source}: line exposure duration {value!r} is not a number") from err

    def _summing(self) -> int:
        value = self.summing()
        try:
            summing = int(value)
            if isinstance(value, bool) or float(value) != summing:
                raise ValueError(value)
        except (TypeError, ValueError, OverflowError) as err:   # 1e999 is inf: int() overflows
            raise LabelError(f"label {self.source}: summing {value!r} is not an integer") from err
        if summing < 1:
            raise LabelError(f"label {self.source}: summing {summing} is not positive")
        return summing

    def image_times(self) -> tuple[float, float, float]:
        exposure = self._line_exposure_s()
        dt = exposure * (1.0 + float(self.ik("MULTIPLI_LINE_ERROR", 0.0))) + float(self.ik("ADDITIVE_LINE_ERROR", 0.0))
        preroll = q.scs2e(self.spacecraft_id, self.preroll_count())
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
        io["line_summing"] = io["sample_summing"] = self._summing()
        try:
            io["starting_detector_sample"] = float(self.sample_first_pixel())
        except (TypeError, ValueError) as err:
            raise LabelError(f"label {self.source}: SampleFirstPixel is not a number") from err
        io["optical_distortion"] = {"lrolrocnac": {"coefficients": [float(self.ik("OD_K"))]}}
        return io


class LroNacDriver(_LroNac):
    """LRO NAC-L/NAC-R from an ISIS cube label (``lronac2isis`` output)."""

    name = "lro_nac"

    @classmethod
    def matches(cls, label: Label) -> bool:
        inst = cls.isis_instrument(label)
        return inst is not None and str(inst.get("InstrumentHostId", "")) == "LRO" and \
            str(inst.get("InstrumentId", "")) in _FRAMES

    @property
    def nac(self) -> str:
        return str(self.keyword("Instrument", "InstrumentId"))

    @property
    def sensor_name(self) -> str:
        return str(self.keyword("Instrument", "InstrumentName"))

    @property
    def platform_name(self) -> str:
        return str(self.keyword("Instrument", "SpacecraftName"))

    def line_exposure(self) -> Any:
        return self.keyword("Instrument", "LineExposureDuration")

    def preroll_count(self) -> str:
        return str(self.keyword("Instrument", "SpacecraftClockPrerollCount"))

    def summing(self) -> Any:
        return self.group("Instrument").get("SpatialSumming", 1)

    def sample_first_pixel(self) -> Any:
        return self.group("Instrument").get("SampleFirstPixel", 0)


class LroNacPds3Driver(_LroNac):
    """LRO NAC-L/NAC-R from the PDS3 EDR (or CDR) label as distributed by the PDS.

    Claims every PDS3 label of ``INSTRUMENT_HOST_ID = LRO``, ``INSTRUMENT_ID = LROC``
    and refuses, at construction and before any kernel is loaded, what it cannot
    model: another ``FRAME_ID`` than LEFT/RIGHT (the WAC), map-projected products,
    and NAC-R EDRs older than product version 1.30 (their samples are mirrored).

    Raises
    ------
    UnknownInstrumentError
        ``FRAME_ID`` is not ``LEFT`` or ``RIGHT``.
    LabelError
        A map-projected product, or a NAC-R EDR with mirrored samples, or an
        unreadable ``PRODUCT_VERSION_ID`` on a NAC-R label.
    """

    name = "lro_nac_pds3"

    def __init__(self, label: Label, source: str = "") -> None:
        super().__init__(label, source)
        frame = str(label.get("FRAME_ID", ""))
        if frame not in _PDS3_FRAMES:
            raise UnknownInstrumentError(
                f"LROC PDS3 label {source} has {f'FRAME_ID {frame!r}' if frame else 'no FRAME_ID'}: lunarmap models only the "
                f"Narrow Angle Cameras (FRAME_ID LEFT or RIGHT), not the WAC")
        if "IMAGE_MAP_PROJECTION" in label:
            raise LabelError(f"LROC PDS3 label {source} describes a map-projected product (IMAGE_MAP_PROJECTION): "
                             f"it has no camera geometry; use the EDR")
        if frame == "RIGHT":
            raw = str(label.get("PRODUCT_VERSION_ID", ""))
            try:
                version = float(raw.strip().lstrip("vV"))
            except ValueError as err:
                raise LabelError(f"LROC PDS3 label {source}: PRODUCT_VERSION_ID {raw!r} is not a version number; "
                                 f"it decides whether NAC-R samples are mirrored") from err
            if version < _NACR_FLIP_BEFORE:
                raise LabelError(
                    f"LROC PDS3 label {source}: NAC-R EDR version {raw} (< v1.30) stores its samples mirrored; "
                    f"import it with ISIS lronac2isis (which flips them) and use the cube's label")
        self._frame = frame

    @classmethod
    def matches(cls, label: Label) -> bool:
        return "IsisCube" not in label and str(label.get("INSTRUMENT_HOST_ID", "")) == "LRO" and \
            str(label.get("INSTRUMENT_ID", "")) == "LROC"

    def _pds3(self, key: str) -> Any:
        if key not in self.label:
            raise LabelError(f"PDS3 label {self.source} lacks keyword {key}")
        return self.label[key]

    @property
    def nac(self) -> str:
        return _PDS3_FRAMES[self._frame]

    @property
    def sensor_name(self) -> str:
        return f"LUNAR RECONNAISSANCE ORBITER NARROW ANGLE CAMERA {self._frame}"

    @property
    def platform_name(self) -> str:
        return str(self._pds3("MISSION_NAME"))  # lronac2isis: SpacecraftName = MISSION_NAME

    def line_exposure(self) -> Any:
        return self._pds3("LINE_EXPOSURE_DURATION")

    def preroll_count(self) -> str:
        return str(self._pds3("LRO:SPACECRAFT_CLOCK_PREROLL_COUNT"))

    def summing(self) -> Any:
        return self.label.get("CROSSTRACK_SUMMING", 1)

    def sample_first_pixel(self) -> Any:
        return 0  # lronac2isis writes SampleFirstPixel = 0 for every NAC EDR
