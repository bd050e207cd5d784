"""Image support data (ISD): everything a sensor model needs, sampled once.

:class:`ImageSupport` holds, for one image, the sampled SPICE geometry in the
frames and units of USGS ALE's ISDs (J2000, km, km/s, rad/s, SPICE
quaternions) plus the interior orientation. It writes the JSON document that
USGS CSM (usgscsm) and ALE users know (:meth:`ImageSupport.to_ale_dict`), and it
derives the body-fixed :class:`~lunarmap.orientation.exterior.ExteriorOrientation`
(metres) that lunarmap's camera models use (:meth:`ImageSupport.exterior_orientation`).

The body rotation is kept at *every* pointing epoch internally (the ISD
itself, like ALE's, lists only the first and last) so that the body-fixed
trajectory is exact at each sample.

:meth:`ImageSupport.read_json` / :meth:`ImageSupport.from_ale_dict` read such
documents back, from lunarmap or from ALE, without SPICE (see
:mod:`lunarmap.orientation.isd_reader`).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..atomic import atomic_write
from ..errors import InvalidInputError
from .exterior import ExteriorOrientation
from .isd_kinds import PushFrameTiming, SarParameters
from .rotation import matrix_to_quat
from .rotation_table import J2000, RotationTable

__all__ = ["RotationTable", "ImageSupport", "PushFrameTiming", "SarParameters", "NAME_MODELS", "line_scan_epochs",
           "write_json_atomic"]



def line_scan_epochs(start: float, stop: float, lines: int) -> NDArray[np.float64]:
    """ALE's sampling grid for line scanners: every 10th line, at least 100 samples."""
    n = lines // 10 + 1
    n = lines + 1 if n < 100 else n
    return np.linspace(start, stop, n)


#: lunarmap's name of each kind of sensor -> usgscsm ``name_model``.
NAME_MODELS = {
    "frame": "USGS_ASTRO_FRAME_SENSOR_MODEL",
    "linescan": "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL",
    "pushframe": "USGS_ASTRO_PUSH_FRAME_SENSOR_MODEL",
    "sar": "USGS_ASTRO_SAR_SENSOR_MODEL",
}

#: Sensors looking through optics (focal plane, distortion); SAR has none.
OPTICAL_MODELS = ("frame", "linescan", "pushframe")


