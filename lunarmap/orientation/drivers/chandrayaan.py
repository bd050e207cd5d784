"""Chandrayaan-2 OHRC and TMC-2, Chandrayaan-1 M3 (ISIS label and PDS3 label with its timing table).

All follow USGS ALE's drivers (shared kernel README 8.3-8.5); their pointing CKs carry no angular
rates, so only ``pxform`` is sampled and the ISD, like ALE's, has no pointing angular velocities.

* **OHRC** (``Chandrayaan2OHRCIsisLabelNaifSpiceDriver``): instrument = label ``NaifFrameCode``
  (-152270 CH2_OHRC), sensor frame ``ikid - 10`` (CH2_OHRC_ISIS, an axis fix of the IAK);
  ``start = str2et(StartTime)``, ``stop = str2et(StopTime)`` (the whole strip's: the grid does not
  follow the line time of a crop), ``dt = LineExposureDuration`` only in ``line_scan_rate``; detector
  centre ``INS<ikid>_CENTER`` (sample, line) as it is, focal plane ``1 / (PIXEL_SIZE * 1000)`` px/mm;
  no distortion; ``LT+S``, spacecraft as target; body frame IAU_MOON.
* **TMC-2** (``Chandrayaan2TMC2IsisLabelNaifSpiceDriver``): as OHRC, instruments -152210/-152211/-152212
  (nadir/fore/aft), ``stop = start + lines * dt`` (the label's StopTime is the strip's).
* **M3, ISIS label** (``Chandrayaan1M3IsisLabelNaifSpiceDriver``): ``start = scs2e(SpacecraftClockStartCount)``,
  ``dt = LineExposureDuration`` (ms), ``stop = start + lines dt``; IK ``INS-86520_ITRANSL/ITRANSS``,
  boresight; no distortion; ``NONE`` + swap (IAK).
* **M3, PDS3 label** (``Chandrayaan1M3Pds3NaifSpiceDriver``, ALE option ``nadir=True``): line-centre
  UTCs from the label's ``UTC_TIME_TABLE`` (in time order), ``dt`` from ``INSTRUMENT_MODE_ID`` (TARGET
  0.05088 s, GLOBAL 0.10176 s and summing 2), ``start = scs2e(sce2s(str2et(first) - dt / 2))``, nadir
  pointing ``twovec(-p, 3, v, axis)`` from the J2000 states (axis 1 when ``ITRANSL[0] < ITRANSL[1]``,
  else 2), ``time_dependent_frames [-86, 1]``.

Departures from ALE (recorded in the ISD's ``lunarmap`` block): the M3 boresight sample is moved to the
CSM pixel convention (``BORESIGHT_SAMPLE - 0.5``; ALE copies the ISIS value, half a pixel off, as for
Clementine); ALE samples the M3 ISIS label's pointing at the CK's own records (7 epochs here), lunarmap
at the position epochs (6), where it equals SPICE's CK to 1e-10 rad; the PDS3 driver's "sensor frame"
``-86`` (a body code ALE takes as a frame) is named as ALE names it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ...errors import LabelError
from ...labels import Label
from ...spice import queries as q
from ..isd import RotationTable
from ..rotation import matrix_to_quat
from ..rotation_hermite import rates_from_samples
from .base import Driver

__all__ = ["Chandrayaan2OhrcDriver", "Chandrayaan2TmcDriver", "Chandrayaan1M3Driver", "Chandrayaan1M3Pds3Driver"]

_TMC = {-152210: "CH2_TMC_NADIR", -152211: "CH2_TMC_FORE", -152212: "CH2_TMC_AFT"}
_NO_DISTORTION = {"radial": {"coefficients": [0.0, 0.0, 0.0]}}


class _Chandrayaan2(Driver):
    """What OHRC and TMC-2 share."""

    model = "linescan"
    isis_camera_version = 1
    pointing_rates = False

    @property
    def spacecraft_id(self) -> int:
        return -152

    @property
    def sensor_frame(self) -> int:
        return self.ikid - 10       # CH2_OHRC_ISIS / CH2_TMC_*_ISIS of the IAK

    def _line_period(self) -> float:
        return self.as_float(self.keyword("Instrument", "LineExposureDuration"), "Instrument/LineExposureDuration") \
            * 1e-3

    def interior(self) -> dict[str, Any]:
        pixel = self.ik("PIXEL_SIZE")
        pixel = float(pixel[0] if isinstance(pixel, list) else pixel) * 1000.0    # m -> mm
        centre = self.ik("CENTER")
        focal = self.ik("FOCAL_LENGTH")
        return {
            "focal_length": float(focal[0] if isinstance(focal, list) else focal),
            "focal2pixel_lines": [0.0, 1.0 / pixel, 0.0],
            "focal2pixel_samples": [0.0, 0.0, 1.0 / pixel],
            "detector_center_line": float(centre[1]),
            "detector_center_sample": float(centre[0]),
            "starting_detector_line": 0.0,
            "starting_detector_sample": 0.0,
            "line_summing": 1,
            "sample_summing": 1,
            "optical_distortion": dict(_NO_DISTORTION),
        }


class Chandrayaan2OhrcDriver(_Chandrayaan2):
    name = "chandrayaan2_ohrc"

    @classmethod
    def matches(cls, label: Label) -> bool:
        inst = cls.isis_instrument(label)
        return inst is not None and str(inst.get("SpacecraftName", "")).upper() == "CHANDRAYAAN-2" and \
            str(inst.get("InstrumentId", "")).upper() == "OHRC"

    @property
    def sensor_name(self) -> str:
        return "CH2_OHRC"

    def image_times(self) -> tuple[float, float, float]:
        start = q.str2et(str(self.keyword("Instrument", "StartTime")))
        stop = q.str2et(str(self.keyword("Instrument", "StopTime")))
        if not stop > start:
            raise LabelError(f"label {self.source}: StopTime is not after StartTime")
        return start, stop, self._line_period()


class Chandrayaan2TmcDriver(_Chandrayaan2):
    name = "chandrayaan2_tmc2"

    @classmethod
    def matches(cls, label: Label) -> bool:
        inst = cls.isis_instrument(label)
        return inst is not None and str(inst.get("SpacecraftName", "")).upper() == "CHANDRAYAAN-2" and \
            str(inst.get("InstrumentId", "")).upper().startswith("CH2_TMC")

    @property
    def sensor_name(self) -> str:
        return _TMC.get(self.ikid, str(self.ikid))

    def image_times(self) -> tuple[float, float, float]:
        start = q.str2et(str(self.keyword("Instrument", "StartTime")))
        dt = self._line_period()
        return start, start + self.image_lines * dt, dt


class _M3(Driver):
    """What both M3 label kinds share."""

    model = "linescan"
    isis_camera_version = 1
    pointing_rates = False

    @property
    def ikid(self) -> int:
        return -86520

    @property
    def spacecraft_id(self) -> int:
        return -86

    @property
    def sensor_name(self) -> str:
        return "CHANDRAYAAN-1_M3"

    def interior(self) -> dict[str, Any]:
        io = super().interior()
        io["detector_center_sample"] -= 0.5      # ISIS -> CSM pixels (ALE copies the ISIS value)
        io["optical_distortion"] = dict(_NO_DISTORTION)
        return io

    def image_support(self) -> Any:
        isd = super().image_support()
        isd.provenance["detector_center"] = "BORESIGHT_SAMPLE - 0.5 (ISIS -> CSM pixels; ALE copies the ISIS value)"
        return isd


class Chandrayaan1M3Driver(_M3):
    """M3 from an ISIS cube label."""

    name = "chandrayaan1_m3"

    @classmethod
    def matches(cls, label: Label) -> bool:
        inst = cls.isis_instrument(label)
        return inst is not None and str(inst.get("SpacecraftName", "")).upper() == "CHANDRAYAAN-1" and \
            str(inst.get("InstrumentId", "")).upper() == "M3"

    def image_times(self) -> tuple[float, float, float]:
        start = q.scs2e(self.spacecraft_id, str(self.keyword("Instrument", "SpacecraftClockStartCount")))
        dt = self.as_float(self.keyword("Instrument", "LineExposureDuration"), "Instrument/LineExposureDuration") * 1e-3
        return start, start + self.image_lines * dt, dt


class Chandrayaan1M3Pds3Driver(_M3):
    """M3 from its PDS3 L1B label and line timing table, pointing along nadir (ALE's ``nadir=True``)."""

    name = "chandrayaan1_m3_pds3"

    @classmethod
    def matches(cls, label: Label) -> bool:
        return "IsisCube" not in label and str(label.get("MISSION_ID", "")).upper() == "CH1" and \
            str(label.get("INSTRUMENT_ID", "")).upper() == "M3"

    @property
    def platform_name(self) -> str:
        return str(self.value_at("MISSION_NAME"))

    @property
    def image_lines(self) -> int:
        return self.as_int(self.value_at("RDN_FILE", "RDN_IMAGE", "LINES"), "RDN_FILE/RDN_IMAGE/LINES", minimum=1,
                           maximum=self.MAX_IMAGE_SIZE)

    @property
    def image_samples(self) -> int:
        return self.as_int(self.value_at("RDN_FILE", "RDN_IMAGE", "LINE_SAMPLES"), "RDN_FILE/RDN_IMAGE/LINE_SAMPLES",
                           minimum=1, maximum=self.MAX_IMAGE_SIZE)

    def _mode(self) -> str:
        mode = str(self.value_at("INSTRUMENT_MODE_ID")).strip().upper()
        if mode not in ("TARGET", "GLOBAL"):
            raise LabelError(f"label {self.source}: INSTRUMENT_MODE_ID {mode!r} is neither TARGET nor GLOBAL")
        return mode

    def line_times_utc(self) -> list[str]:
        """The line-centre UTCs of the timing table, in time order."""
        name = str(self.value_at("UTC_FILE", "^UTC_TIME_TABLE")).strip('"')
        table = Path(self.source).parent / name if self.source else Path(name)
        if not table.is_file():
            raise LabelError(f"label {self.source}: its line timing table {table} does not exist")
        rows = [line.split() for line in table.read_text().splitlines() if line.strip()]
        if not rows or any(len(r) < 2 for r in rows):
            raise LabelError(f"timing table {table}: rows must hold a line number and a UTC")
        utc = [r[1] for r in rows]
        return list(reversed(utc)) if utc[0] > utc[-1] else utc   # ALE: the table in time order

    def image_times(self) -> tuple[float, float, float]:
        dt = 0.10176 if self._mode() == "GLOBAL" else 0.05088
        first = q.str2et(self.line_times_utc()[0]) - 0.5 * dt
        start = q.scs2e(self.spacecraft_id, q.sce2s(self.spacecraft_id, first))   # rounded to the 1 ms tick
        return start, start + self.image_lines * dt, dt

    def interior(self) -> dict[str, Any]:
        io = super().interior()
        io["line_summing"] = io["sample_summing"] = 2 if self._mode() == "GLOBAL" else 1
        return io

    def _rotation_table(self, frame: int, times: np.ndarray, rates: bool = True) -> RotationTable:
        if frame != self.sensor_frame:
            return super()._rotation_table(frame, times, rates)
        # nadir pointing (ISIS SpiceRotation::setEphemerisTimeNadir, ALE nadir=True): z towards the body
        # centre, x (or y) along the velocity
        state = q.states(self.spacecraft_id, times, "J2000", self.position_correction(), self.target_id)
        itransl = self.ik("ITRANSL")
        axis = 0 if float(itransl[0]) < float(itransl[1]) else 1
        z = -state[:, :3] / np.linalg.norm(state[:, :3], axis=1, keepdims=True)
        v = state[:, 3:]
        a = v - np.einsum("ni,ni->n", v, z)[:, None] * z
        a /= np.linalg.norm(a, axis=1, keepdims=True)
        b = np.cross(z, a)
        rows = np.empty((times.size, 3, 3))          # J2000 -> sensor: rows are the sensor axes
        rows[:, 2] = z
        if axis == 0:
            rows[:, 0], rows[:, 1] = a, b
        else:
            rows[:, 1], rows[:, 0] = a, -b
        quats = matrix_to_quat(rows)
        return RotationTable(time_dependent_frames=[self.spacecraft_id, 1], times=times, quaternions=quats,
                             angular_velocities=rates_from_samples(times, quats), constant_frames=[self.spacecraft_id],
                             constant_rotation=np.eye(3), rates_given=False)

    @property
    def sensor_frame(self) -> int:
        return self.spacecraft_id      # ALE: bods2c('CH1'), a body code standing for the nadir frame

    def image_support(self) -> Any:
        isd = super().image_support()
        isd.provenance["pointing"] = "nadir (ISIS setEphemerisTimeNadir, ALE nadir=True), no CK"
        return isd
