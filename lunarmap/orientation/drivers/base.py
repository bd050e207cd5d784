"""The shared part of every instrument driver: label + kernels -> :class:`ImageSupport`.

A driver answers a handful of instrument-specific questions (which NAIF ids,
which image times, which aberration correction, which interior orientation);
:meth:`Driver.image_support` then samples SPICE once, in one locked pass, the way
USGS ALE does (see the shared kernel README, section 5), and returns pure data.

Drivers are selected explicitly by :func:`lunarmap.orientation.drivers.driver_for`
(each driver says whether a label is its own); there is no try-every-driver
fallback that would hide the real error.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from ...errors import LabelError, LabelKeywordError, UnknownInstrumentError
from ...labels import Label
from ...labels.pvl import label_int
from ...spice import queries as q
from ..isd import ImageSupport, RotationTable, line_scan_epochs
from ..rotation import matrix_to_quat
from ..rotation_hermite import rates_from_samples

__all__ = ["Driver"]

MOON = 301


def _bool(v: Any) -> Any:
    if isinstance(v, str) and v.upper() in ("TRUE", "FALSE"):
        return v.upper() == "TRUE"
    return v


def _unlist(v: list) -> Any:
    v = [_bool(x) for x in v]
    return v[0] if len(v) == 1 else v


class Driver:
    """Base driver. Subclasses set the class attributes and override the hooks.

    Parameters
    ----------
    label : Label
        The parsed image label.
    source : str
        Label file path, for messages.
    """

    #: human-readable name of what the driver handles
    name: ClassVar[str] = "generic"
    #: ``"frame"``, ``"linescan"``, ``"pushframe"`` or ``"sar"``; generic drivers decide per image
    model: ClassVar[str] = "frame"
    isis_camera_version: ClassVar[int] = 1
    #: whether the pointing CKs carry angular rates; without them (Chandrayaan-1/-2) only ``pxform``
    #: works, the rates are derived from the samples and the ISD gets none, as ALE writes none
    pointing_rates: ClassVar[bool] = True

    def __init__(self, label: Label, source: str = "") -> None:
        self.label = label
        self.source = source

    # -- selection ------------------------------------------------------------
    @classmethod
    def matches(cls, label: Label) -> bool:
        """Whether this driver handles ``label``."""
        return False

    @staticmethod
    def isis_instrument(label: Label) -> Label | None:
        """The ``IsisCube/Instrument`` group of an ISIS label, ``None`` for other labels."""
        cube = label.get("IsisCube")
        if cube is None or "Instrument" not in cube:
            return None
        return cube["Instrument"]

    # -- label access -----------------------------------------------------------
    # Every label value goes through these: a missing, misplaced or malformed keyword is a named
    # LabelError (fuzzing found raw KeyError / ValueError / TypeError from direct indexing).
    def group(self, name: str) -> Label:
        """An ISIS label group (``IsisCube/<name>``) or the PDS3 label itself."""
        cube = self.label.get("IsisCube")
        if cube is not None:
            g = cube.get(name) if isinstance(cube, Label) else None
            if not isinstance(g, Label):
                raise LabelKeywordError(f"label {self.source} has no {name} group")
            return g
        return self.label

    #: largest image dimension a label may give (pixels): far beyond any planetary image (LRO NAC 52,224
    #: lines, HRSC strips ~10^5), small enough that the sampling grids of a damaged label fit in memory
    MAX_IMAGE_SIZE = 10_000_000

    def keyword(self, group: str, key: str) -> Any:
        g = self.group(group)
        if key not in g:
            raise LabelKeywordError(f"label {self.source} lacks {group}/{key}")
        return g[key]

    def value_at(self, *path: str) -> Any:
        """The value at a path of blocks and keyword, e.g. ``("IsisCube", "Core", "Dimensions", "Lines")``."""
        node: Any = self.label
        for i, key in enumerate(path):
            if not isinstance(node, Label) or key not in node:
                raise LabelKeywordError(f"label {self.source} lacks {'/'.join(path[: i + 1])}")
            node = node[key]
        return node

    def as_int(self, value: Any, what: str, minimum: int | None = None, maximum: int | None = None) -> int:
        """A label value as an integer (``what`` names it in the message), in ``[minimum, maximum]``."""
        return label_int(value, f"label {self.source}: {what}", minimum, maximum)

    def as_float(self, value: Any, what: str) -> float:
        """A label value as a finite float (``what`` names it in the message)."""
        try:
            out = float(value)
        except (TypeError, ValueError, OverflowError):
            raise LabelError(f"label {self.source}: {what} {value!r:.60} is not a number") from None
        if isinstance(value, bool) or not math.isfinite(out):
            raise LabelError(f"label {self.source}: {what} {value!r:.60} is not a finite number")
        return out

    @property
    def image_lines(self) -> int:
        if self.label.get("IsisCube") is not None:
            return self.as_int(self.value_at("IsisCube", "Core", "Dimensions", "Lines"), "Lines", minimum=1,
                               maximum=self.MAX_IMAGE_SIZE)
        return self.as_int(self.value_at("IMAGE", "LINES"), "IMAGE/LINES", minimum=1, maximum=self.MAX_IMAGE_SIZE)

    @property
    def image_samples(self) -> int:
        if self.label.get("IsisCube") is not None:
            return self.as_int(self.value_at("IsisCube", "Core", "Dimensions", "Samples"), "Samples", minimum=1,
                               maximum=self.MAX_IMAGE_SIZE)
        return self.as_int(self.value_at("IMAGE", "LINE_SAMPLES"), "IMAGE/LINE_SAMPLES", minimum=1,
                           maximum=self.MAX_IMAGE_SIZE)

    # -- hooks (SPICE ids and times) ---------------------------------------------
    @property
    def ikid(self) -> int:
        """NAIF instrument id (keys of the IK: ``INS<ikid>_*``)."""
        return self.as_int(self.keyword("Kernels", "NaifFrameCode"), "Kernels/NaifFrameCode")

    @property
    def sensor_frame(self) -> int:
        """NAIF id of the sensor frame (look vectors are defined in it)."""
        return self.ikid

    @property
    def spacecraft_id(self) -> int:
        return q.body_code(str(self.platform_name))

    @property
    def target_id(self) -> int:
        return MOON

    @property
    def platform_name(self) -> str:
        return str(self.keyword("Instrument", "SpacecraftName"))

    @property
    def sensor_name(self) -> str:
        return str(self.keyword("Instrument", "InstrumentId"))

    def image_times(self) -> tuple[float, float, float]:
        """``(start, stop, line_period)`` in ET seconds (line period 0 for frames)."""
        raise NotImplementedError

    def sample_times(self) -> np.ndarray:
        """Epochs of the position and pointing tables: ALE's per sensor kind (shared kernel README 5.1, 8)."""
        start, stop, _ = self.image_times()
        if self.model == "linescan":
            return line_scan_epochs(start, stop, self.image_lines)
        if self.model in ("pushframe", "sar"):
            return np.linspace(start, stop, self.image_lines + 1)   # ALE's PushFrame and Radar rule
        return np.array([(start + stop) / 2.0])

    def center_time(self) -> float:
        """The ISD's ``center_ephemeris_time``: the middle of the image times."""
        start, stop, _ = self.image_times()
        return (start + stop) / 2.0

    def sensor_keys(self) -> dict[str, Any]:
        """Extra :class:`ImageSupport` fields of push-frame (``push_frame``) and SAR (``sar``) drivers."""
        return {}

    def position_correction(self) -> str:
        """Aberration correction of the sensor position (``"NONE"``, ``"LT+S"``, ``"SURFACE"``)."""
        kw = f"INS{self.ikid}_LIGHTTIME_CORRECTION"
        corr = str(q.pool_values(kw)[0]) if q.pool_has(kw) else "LT+S"
        if corr != "NONE" and q.pool_has(f"INS{self.ikid}_LT_SURFACE_CORRECT"):
            if str(q.pool_values(f"INS{self.ikid}_LT_SURFACE_CORRECT")[0]).upper() == "TRUE":
                return "SURFACE"
        return corr

    def ik(self, key: str, default: Any = None) -> Any:
        """An IK keyword of this instrument (scalar or list), ``default`` when absent."""
        name = f"INS{self.ikid}_{key}"
        if not q.pool_has(name):
            if default is None:
                raise UnknownInstrumentError(f"IK keyword {name} is not in the loaded kernels "
                                             f"(instrument {self.ikid}, label {self.source})")
            return default
        return _unlist(q.pool_values(name))

    # -- interior orientation hooks ------------------------------------------------
    def interior(self) -> dict[str, Any]:
        """Focal length, focal2pixel, detector centre/start, summing, distortion (ALE keys)."""
        return {
            "focal_length": float(self.ik("FOCAL_LENGTH")),
            "focal2pixel_lines": [float(v) for v in self.ik("ITRANSL")],
            "focal2pixel_samples": [float(v) for v in self.ik("ITRANSS")],
            "detector_center_line": float(self.ik("BORESIGHT_LINE")),
            "detector_center_sample": float(self.ik("BORESIGHT_SAMPLE")),
            "starting_detector_line": 0.0,
            "starting_detector_sample": 0.0,
            "line_summing": 1,
            "sample_summing": 1,
            "optical_distortion": {"radial": {"coefficients": [0.0, 0.0, 0.0]}},
        }

    def naif_keywords(self, body_frame_code: int) -> dict[str, Any]:
        """ALE's ``naif_keywords``: body, instrument and sensor-frame kernel-pool variables."""
        radii = q.body_radii(self.target_id)
        out: dict[str, Any] = {f"BODY{self.target_id}_RADII": radii.tolist(),
                               "BODY_FRAME_CODE": body_frame_code, "BODY_CODE": self.target_id}
        prefixes = (f"BODY{self.target_id}_", f"FRAME_{self.ikid}_", f"TKFRAME_{self.ikid}_",
                    f"CK_{self.ikid}_", f"INS{self.ikid}_")
        pool = q.instrument_keywords(self.ikid, extra_prefixes=prefixes[:-1])
        out.update({k: _unlist(v) for k, v in pool.items()})
        return out

    def check_instrument(self) -> None:
        """Raise :class:`UnknownInstrumentError` unless the kernels describe this instrument."""
        ikid = self.ikid
        if not q.pool_has(f"INS{ikid}_FOCAL_LENGTH"):
            raise UnknownInstrumentError(
                f"instrument id {ikid} (label {self.source}) is unknown to the loaded kernels: "
                f"no INS{ikid}_FOCAL_LENGTH; is its IK in the meta-kernel?")

    # -- the one SPICE pass ---------------------------------------------------------
    def image_support(self) -> ImageSupport:
        """Sample SPICE for this image. The caller holds the kernels loaded."""
        self.check_instrument()
        start, stop, line_period = self.image_times()
        times = self.sample_times()
        center = self.center_time()
        sc, body = self.spacecraft_id, self.target_id
        radii = q.body_radii(body)

        corr = self.position_correction()
        if corr == "SURFACE":
            state = q.surface_lt_states(sc, body, times, "J2000", (radii[0] + radii[2]) / 2.0)
        else:
            state = q.states(sc, times, "J2000", corr, body)
        sun_times = times[[0, -1]] if times.size > 1 else times.copy()
        sun = q.states(10, sun_times, "J2000", "LT+S", body)

        body_code, body_frame = q.body_frame(body)
        pointing = self._rotation_table(self.sensor_frame, times, rates=self.pointing_rates)
        # The body rotation is sampled where the ISD lists it (first and last epoch, as ALE does) and
        # interpolated to the other epochs exactly as a reader of the ISD file does: SPICE's own
        # per-epoch values differ from that smooth rotation only by its rounding noise (~8e-13 rad),
        # and an image written and read back stays the same camera.
        body_rot = self._rotation_table(body_code, sun_times).interpolated(times)
        xf = body_rot.state_transforms()

        io = self.interior() if self.model != "sar" else {}
        return ImageSupport(
            model=self.model, name_platform=self.platform_name, name_sensor=self.sensor_name,
            image_lines=self.image_lines, image_samples=self.image_samples,
            center_ephemeris_time=center, starting_ephemeris_time=start, line_period=line_period,
            times=times, positions=state[:, :3], velocities=state[:, 3:], pointing=pointing,
            body_rotation=body_rot, body_state_rotations=xf, sun_times=sun_times,
            sun_positions=sun[:, :3], sun_velocities=sun[:, 3:], radii=radii, body_frame=body_frame,
            naif_keywords=self.naif_keywords(body_code), isis_camera_version=self.isis_camera_version,
            # the NAIF ids let adjusted orientation be written back as kernels (orientation.kernels)
            provenance={"driver": self.name, "label": self.source, "position_correction": corr,
                        "spacecraft_id": int(sc), "target_id": int(body)},
            **io, **self.sensor_keys(),
        )

    def _rotation_table(self, frame: int, times: np.ndarray, rates: bool = True) -> RotationTable:
        # an instance method (it was static) so that drivers can override it with their own pointing
        constant, dependent = q.frame_trace(frame, float(times[0]))
        source = dependent[0]
        m = q.rotations("J2000", source, times)
        quats = matrix_to_quat(m)
        if rates:
            av = q.angular_velocities("J2000", source, times)
        else:
            av = rates_from_samples(times, quats)
        const = q.rotations(source, constant[0], times[:1])[0]
        return RotationTable(time_dependent_frames=dependent, times=times, quaternions=quats,
                             angular_velocities=av, constant_frames=constant, constant_rotation=const,
                             rates_given=rates)