@dataclass
class ImageSupport:
    """Sampled geometry and camera constants of one image (ALE ISD content).

    Units follow ALE's ISD: km, km/s, seconds of ephemeris time, millimetres in
    the focal plane. ``model`` is ``"frame"``, ``"linescan"``, ``"pushframe"`` (with
    :attr:`push_frame`) or ``"sar"`` (with :attr:`sar`; a SAR image has no focal plane, so the
    interior-orientation fields keep their defaults and are not written).
    """

    model: str
    name_platform: str
    name_sensor: str
    image_lines: int
    image_samples: int
    center_ephemeris_time: float
    starting_ephemeris_time: float
    line_period: float  # s per line (0 for framing cameras)
    times: NDArray[np.float64]
    positions: NDArray[np.float64]  # km, J2000, sensor w.r.t. body centre
    velocities: NDArray[np.float64]  # km/s
    pointing: RotationTable
    body_rotation: RotationTable  # sampled at self.times
    body_state_rotations: NDArray[np.float64]  # (n, 6, 6) J2000 -> body-fixed, at self.times
    sun_times: NDArray[np.float64]
    sun_positions: NDArray[np.float64]  # km, J2000, Sun w.r.t. body centre
    sun_velocities: NDArray[np.float64]
    radii: NDArray[np.float64]  # km
    body_frame: str
    focal_length: float = float("nan")
    focal2pixel_lines: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    focal2pixel_samples: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    detector_center_line: float = 0.0
    detector_center_sample: float = 0.0
    starting_detector_line: float = 0.0
    starting_detector_sample: float = 0.0
    line_summing: int = 1
    sample_summing: int = 1
    optical_distortion: dict[str, Any] = field(default_factory=dict)
    naif_keywords: dict[str, Any] = field(default_factory=dict)
    isis_camera_version: int = 1
    provenance: dict[str, Any] = field(default_factory=dict)
    #: usgscsm ``line_scan_rate`` rows ``[line, time - centre (s), s per line]`` when they were given
    #: (read from a file, possibly several: variable line rate); ``None``: one row from ``line_period``.
    line_scan_rates: NDArray[np.float64] | None = None
    #: J2000 -> body-fixed rotations at ``sun_times`` (m, 3, 3), when the Sun epochs are not among
    #: ``times``; ``None``: taken from ``body_state_rotations`` at the nearest sample.
    sun_body_rotations: NDArray[np.float64] | None = None
    #: framelet timing of a push-frame image (``model == "pushframe"``)
    push_frame: PushFrameTiming | None = None
    #: range geometry of a SAR image (``model == "sar"``)
    sar: SarParameters | None = None

    def __post_init__(self) -> None:
        if self.model not in NAME_MODELS:
            raise InvalidInputError(f"unknown sensor model {self.model!r}; use one of {sorted(NAME_MODELS)}")
        if self.line_scan_rates is not None:
            rows = np.asarray(self.line_scan_rates, dtype=float)
            if rows.ndim != 2 or rows.shape[1] != 3 or rows.shape[0] == 0:
                raise InvalidInputError(f"line_scan_rates must have shape (m, 3), got {rows.shape}")
            self.line_scan_rates = rows
        if (self.model == "pushframe") != (self.push_frame is not None):
            raise InvalidInputError("a push-frame ImageSupport needs push_frame timing, and only it")
        if (self.model == "sar") != (self.sar is not None):
            raise InvalidInputError("a SAR ImageSupport needs sar parameters, and only it")
        if self.push_frame is not None:
            bad = self.push_frame.problem(int(self.image_lines), int(self.line_summing))
            if bad is not None:
                raise InvalidInputError(f"push-frame timing: {bad[0]} {bad[1]}")
        if self.sar is not None:
            bad = self.sar.problem()
            if bad is not None:
                raise InvalidInputError(f"SAR parameters: {bad[0]} {bad[1]}")
        if self.model in OPTICAL_MODELS and not (np.isfinite(self.focal_length) and self.focal_length != 0.0):
            raise InvalidInputError(f"a {self.model} camera needs a finite non-zero focal length, "
                                    f"got {self.focal_length!r}")

    # -- construction from documents -------------------------------------------
    @classmethod
    def from_ale_dict(cls, d: dict[str, Any], source: str = "") -> "ImageSupport":
        """Build from an ISD document in ALE's layout (as :meth:`to_ale_dict` or ALE writes it).

        No SPICE is involved: the body rotation, given at a few epochs with its
        angular velocities, is interpolated to every position/pointing epoch.

        Parameters
        ----------
        d : dict
            The parsed JSON document (left unchanged).
        source : str
            File name, for messages and provenance.

        Raises
        ------
        IsdFormatError
            The document is malformed; the message names the source and the key.
        """
        from .isd_reader import image_support_fields

        return cls(**image_support_fields(d, source=source))

    @classmethod
    def read_json(cls, path: str | os.PathLike[str]) -> "ImageSupport":
        """Read an ISD JSON file written by lunarmap (:meth:`write_json`) or USGS ALE.

        Raises
        ------
        FileNotFoundError
            No such file.
        IsdFormatError
            Malformed JSON or ISD; the message names the file and the key.
        """
        from .isd_reader import read_isd_document

        d, source = read_isd_document(path)
        return cls.from_ale_dict(d, source=source)

    # -- derived quantities ---------------------------------------------------
    @property
    def line_scan_rate(self) -> list[list[float]]:
        """usgscsm's ``[[line, time relative to centre, seconds per line]]`` (ISIS line convention)."""
        if self.line_scan_rates is not None:
            return np.asarray(self.line_scan_rates, dtype=float).tolist()
        return [[0.5, self.starting_ephemeris_time - self.center_ephemeris_time, self.line_period]]

    def sensor_to_body_matrices(self) -> NDArray[np.float64]:
        """Rotation sensor frame -> body-fixed frame at ``self.times``, (n, 3, 3)."""
        j2000_to_body = self.body_state_rotations[:, :3, :3]
        j2000_to_sensor = self.pointing.matrices()
        return j2000_to_body @ np.transpose(j2000_to_sensor, (0, 2, 1))

    def exterior_orientation(self, epoch: float | None = None) -> ExteriorOrientation:
        """The body-fixed, metre-based exterior orientation of this image.

        Parameters
        ----------
        epoch : float, optional
            Reference ET for the relative times; defaults to the centre time of a framing
            camera and to the image start of the others.
        """
        if epoch is None:
            epoch = self.center_ephemeris_time if self.model == "frame" else self.starting_ephemeris_time
        xf = self.body_state_rotations
        state = np.concatenate([self.positions, self.velocities], axis=1)
        bf = np.einsum("nij,nj->ni", xf, state) * 1000.0
        quats = matrix_to_quat(self.sensor_to_body_matrices())
        if self.sun_body_rotations is not None:
            sun_rot = np.asarray(self.sun_body_rotations, dtype=float)
        else:
            # the Sun samples are a subset of the pointing epochs (first and last)
            idx = np.searchsorted(self.times, self.sun_times).clip(0, self.times.size - 1)
            sun_rot = xf[idx, :3, :3]
        sun_bf = np.einsum("nij,nj->ni", sun_rot, self.sun_positions) * 1000.0
        return ExteriorOrientation(
            epoch=float(epoch), times=self.times - epoch, positions=bf[:, :3], velocities=bf[:, 3:],
            quaternions=quats, sun_times=self.sun_times - epoch, sun_positions=sun_bf,
            body_frame=self.body_frame,
            attrs={"sensor": self.name_sensor, "platform": self.name_platform, **{
                k: v for k, v in self.provenance.items() if isinstance(v, (str, int, float))}},
        )

    # -- output ---------------------------------------------------------------
    def to_ale_dict(self, csm: bool = False) -> dict[str, Any]:
        """The ISD as ALE's ``ale.formatters.formatter.to_isd`` lays it out.

        Parameters
        ----------
        csm : bool
            Replace a distortion model usgscsm does not apply (Apollo metric, Lunar Orbiter) by a fitted
            ``transverse`` polynomial, its fit error in the ``lunarmap`` block
            (:func:`lunarmap.camera.csm.csm_image_support`).
        """
        if csm:
            # the fit needs the distortion models, which live in the camera package (imported on demand:
            # the one call from orientation up into camera, for this output option only)
            from ..camera.csm import csm_image_support

            return csm_image_support(self).to_ale_dict()
        isd: dict[str, Any] = {
            "isis_camera_version": self.isis_camera_version,
            "image_lines": int(self.image_lines),
            "image_samples": int(self.image_samples),
            "name_platform": self.name_platform,
            "name_sensor": self.name_sensor,
            "reference_height": {"maxheight": 1000, "minheight": -1000, "unit": "m"},
            "name_model": NAME_MODELS[self.model],
        }
        start, center = self.starting_ephemeris_time, self.center_ephemeris_time
        if self.model == "linescan":
            isd["interpolation_method"] = "lagrange"
            isd["line_scan_rate"] = self.line_scan_rate
            isd["starting_ephemeris_time"] = start
            isd["center_ephemeris_time"] = center
        elif self.push_frame is not None:
            isd.update(self.push_frame.to_isd(start, center))
        elif self.sar is not None:
            isd.update(self.sar.to_isd(start, center))
        else:
            isd["center_ephemeris_time"] = center
        isd["radii"] = {"semimajor": float(self.radii[0]), "semiminor": float(self.radii[2]), "unit": "km"}
        ends = [0, self.times.size - 1] if self.times.size > 1 else [0]
        isd["body_rotation"] = self.body_rotation.to_dict(every=np.array(ends), always_constant=False)  # type: ignore[arg-type]
        isd["instrument_pointing"] = self.pointing.to_dict()
        isd["naif_keywords"] = self.naif_keywords
        if self.model in OPTICAL_MODELS:
            isd["detector_sample_summing"] = int(self.sample_summing)
            isd["detector_line_summing"] = int(self.line_summing)
            isd["focal_length_model"] = {"focal_length": self.focal_length}
            isd["detector_center"] = {"line": self.detector_center_line, "sample": self.detector_center_sample}
            isd["focal2pixel_lines"] = list(self.focal2pixel_lines)
            isd["focal2pixel_samples"] = list(self.focal2pixel_samples)
            isd["optical_distortion"] = self.optical_distortion
            isd["starting_detector_line"] = self.starting_detector_line
            isd["starting_detector_sample"] = self.starting_detector_sample
        isd["instrument_position"] = _position_block(self.times, self.positions, self.velocities)
        isd["sun_position"] = _position_block(self.sun_times, self.sun_positions, self.sun_velocities)
        # ALE's layout names the body-fixed frame only by its NAIF id (naif_keywords.BODY_FRAME_CODE)
        isd["lunarmap"] = {**self.provenance, "body_frame": self.body_frame}
        return _jsonable(isd)

    def write_json(self, path: str | os.PathLike[str], csm: bool = False) -> None:
        """Write :meth:`to_ale_dict` (``csm``: see there) as JSON, atomically (no partial file on failure)."""
        write_json_atomic(self.to_ale_dict(csm=True) if csm else self.to_ale_dict(), path)


def _position_block(times: NDArray[np.float64], pos: NDArray[np.float64], vel: NDArray[np.float64]) -> dict[str, Any]:
    return {
        "spk_table_start_time": float(times[0]),
        "spk_table_end_time": float(times[-1]),
        "spk_table_original_size": int(times.size),
        "ephemeris_times": times.tolist(),
        "positions": pos.tolist(),
        "velocities": vel.tolist(),
        "reference_frame": J2000,
    }


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        raise InvalidInputError("ISD holds a non-finite number")
    return obj


def write_json_atomic(data: Any, path: str | os.PathLike[str]) -> None:
    """Write JSON to ``path`` via a temporary file in the same folder, then rename."""
    def write(tmp: Path) -> None:
        with open(tmp, "w") as fh:
            json.dump(data, fh, indent=2)

    atomic_write(path, write)
