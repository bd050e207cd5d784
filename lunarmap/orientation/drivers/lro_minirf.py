"""LRO Mini-RF synthetic-aperture radar, ISIS cube labels (``mrf2isis`` output).

Follows USGS ALE's ``LroMiniRfIsisLabelNaifSpiceDriver`` (shared kernel README 8.2):

* the clock counts are ``UNK``: ``start = str2et(StartTime) - dt``, ``stop = start + (lines + 2) dt``
  with ``dt = LineExposureDuration`` (already seconds); states and pointing at
  ``linspace(start, stop, lines + 1)``;
* ``wavelength = 299792.458 / Frequency / 1000`` m (the label's ``Frequency`` is in MHz, whatever its
  unit says: 2380 for Mini-RF's S band, 12.6 cm), ``scaled_pixel_width = ScaledPixelHeight`` (m),
  ``range_conversion_times`` = ``str2et`` of the first item of each ``RangeCoefficientSet`` entry, the
  other four its ``range_conversion_coefficients``, ``look_direction`` in lower case;
* no light-time keywords in the kernels: the default ``LT+S``, spacecraft as target (unlike the LROC
  cameras); pointing of ``LRO_MINIRF`` (-85700) on the bus; ALE's ``TRANSX``/``ITRANSS`` in
  ``naif_keywords`` from the pixel width (ISIS ``RadarGroundRangeMap``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...errors import LabelError
from ...labels import Label
from ...spice import queries as q
from ..isd_kinds import SarParameters
from .base import Driver

__all__ = ["LroMiniRfDriver"]

_LIGHT_SPEED_KM_S = 299792.458


class LroMiniRfDriver(Driver):
    name = "lro_minirf"
    model = "sar"
    isis_camera_version = 1

    @classmethod
    def matches(cls, label: Label) -> bool:
        inst = cls.isis_instrument(label)
        return inst is not None and str(inst.get("InstrumentId", "")).upper() == "MRFLRO"

    @property
    def ikid(self) -> int:
        return -85700   # LRO_MINIRF

    @property
    def spacecraft_id(self) -> int:
        return -85

    @property
    def sensor_name(self) -> str:
        return str(self.keyword("Instrument", "InstrumentName"))

    def check_instrument(self) -> None:
        q.frame_name(self.ikid)   # LRO_MINIRF must be defined (lro_frames FK); there is no IK

    def position_correction(self) -> str:
        return "LT+S"   # no INS-85700 light-time keywords: ALE's default

    def _line_period(self) -> float:
        dt = self.as_float(self.keyword("Instrument", "LineExposureDuration"), "Instrument/LineExposureDuration")
        if not dt > 0.0:
            raise LabelError(f"label {self.source}: LineExposureDuration {dt!r} must be positive (s)")
        return dt

    def image_times(self) -> tuple[float, float, float]:
        dt = self._line_period()
        start = q.str2et(str(self.keyword("Instrument", "StartTime"))) - dt
        return start, start + (self.image_lines + 2) * dt, dt

    def _range_sets(self) -> tuple[np.ndarray, np.ndarray]:
        sets = self.keyword("Instrument", "RangeCoefficientSet")
        if not isinstance(sets, list) or not sets:
            raise LabelError(f"label {self.source}: Instrument/RangeCoefficientSet must be a list of "
                             "(UTC, c0, c1, c2, c3) entries")
        times, coeffs = [], []
        for i, entry in enumerate(sets):
            if not isinstance(entry, list) or len(entry) != 5:
                raise LabelError(f"label {self.source}: RangeCoefficientSet entry {i} must be (UTC, c0, c1, c2, c3), "
                                 f"got {entry!r:.80}")
            times.append(q.str2et(str(entry[0])))
            coeffs.append([self.as_float(v, f"RangeCoefficientSet entry {i}") for v in entry[1:]])
        return np.array(times), np.array(coeffs)

    def sensor_keys(self) -> dict[str, Any]:
        frequency = self.as_float(self.keyword("Instrument", "Frequency"), "Instrument/Frequency")
        times, coeffs = self._range_sets()
        _, stop, dt = self.image_times()
        look = str(self.keyword("Instrument", "LookDirection")).strip().lower()
        params = SarParameters(
            wavelength=_LIGHT_SPEED_KM_S / frequency / 1000.0, line_exposure_duration=dt,
            scaled_pixel_width=self.as_float(self.keyword("Instrument", "ScaledPixelHeight"),
                                             "Instrument/ScaledPixelHeight"),
            range_conversion_times=times, range_conversion_coefficients=coeffs, look_direction=look,
            ending_ephemeris_time=stop)
        bad = params.problem()
        if bad is not None:
            raise LabelError(f"label {self.source}: Mini-RF {bad[0]} {bad[1]}")
        return {"sar": params}

    def naif_keywords(self, body_frame_code: int) -> dict[str, Any]:
        out = super().naif_keywords(body_frame_code)
        r = self.as_float(self.keyword("Instrument", "ScaledPixelHeight"), "Instrument/ScaledPixelHeight")
        p = f"INS{self.ikid}_"
        out.update({p + "TRANSX": [-r, r, 0.0], p + "TRANSY": [0.0, 0.0, 0.0],
                    p + "ITRANSS": [1.0, 1.0 / r, 0.0], p + "ITRANSL": [0.0, 0.0, 0.0]})
        return out
