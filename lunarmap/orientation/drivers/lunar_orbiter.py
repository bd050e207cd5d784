"""Lunar Orbiter 3-5 high-resolution camera (scanned film), ISIS cube labels.

Times, frames and the aberration correction follow USGS ALE's
``LoHighCameraIsisLabelNaifSpiceDriver`` (shared kernel README, 5.1-5.5): one epoch,
``str2et(StartTime)`` (no exposure time); sensor position without aberration correction
(ISIS turns it off for all Lunar Orbiter data); sensor frame ``LO<n>_HIGH_RESOLUTION_CAMERA``
(the ``Kernels/NaifFrameCode``) below the CK frame ``LUNAR_ORBITER_<n>``.

Interior orientation: the film carries fiducial marks whose scanned positions (label
``FiducialSamples``/``FiducialLines``, ISIS pixels) and calibrated focal-plane positions
(``FiducialXCoordinates``/``FiducialYCoordinates``, mm) define the focal plane: an affine
transform fitted to them by least squares (ISIS ``LoCameraFiducialMap``, ALE's ``naif_keywords``
``TRANSX``/``TRANSY``/``ITRANSS``/``ITRANSL``); the fit's residual per mark is kept in the ISD's
``lunarmap`` block. Distortion: ISIS ``LoHighDistortionMap`` (perspective factors, point of
symmetry and ``OD_K``), ALE's ``lunarorbiter`` block plus the ``OD_K`` coefficients ALE leaves out
(:class:`~lunarmap.camera.distortion.LunarOrbiterDistortion`).

Two deliberate departures from ALE's ISD, recorded here and in the ISD's ``lunarmap`` block:

* the focal length is written **negative**: ISIS builds these cameras with the focal-plane z
  direction -1 (``CameraDistortionMap(parent, -1)``): they look along ``-z`` of the NAIF frame,
  whose ``+z`` points away from the Moon (checked against SPICE in the tests). A look vector
  ``(x, y, f)`` with ``f < 0`` is exactly that, in lunarmap and in usgscsm's frame model alike;
  ALE's positive focal length points the camera into space;
* the detector centre is ``(-0.5, -0.5)`` instead of ALE's ``(0, 0)``: the fiducial positions are
  ISIS pixel coordinates (first pixel centre at 1), CSM's are half a pixel less, as for the other
  drivers.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...errors import LabelError, UnknownInstrumentError
from ...labels import Label
from ...spice import queries as q
from .base import Driver

__all__ = ["LunarOrbiterHighDriver", "LunarOrbiterMediumDriver", "fiducial_affine"]

_MISSIONS = {f"LUNAR ORBITER {n}": n for n in (3, 4, 5)}


def fiducial_affine(samples: Any, lines: Any, x_mm: Any, y_mm: Any) -> dict[str, Any]:
    """Least-squares affine transform from scanned fiducial positions to their calibrated focal-plane positions.

    Parameters
    ----------
    samples, lines : array_like
        Measured fiducial positions in the scan, pixels (any pixel convention; the transform uses it).
    x_mm, y_mm : array_like
        Calibrated fiducial positions in the focal plane, millimetres.

    Returns
    -------
    dict
        ``transx``/``transy`` (``x = c + a s + b l``, ISIS order ``[c, a, b]``, mm per pixel),
        ``itranss``/``itransl`` (the inverse, ``s = c' + a' x + b' y``, pixels per mm),
        ``residuals_mm`` (n, 2) of the fit, ``rms_mm`` and ``max_mm``.

    Raises
    ------
    LabelError
        Fewer than 3 fiducials, unequal lengths, non-finite values or collinear marks.
    """
    s, ln, x, y = (np.asarray(v, dtype=float).ravel() for v in (samples, lines, x_mm, y_mm))
    if not (s.size == ln.size == x.size == y.size):
        raise LabelError(f"fiducials: {s.size} samples, {ln.size} lines, {x.size} x and {y.size} y coordinates")
    if s.size < 3:
        raise LabelError(f"fiducials: an affine focal-plane transform needs at least 3 marks, got {s.size}")
    if not all(np.all(np.isfinite(v)) for v in (s, ln, x, y)):
        raise LabelError("fiducials: non-finite positions")
    a = np.column_stack([s, ln, np.ones_like(s)])
    if np.linalg.matrix_rank(a) < 3:
        raise LabelError("fiducials: the marks are collinear; no affine transform")
    cx, *_ = np.linalg.lstsq(a, x, rcond=None)
    cy, *_ = np.linalg.lstsq(a, y, rcond=None)
    m = np.array([[cx[0], cx[1]], [cy[0], cy[1]]])
    inv = np.linalg.inv(m)
    off = -inv @ np.array([cx[2], cy[2]])
    res = np.column_stack([a @ cx - x, a @ cy - y])
    dist = np.hypot(res[:, 0], res[:, 1])
    return {"transx": [cx[2], cx[0], cx[1]], "transy": [cy[2], cy[0], cy[1]],
            "itranss": [off[0], inv[0, 0], inv[0, 1]], "itransl": [off[1], inv[1, 0], inv[1, 1]],
            "residuals_mm": res, "rms_mm": float(np.sqrt(np.mean(dist ** 2))), "max_mm": float(dist.max())}


class LunarOrbiterHighDriver(Driver):
    name = "lunar_orbiter_high"
    model = "frame"
    isis_camera_version = 1

    def __init__(self, label: Label, source: str = "") -> None:
        super().__init__(label, source)
        self._fit: dict[str, Any] | None = None

    @classmethod
    def matches(cls, label: Label) -> bool:
        inst = cls.isis_instrument(label)
        return inst is not None and str(inst.get("SpacecraftName", "")).upper() in _MISSIONS and \
            str(inst.get("InstrumentId", "")).upper() == "HIGH RESOLUTION CAMERA"

    @property
    def _mission(self) -> int:
        return _MISSIONS[str(self.keyword("Instrument", "SpacecraftName")).upper()]

    @property
    def ikid(self) -> int:
        ikid = self.as_int(self.keyword("Kernels", "NaifFrameCode"), "Kernels/NaifFrameCode")
        expected = -(530000 + 1000 * self._mission + 1)
        if ikid != expected:
            raise UnknownInstrumentError(f"label {self.source}: NaifFrameCode {ikid} is not the high-resolution "
                                         f"camera of Lunar Orbiter {self._mission} ({expected})")
        return ikid

    @property
    def spacecraft_id(self) -> int:
        return -(abs(self.ikid) // 1000)

    @property
    def sensor_name(self) -> str:
        return f"LO{self._mission}_HIGH_RESOLUTION_CAMERA"  # ALE's name: the NAIF frame

    def position_correction(self) -> str:
        return "NONE"  # ISIS and ALE switch aberration corrections off for Lunar Orbiter

    def image_times(self) -> tuple[float, float, float]:
        start = q.str2et(str(self.keyword("Instrument", "StartTime")))
        return start, start, 0.0

    def fiducials(self) -> dict[str, Any]:
        """The label's fiducial marks and the affine transform fitted to them (:func:`fiducial_affine`)."""
        if self._fit is None:
            inst = self.group("Instrument")
            keys = ("FiducialSamples", "FiducialLines", "FiducialXCoordinates", "FiducialYCoordinates")
            missing = [k for k in keys if k not in inst]
            if missing:
                raise LabelError(f"label {self.source} lacks Instrument/{', '.join(missing)}: the Lunar Orbiter "
                                 "focal plane is defined by the fiducial marks")
            try:
                values = [[float(v) for v in (inst[k] if isinstance(inst[k], list) else [inst[k]])] for k in keys]
            except (TypeError, ValueError) as err:
                raise LabelError(f"label {self.source}: malformed fiducial keyword ({err})") from None
            try:
                fit = fiducial_affine(*values)
            except LabelError as err:
                raise LabelError(f"label {self.source}: {err}") from None
            ids = inst.get("FiducialID", [])
            fit["ids"] = [str(i) for i in (ids if isinstance(ids, list) else [ids])]
            self._fit = fit
        return self._fit

    def interior(self) -> dict[str, Any]:
        fit = self.fiducials()
        # CSM pixels are ISIS's minus 0.5 (the fiducial positions are ISIS pixel coordinates)
        return {
            "focal_length": -abs(float(self.ik("FOCAL_LENGTH"))),
            "focal2pixel_lines": [float(v) for v in fit["itransl"]],
            "focal2pixel_samples": [float(v) for v in fit["itranss"]],
            "detector_center_line": -0.5,
            "detector_center_sample": -0.5,
            "starting_detector_line": 0.0,
            "starting_detector_sample": 0.0,
            "line_summing": 1,
            "sample_summing": 1,
            "optical_distortion": {"lunarorbiter": {
                "perspective_x": float(self.ik("PERSPECTIVE_FACTORS")[0]),
                "perspective_y": float(self.ik("PERSPECTIVE_FACTORS")[1]),
                "center_point_x": float(self.ik("POINT_OF_SYMMETRY")[0]),
                "center_point_y": float(self.ik("POINT_OF_SYMMETRY")[1]),
                "coefficients": [float(v) for v in self.ik("OD_K")]}},
        }

    def naif_keywords(self, body_frame_code: int) -> dict[str, Any]:
        fit = self.fiducials()
        out = super().naif_keywords(body_frame_code)
        p = f"INS{self.ikid}_"
        out.update({p + "TRANSX": fit["transx"], p + "TRANSY": fit["transy"],
                    p + "ITRANSS": fit["itranss"], p + "ITRANSL": fit["itransl"]})
        return out

    def image_support(self) -> Any:
        isd = super().image_support()
        fit = self.fiducials()
        isd.provenance.update({
            "focal_plane": "affine fit to the label's fiducial marks; focal length negative: the camera looks "
                           "along -z of its NAIF frame (ISIS z direction -1)",
            "fiducial_rms_mm": fit["rms_mm"], "fiducial_max_mm": fit["max_mm"],
            "fiducial_residuals_mm": {i: [float(r[0]), float(r[1])] for i, r in
                                      zip(fit["ids"] or range(len(fit["residuals_mm"])), fit["residuals_mm"])},
        })
        return isd


class LunarOrbiterMediumDriver(Driver):
    """Lunar Orbiter 3-5 medium-resolution camera (scanned film), ISIS cube labels.

    Follows ALE's ``LoMediumCameraIsisLabelNaifSpiceDriver`` (shared kernel README 8.7): instrument
    ``LO<n>_MED_RESOLUTION_CAMERA`` (-53x002), one epoch ``str2et(StartTime)``, no aberration correction,
    focal length and ``ITRANSL``/``ITRANSS`` from the IAK (no fiducial fit), detector centre from the
    label's ``BoresightLine``/``BoresightSample``. Departures, as for the high-resolution camera: the
    focal length is negative (the camera looks along -z of its NAIF frame, checked against SPICE), the
    detector centre is moved to CSM pixels (label value - 0.5). Distortion: none, as ALE; ISIS applies its
    ``LoMediumDistortionMap`` (IAK ``OD_K``, ``POINT_OF_SYMMETRY``), which lunarmap does not model.
    """

    name = "lunar_orbiter_medium"
    model = "frame"
    isis_camera_version = 1

    @classmethod
    def matches(cls, label: Label) -> bool:
        inst = cls.isis_instrument(label)
        return inst is not None and str(inst.get("SpacecraftName", "")).upper() in _MISSIONS and \
            str(inst.get("InstrumentId", "")).upper() == "MEDIUM RESOLUTION CAMERA"

    @property
    def _mission(self) -> int:
        return _MISSIONS[str(self.keyword("Instrument", "SpacecraftName")).upper()]

    @property
    def ikid(self) -> int:
        return -(530000 + 1000 * self._mission + 2)

    @property
    def spacecraft_id(self) -> int:
        return -(530 + self._mission)

    @property
    def sensor_name(self) -> str:
        return f"LO{self._mission}_MED_RESOLUTION_CAMERA"

    def position_correction(self) -> str:
        return "NONE"

    def image_times(self) -> tuple[float, float, float]:
        start = q.str2et(str(self.keyword("Instrument", "StartTime")))
        return start, start, 0.0

    def interior(self) -> dict[str, Any]:
        return {
            "focal_length": -abs(float(self.ik("FOCAL_LENGTH"))),
            "focal2pixel_lines": [float(v) for v in self.ik("ITRANSL")],
            "focal2pixel_samples": [float(v) for v in self.ik("ITRANSS")],
            "detector_center_line": self.as_float(self.keyword("Instrument", "BoresightLine"), "BoresightLine") - 0.5,
            "detector_center_sample": self.as_float(self.keyword("Instrument", "BoresightSample"),
                                                    "BoresightSample") - 0.5,
            "starting_detector_line": 0.0,
            "starting_detector_sample": 0.0,
            "line_summing": 1,
            "sample_summing": 1,
            "optical_distortion": {"radial": {"coefficients": [0.0, 0.0, 0.0]}},
        }

    def image_support(self) -> Any:
        isd = super().image_support()
        isd.provenance.update({
            "focal_plane": "IAK ITRANSL/ITRANSS; focal length negative: the camera looks along -z of its NAIF frame",
            "detector_center": "label Boresight - 0.5 (ISIS -> CSM pixels)",
            "distortion": "none (as ALE); ISIS's LoMediumDistortionMap is not modelled"})
        return isd
