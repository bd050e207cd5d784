"""What push-frame and SAR images add to an ISD: framelet timing, and SAR range geometry.

The keys, names and units are those of USGS ALE's ISDs and usgscsm's
``USGS_ASTRO_PUSH_FRAME_SENSOR_MODEL`` / ``USGS_ASTRO_SAR_SENSOR_MODEL``
(``ale/formatters/formatter.py``, ``UsgsAstroPushFrameSensorModel::constructStateFromIsd``,
``UsgsAstroSarSensorModel::constructStateFromIsd``). Both are plain data: the camera package
turns them into sensor models (:mod:`lunarmap.camera.pushframe`, :mod:`lunarmap.camera.sar`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["PushFrameTiming", "SarParameters", "SAR_LOOK_DIRECTIONS"]

SAR_LOOK_DIRECTIONS = ("left", "right")


@dataclass(frozen=True)
class PushFrameTiming:
    """Framelet timing and layout of a push-frame image (LRO WAC).

    The image is a stack of framelets, each a short frame exposed at once; framelet ``k`` (image
    order) covers image lines ``[k h, (k + 1) h)`` with ``h = (framelet_height - num_lines_overlap) //
    detector_line_summing`` and is exposed at ``starting_ephemeris_time + exposure_duration / 2 +
    j * interframe_delay`` with ``j = k`` (``j = n - 1 - k`` when the order is reversed), as usgscsm's
    ``getImageTime``.

    Parameters
    ----------
    exposure_duration : float
        Framelet exposure, s.
    interframe_delay : float
        Time between successive framelets, s.
    framelet_height : int
        Detector lines of one framelet (before summing).
    framelets_flipped : bool
        Each framelet's lines are stored bottom-up (ISIS ``DataFlipped``).
    framelet_order_reversed : bool
        The image's first framelet is the last one exposed.
    num_lines_overlap : int
        Detector lines shared by neighbouring framelets, half of them dropped at either end.
    ending_ephemeris_time : float or None
        The ISD's ``ending_ephemeris_time`` (informational: usgscsm does not read it, and ALE's
        drivers disagree on it).
    """

    exposure_duration: float
    interframe_delay: float
    framelet_height: int
    framelets_flipped: bool = False
    framelet_order_reversed: bool = False
    num_lines_overlap: int = 0
    ending_ephemeris_time: float | None = None

    def framelet_lines(self, line_summing: int) -> int:
        """Image lines of one framelet (usgscsm's integer ``summedFrameletHeight``)."""
        return (int(self.framelet_height) - int(self.num_lines_overlap)) // int(line_summing)

    def problem(self, image_lines: int, line_summing: int) -> tuple[str, str] | None:
        """The key and what is inconsistent about the framelet layout, or ``None``."""
        if not self.exposure_duration > 0.0:
            return "exposure_duration", f"must be positive (s), got {self.exposure_duration!r}"
        if not self.interframe_delay > 0.0:
            return "interframe_delay", f"must be positive (s), got {self.interframe_delay!r}"
        if self.framelet_height < 1:
            return "framelet_height", f"must be >= 1 detector line, got {self.framelet_height!r}"
        if not 0 <= self.num_lines_overlap < self.framelet_height:
            return "num_lines_overlap", (f"must be >= 0 and below framelet_height {self.framelet_height}, "
                                         f"got {self.num_lines_overlap!r}")
        reduced = self.framelet_height - self.num_lines_overlap
        if reduced % line_summing:
            return "framelet_height", (f"{self.framelet_height} less num_lines_overlap {self.num_lines_overlap} is not "
                                       f"a multiple of detector_line_summing {line_summing}: framelets would not "
                                       "be whole image lines")
        h = reduced // line_summing
        if image_lines % h:
            return "image_lines", (f"{image_lines} is not a whole number of framelets of {h} image lines "
                                   f"(framelet_height {self.framelet_height}, num_lines_overlap "
                                   f"{self.num_lines_overlap}, detector_line_summing {line_summing})")
        return None

    def to_isd(self, starting: float, center: float) -> dict[str, Any]:
        out: dict[str, Any] = {
            "starting_ephemeris_time": float(starting),
        }
        if self.ending_ephemeris_time is not None:
            out["ending_ephemeris_time"] = float(self.ending_ephemeris_time)
        out.update({
            "center_ephemeris_time": float(center),
            "exposure_duration": float(self.exposure_duration),
            "interframe_delay": float(self.interframe_delay),
            "framelet_order_reversed": bool(self.framelet_order_reversed),
            "framelets_flipped": bool(self.framelets_flipped),
            "framelet_height": int(self.framelet_height),
            "num_lines_overlap": int(self.num_lines_overlap),
        })
        return out


@dataclass(frozen=True, eq=False)
class SarParameters:
    """Range geometry of a SAR image in zero-Doppler (slant-range) coordinates (LRO Mini-RF).

    Image line ``L`` is the zero-Doppler time ``starting_ephemeris_time + (L - 0.5) *
    line_exposure_duration``; sample ``S`` the ground range ``(S - 0.5) * scaled_pixel_width``, whose
    slant range is the cubic ``c0 + c1 g + c2 g² + c3 g³`` of the range-conversion set at that time.

    Parameters
    ----------
    wavelength : float
        Radar wavelength, m (used only for the Doppler frequency, not the geometry).
    line_exposure_duration : float
        Time per image line, s.
    scaled_pixel_width : float
        Ground range per image sample, m.
    range_conversion_times : ndarray (m,)
        Ephemeris times of the range-conversion sets, s.
    range_conversion_coefficients : ndarray (m, 4)
        Ground range (m) to slant range (m) cubic coefficients, ``c0 .. c3``.
    look_direction : {"left", "right"}
        Side of the ground track the radar looks at.
    ending_ephemeris_time : float
        End of the image, s (usgscsm searches zero-Doppler times within the image time span).
    """

    wavelength: float
    line_exposure_duration: float
    scaled_pixel_width: float
    range_conversion_times: NDArray[np.float64]
    range_conversion_coefficients: NDArray[np.float64]
    look_direction: str
    ending_ephemeris_time: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "range_conversion_times",
                           np.atleast_1d(np.asarray(self.range_conversion_times, dtype=float)))
        object.__setattr__(self, "range_conversion_coefficients",
                           np.asarray(self.range_conversion_coefficients, dtype=float).reshape(-1, 4))
        object.__setattr__(self, "look_direction", str(self.look_direction).lower())

    def problem(self) -> tuple[str, str] | None:
        """The key and what is inconsistent, or ``None``."""
        for key in ("wavelength", "line_exposure_duration", "scaled_pixel_width"):
            v = getattr(self, key)
            if not (np.isfinite(v) and v > 0.0):
                return key, f"must be a positive number, got {v!r}"
        t, c = self.range_conversion_times, self.range_conversion_coefficients
        if t.size == 0:
            return "range_conversion_times", "must hold at least one time"
        if c.shape[0] != t.size:
            return "range_conversion_coefficients", (f"has {c.shape[0]} sets for {t.size} range_conversion_times "
                                                     "(one set of 4 coefficients per time)")
        if t.size > 1 and np.any(np.diff(t) <= 0.0):
            return "range_conversion_times", "must be strictly increasing"
        if self.look_direction not in SAR_LOOK_DIRECTIONS:
            return "look_direction", f"must be 'left' or 'right', got {self.look_direction!r}"
        return None

    def to_isd(self, starting: float, center: float) -> dict[str, Any]:
        return {
            "starting_ephemeris_time": float(starting),
            "ending_ephemeris_time": float(self.ending_ephemeris_time),
            "center_ephemeris_time": float(center),
            "wavelength": float(self.wavelength),
            "line_exposure_duration": float(self.line_exposure_duration),
            "scaled_pixel_width": float(self.scaled_pixel_width),
            "range_conversion_times": self.range_conversion_times.tolist(),
            "range_conversion_coefficients": self.range_conversion_coefficients.tolist(),
            "look_direction": self.look_direction,
        }
