"""Apollo 15-17 metric (mapping) camera (scanned film), ISIS cube labels.

Times, frames and the aberration correction follow USGS ALE's
``ApolloMetricIsisLabelNaifSpiceDriver`` (shared kernel README, 5.1-5.5): one epoch,
``str2et(Instrument/StartTime)`` (not the ``Code`` group's ``StartTime``) plus the ``Code``
group's ``ExposureDuration`` (0 in the scanned-film labels); the sensor position with ALE's
default ``LT+S`` correction (the IK names none); sensor frame ``A<n>_METRIC`` (the
``Kernels/NaifFrameCode``, a CK frame relative to ``APOLLO_<n>_NADIR``).

Interior orientation: ISIS ``ApolloMetricCamera`` rather than ALE, whose ISD puts the principal
point at pixel (0, 0) and leaves the camera undistorted:

* detector centre at the image centre, ISIS's ``SetDetectorOrigin(samples / 2, lines / 2)`` in ISIS
  pixels, i.e. ``(lines / 2 - 0.5, samples / 2 - 0.5)`` in CSM's; focal plane from the IK's
  ``ITRANSS``/``ITRANSL`` (5 um pixels, x to the left as in the calibration report);
* distortion ISIS ``ApolloMetricDistortionMap`` (IK ``PP``, ``OD_K``, ``DECENTER``), lunarmap's
  ``apollometric`` model (:class:`~lunarmap.camera.distortion.ApolloMetricDistortion`);
* focal length written **negative**: ISIS builds the camera with the focal-plane z direction -1
  (the NAIF frame's ``+z`` points away from the Moon); a look vector ``(x, y, f)`` with ``f < 0``
  is exactly that, in lunarmap and in usgscsm's frame model alike.

The label's ``Reseaus`` group is not used: in these labels its ``Status`` is ``Nominal`` (the
template positions, not measured ones), so it carries no information about the film.
"""

from __future__ import annotations

from typing import Any

from ...errors import LabelError, UnknownInstrumentError
from ...labels import Label
from ...spice import queries as q
from .base import Driver

__all__ = ["ApolloMetricDriver"]

_MISSIONS = {"15": -915240, "16": -916240, "17": -917240}


def _mission(name: str) -> str | None:
    up = name.upper().replace("_", " ")
    if "APOLLO" not in up:
        return None
    return next((m for m in _MISSIONS if m in up), None)


class ApolloMetricDriver(Driver):
    name = "apollo_metric"
    model = "frame"
    isis_camera_version = 1

    @classmethod
    def matches(cls, label: Label) -> bool:
        inst = cls.isis_instrument(label)
        return inst is not None and _mission(str(inst.get("SpacecraftName", ""))) is not None and \
            str(inst.get("InstrumentId", "")).upper() == "METRIC"

    @property
    def ikid(self) -> int:
        ikid = self.as_int(self.keyword("Kernels", "NaifFrameCode"), "Kernels/NaifFrameCode")
        mission = _mission(self.platform_name)
        if mission is None or ikid != _MISSIONS[mission]:
            raise UnknownInstrumentError(f"label {self.source}: NaifFrameCode {ikid} is not the metric camera of "
                                         f"{self.platform_name!r} (known: {_MISSIONS})")
        return ikid

    @property
    def spacecraft_id(self) -> int:
        return -(abs(self.ikid) // 1000)

    @property
    def sensor_name(self) -> str:
        return "APOLLO_METRIC"  # ALE's name

    def image_times(self) -> tuple[float, float, float]:
        start = q.str2et(str(self.keyword("Instrument", "StartTime")))
        exposure = 0.0
        cube = self.label.get("IsisCube")
        code = cube.get("Code") if cube is not None else None
        if code is not None and "ExposureDuration" in code:
            value = code["ExposureDuration"]
            unit = str(getattr(value, "unit", "ms")).lower()
            try:
                exposure = float(value) * (1e-3 if unit.startswith("m") else 1.0)
            except (TypeError, ValueError) as err:
                raise LabelError(f"label {self.source}: Code/ExposureDuration {value!r} is not a number") from err
        return start, start + exposure, 0.0

    def interior(self) -> dict[str, Any]:
        def three(key: str) -> list[float]:
            v = self.ik(key)
            values = [float(x) for x in (v if isinstance(v, list) else [v])]
            if len(values) != 3:
                raise UnknownInstrumentError(f"IK keyword INS{self.ikid}_{key} must hold 3 values, got {v!r}")
            return values

        pp = self.ik("PP")
        if not isinstance(pp, list) or len(pp) != 2:
            raise UnknownInstrumentError(f"IK keyword INS{self.ikid}_PP must hold 2 values, got {pp!r}")
        return {
            "focal_length": -abs(float(self.ik("FOCAL_LENGTH"))),
            "focal2pixel_lines": three("ITRANSL"),
            "focal2pixel_samples": three("ITRANSS"),
            "detector_center_line": self.image_lines / 2.0 - 0.5,
            "detector_center_sample": self.image_samples / 2.0 - 0.5,
            "starting_detector_line": 0.0,
            "starting_detector_sample": 0.0,
            "line_summing": 1,
            "sample_summing": 1,
            "optical_distortion": {"apollometric": {"principal_point": [float(v) for v in pp],
                                                    "coefficients": three("OD_K"),
                                                    "decentering": three("DECENTER")}},
        }

    def image_support(self) -> Any:
        isd = super().image_support()
        cube = self.label.get("IsisCube")
        reseaus = cube.get("Reseaus") if cube is not None else None
        isd.provenance.update({
            "focal_plane": "ISIS ApolloMetricCamera: detector origin at the image centre, IK ITRANSS/ITRANSL, "
                           "ApolloMetricDistortionMap; focal length negative: the camera looks along -z of its "
                           "NAIF frame (ISIS z direction -1)",
            "reseaus": "not used" + (f" (Status = {reseaus.get('Status')})" if reseaus is not None else ""),
        })
        return isd
