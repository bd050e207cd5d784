"""Reading ISD JSON documents (USGS ALE's layout, as written by ALE, usgscsm's tests or lunarmap) without SPICE.

Every ISD usgscsm accepts is read, with usgscsm's conventions (its ``constructStateFromIsd`` through
ALE's C++ ``Util.cpp``): frame, line-scan, push-frame (``exposure_duration``, ``interframe_delay``,
``framelet_height``, ``framelets_flipped``, ``framelet_order_reversed``, optional ``num_lines_overlap``)
and SAR ISDs (``wavelength``, ``line_exposure_duration``, ``scaled_pixel_width``,
``range_conversion_times`` / ``_coefficients``, ``look_direction``, ``ending_ephemeris_time``; no
focal plane and no pointing needed); velocities, pointing angular velocities (absent or null) and
``time_dependent_frames`` are optional; the pointing's ``constant_rotation`` counts only when the block
names its ``time_dependent_frames`` (usgscsm ignores it otherwise); positions and radii are km whatever
a ``unit`` key says (a radii unit other than km gets an
:class:`~lunarmap.errors.IsdConventionWarning`); quaternions and constant rotations written with
limited precision (up to 1e-3 off unit norm, 1e-5 off orthonormal) are read normalised, as usgscsm
reads them, with the same warning; files may be gzipped (``.json.gz``). Rolling-shutter
``jitter`` is refused by name (not modelled). Distortion blocks are checked against the schemas of
:mod:`lunarmap.orientation.distortion_schema`.

The document holds, in J2000 and km (see the shared kernel README, section 5):

* ``instrument_position``: sensor states relative to the body centre;
* ``instrument_pointing``: quaternions J2000 -> ``time_dependent_frames[0]``
  (and their ``xf2rav`` angular velocities), then ``constant_rotation`` on to
  the sensor frame;
* ``body_rotation``: the same for the body-fixed frame, usually at only the
  first and last epoch;
* ``sun_position``, the interior orientation and the image timing.

:func:`image_support_fields` gives the fields of an
:class:`~lunarmap.orientation.isd.ImageSupport` from it (``ImageSupport.from_ale_dict`` /
``ImageSupport.read_json`` build the object; this module does not import it, so the two do not
import each other):

* positions and pointing are put on one set of epochs, the union of both
  tables' epochs (pointing epochs within :data:`EPOCH_MERGE_TOLERANCE` of a
  position epoch are merged into it); a table's own epochs keep their values
  bit for bit. Positions are resampled with the cubic Hermite spline of
  positions *and* velocities: the interpolant
  :class:`~lunarmap.orientation.exterior.ExteriorOrientation` uses, so the extra
  nodes do not change the trajectory at all. Pointing quaternions are
  resampled by spherical linear interpolation between neighbouring samples,
  the model of SPICE's CK type 3, *not* with their angular velocities, which
  CK data do not match (see :func:`_resample_pointing`);
* the body rotation, which ALE lists at the first and last epoch only, and its
  6x6 state transformation (``sxform``) are rebuilt at every epoch with
  :class:`~lunarmap.orientation.rotation_hermite.RotationHermite`: a cubic
  Hermite interpolation on SO(3) through the listed rotations that matches
  their angular velocities (exact for a constant angular velocity), and
  constant-angular-velocity propagation outside the listed epochs.

Measured accuracy (tests/test_isd_json.py): the body rotation rebuilt from two
epochs agrees with SPICE's ``sxform`` to the rounding noise of SPICE's own
evaluation (3e-13 rad over ALE's 0.4 s LRO NAC image, 8e-13 rad over 16 s of
the synthetic mission; its rate to 2e-18 rad/s); from a synthetic mission's
kernels, positions resampled from samples 0.31 s apart agree with the SPK to
1e-9 m and pointing resampled from samples 31 ms apart with the CK to 1e-11 rad.
Real CK data are only piecewise smooth, and no interpolation of sampled
attitude (the camera's own between samples included) recovers a CK record
boundary it did not sample: LRO NAC pointing resampled from samples 2 ms apart
is exact to rounding (median 1e-16 rad) except in the intervals that span one
of the CK records, 0.1 s apart, where it is off by up to 1.5e-8 rad.

Every problem raises :class:`~lunarmap.errors.IsdFormatError` naming the
file and the key (``instrument_pointing.quaternions``); nothing is written.
"""

from __future__ import annotations

import gzip
import json
import math
import os
import zlib
from collections.abc import Iterator, Mapping
from numbers import Integral, Real
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.interpolate import CubicHermiteSpline, CubicSpline

from ..errors import IsdConventionWarning, IsdFormatError, warn
from .distortion_schema import distortion_block_problem
from .isd_kinds import PushFrameTiming, SarParameters
from .rotation import align_quaternion_signs, normalize_quat
from .rotation_hermite import RotationHermite, quat_exp, quat_log, quat_multiply, rates_from_samples
from .rotation_table import RotationTable

__all__ = ["image_support_fields", "read_isd_document", "SENSOR_MODELS", "EPOCH_MERGE_TOLERANCE",
           "KNOWN_BODY_FRAMES"]

#: usgscsm ``name_model`` -> lunarmap sensor model.
SENSOR_MODELS = {
    "USGS_ASTRO_FRAME_SENSOR_MODEL": "frame",
    "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL": "linescan",
    "USGS_ASTRO_PUSH_FRAME_SENSOR_MODEL": "pushframe",
    "USGS_ASTRO_SAR_SENSOR_MODEL": "sar",
}

#: Epochs of the position and pointing tables closer than this (s) are one epoch.
#: Closer nodes would only make the exterior orientation's splines ill-conditioned;
#: resampling over 1 microsecond changes nothing measurable.
EPOCH_MERGE_TOLERANCE = 1e-6

#: Names of lunar body-fixed frames by NAIF id, used when the document names none
#: (ALE's ISDs give only ``naif_keywords.BODY_FRAME_CODE``); from NAIF's built-in
#: frames, ``moon_080317.tf`` and ISIS's ``lunarMeanEarth001.tf``.
KNOWN_BODY_FRAMES = {
    10020: "IAU_MOON",
    31000: "MOON_PA",
    31001: "MOON_ME",
    31006: "MOON_PA_DE421",
    31007: "MOON_ME_DE421",
    310000: "LUNAR_PR_AXES",
    310001: "LUNAR_MEAN_EARTH",
    310002: "LUNAR_DE-403_PR_AXES",
    310003: "LUNAR_DE-403_MEAN_EARTH",
}

J2000 = 1
# unit quaternions and rotation matrices of full-precision writers (ALE, lunarmap) are unit / orthonormal
# to ~1e-15 and are used as they are within these tolerances (bit for bit)
_QUAT_NORM_TOL = 1e-6
_ORTHO_TOL = 1e-9
# writers printing 6 to 8 digits leave errors of ~1e-6: up to these tolerances the values are read
# normalised (quaternions) or as the nearest rotation (matrices), with an IsdConventionWarning, as usgscsm
# reads them (it normalises any quaternion); beyond them the data are refused as corrupted
_QUAT_NORMALISE_TOL = 1e-3
_ORTHO_PROJECT_TOL = 1e-5

Array = NDArray[np.float64]


class _Doc:
    """Typed access to the document's keys; every failure names the file and the key."""

    def __init__(self, source: str) -> None:
        self.where = f"ISD {source}" if source else "ISD (in memory)"

    def error(self, key: str, problem: str) -> IsdFormatError:
        return IsdFormatError(f"{self.where}: key {key!r} {problem}")

    def block(self, d: Mapping[str, Any], key: str, prefix: str = "") -> Mapping[str, Any]:
        v = self.get(d, key, prefix)
        if not isinstance(v, Mapping):
            raise self.error(prefix + key, f"must be a JSON object, got {type(v).__name__}")
        return v

    def get(self, d: Mapping[str, Any], key: str, prefix: str = "") -> Any:
        if key not in d:
            raise self.error(prefix + key, "is missing")
        return d[key]

    def number(self, d: Mapping[str, Any], key: str, prefix: str = "", default: float | None = None) -> float:
        if default is not None and key not in d:
            return default
        v = self.get(d, key, prefix)
        if isinstance(v, bool) or not isinstance(v, Real):
            raise self.error(prefix + key, f"must be a number, got {type(v).__name__} {v!r:.40}")
        if not _finite(v):
            raise self.error(prefix + key, f"must be a finite number, got {v!r:.40}")
        return float(v)

    def integer(self, d: Mapping[str, Any], key: str, prefix: str = "", minimum: int | None = None,
                default: int | None = None) -> int:
        if default is not None and key not in d:
            return default
        v = self.get(d, key, prefix)
        # 2.0 is accepted (some writers emit floats), 2.5 and True are not
        if not _integral(v):
            raise self.error(prefix + key, f"must be an integer, got {type(v).__name__} {v!r:.40}")
        if minimum is not None and v < minimum:
            raise self.error(prefix + key, f"must be >= {minimum}, got {v!r}")
        return int(v)

    def string(self, d: Mapping[str, Any], key: str, prefix: str = "") -> str:
        v = self.get(d, key, prefix)
        if not isinstance(v, str):
            raise self.error(prefix + key, f"must be a string, got {type(v).__name__} {v!r}")
        return v

    def int_list(self, d: Mapping[str, Any], key: str, prefix: str = "") -> list[int]:
        v = self.get(d, key, prefix)
        if (not isinstance(v, list) or not v
                or not all(_integral(x) for x in v)):
            raise self.error(prefix + key, f"must be a non-empty list of integers (NAIF ids), got {v!r:.80}")
        return [int(x) for x in v]

    def array(self, d: Mapping[str, Any], key: str, shape: tuple[int, ...], prefix: str = "") -> Array:
        """A numeric array of ``shape`` (-1: any length >= 1); nested lists of finite numbers only."""
        v = self.get(d, key, prefix)
        name = prefix + key
        if isinstance(v, np.ndarray):  # documents built in memory
            v = v.tolist()
        if not isinstance(v, list):
            raise self.error(name, f"must be a list of numbers, got {type(v).__name__}")
        for leaf in _leaves(v):
            if isinstance(leaf, bool) or not isinstance(leaf, Real):
                raise self.error(name, f"must hold numbers only, found {type(leaf).__name__} {leaf!r:.40}")
            if not _finite(leaf):
                raise self.error(name, f"must hold finite numbers only, found {leaf!r:.40}")
        try:
            a = np.array(v, dtype=float)
        except ValueError:
            raise self.error(name, "is a ragged list (rows of different lengths)") from None
        want = tuple(a.shape[i] if s == -1 else s for i, s in enumerate(shape)) if a.ndim == len(shape) else shape
        if a.shape != want or a.size == 0:
            expected = "(" + ", ".join("n" if s == -1 else str(s) for s in shape) + ")"
            raise self.error(name, f"must have shape {expected}, got {a.shape}")
        return a


def _finite(x: Real) -> bool:
    """Whether a number is finite as a float64 (JSON integers may exceed its range)."""
    try:
        return math.isfinite(x)  # type: ignore[arg-type]
    except OverflowError:
        return False


def _integral(x: Any) -> bool:
    """An integer, or a float with an integer value (2.0; some writers emit those); never a bool."""
    if isinstance(x, bool) or not isinstance(x, Real):
        return False
    return isinstance(x, Integral) or (_finite(x) and float(x).is_integer())


def _first_nonfinite(obj: Any, path: str) -> tuple[str, float] | None:
    """Key path and value of the first NaN or infinity anywhere in the document (JSON allows neither)."""
    if isinstance(obj, float):
        return None if math.isfinite(obj) else (path, obj)
    if isinstance(obj, Mapping):
        items = ((f"{path}.{k}" if path else str(k), v) for k, v in obj.items())
    elif isinstance(obj, list):
        items = ((f"{path}[{i}]", v) for i, v in enumerate(obj))
    else:
        return None
    for p, v in items:
        found = _first_nonfinite(v, p)
        if found is not None:
            return found
    return None


def _leaves(v: list[Any]) -> Iterator[Any]:
    for x in v:
        if isinstance(x, list):
            yield from _leaves(x)
        else:
            yield x


def _epochs(doc: _Doc, blk: Mapping[str, Any], prefix: str) -> Array:
    t = doc.array(blk, "ephemeris_times", (-1,), prefix)
    if t.size > 1 and np.any(np.diff(t) <= 0.0):
        raise doc.error(prefix + "ephemeris_times", "must be strictly increasing")
    return t


def _check_j2000(doc: _Doc, blk: Mapping[str, Any], prefix: str) -> None:
    if "reference_frame" in blk:
        ref = doc.integer(blk, "reference_frame", prefix)
        if ref != J2000:
            raise doc.error(prefix + "reference_frame",
                            f"is {ref}; only J2000 (1) can be read without SPICE")


def _states(doc: _Doc, d: Mapping[str, Any], key: str) -> tuple[Array, Array, Array]:
    """Times, positions and velocities (km, km/s) of a state table; velocities are optional.

    Positions are km whatever a ``unit`` key says: usgscsm reads them so (ALE's C++ ISD reader
    ignores the key). Missing velocities (usgscsm accepts tables without them) are the derivative of
    the not-a-knot cubic spline through the positions, zero for a single position.
    """
    blk = doc.block(d, key)
    p = key + "."
    _check_j2000(doc, blk, p)
    t = _epochs(doc, blk, p)
    pos = doc.array(blk, "positions", (t.size, 3), p)
    if "velocities" in blk:
        vel = doc.array(blk, "velocities", (t.size, 3), p)
    elif t.size == 1:
        vel = np.zeros((1, 3))
    elif t.size == 2:
        vel = np.repeat((pos[1:] - pos[:1]) / (t[1] - t[0]), 2, axis=0)
    else:
        vel = CubicSpline(t, pos, axis=0)(t, 1)
    return t, pos, vel


def _unit_quaternions(doc: _Doc, q: Array, key: str) -> Array:
    """Quaternion rows ``(n, 4)`` as unit quaternions, as usgscsm reads them.

    Rows within :data:`_QUAT_NORM_TOL` of unit norm are returned as they are; rows off by up to
    :data:`_QUAT_NORMALISE_TOL` (limited-precision writers) are normalised, with an
    :class:`~lunarmap.errors.IsdConventionWarning`.

    Raises
    ------
    IsdFormatError
        A row is further off unit norm (corrupted data; usgscsm would normalise even those).
    """
    norm = np.linalg.norm(q, axis=1)
    off = np.abs(norm - 1.0)
    if np.any(off > _QUAT_NORMALISE_TOL):
        i = int(np.argmax(off))
        raise doc.error(key, f"must hold unit quaternions; row {i} has norm {norm[i]!r} (up to "
                             f"{_QUAT_NORMALISE_TOL:g} off unit norm is read normalised)")
    loose = off > _QUAT_NORM_TOL
    if not loose.any():
        return q
    warn(f"{doc.where}: {key}: {int(loose.sum())} row(s) up to {off.max():.1e} off unit norm (limited "
         f"precision); read normalised, as usgscsm reads them", IsdConventionWarning)
    q = q.copy()
    q[loose] /= norm[loose, None]
    return q


def _rotation_matrix(doc: _Doc, c: Array, key: str) -> Array:
    """A row-major 3 x 3 rotation matrix as usgscsm reads it.

    Within :data:`_ORTHO_TOL` of orthonormal it is returned as it is; up to
    :data:`_ORTHO_PROJECT_TOL` (limited-precision writers) it is replaced by the nearest rotation
    (polar decomposition), with an :class:`~lunarmap.errors.IsdConventionWarning`.

    Raises
    ------
    IsdFormatError
        Further from orthonormal, or a reflection (determinant < 0).
    """
    err = float(np.abs(c @ c.T - np.eye(3)).max())
    if err > _ORTHO_PROJECT_TOL or np.linalg.det(c) < 0.0:
        raise doc.error(key, "is not a rotation matrix (row-major 3x3)")
    if err <= _ORTHO_TOL:
        return c
    u, _, vt = np.linalg.svd(c)
    warn(f"{doc.where}: {key} is {err:.1e} from orthonormal (limited precision); read as the nearest "
         f"rotation, as usgscsm reads it", IsdConventionWarning)
    return u @ vt


class _Rotations:
    """One rotation block: J2000 -> ``time_dependent_frames[0]`` samples, then the constant part.

    As usgscsm (ALE's C++ ``getInstrumentPointing`` / ``getBodyRotation``) reads them: the frame
    lists are optional; the pointing's ``constant_rotation`` is read only when the block names its
    ``time_dependent_frames`` (usgscsm ignores it otherwise), the body rotation's whenever present.
    """

    def __init__(self, doc: _Doc, d: Mapping[str, Any], key: str, need_rates: bool,
                 constant_needs_frames: bool = False) -> None:
        blk = doc.block(d, key)
        p = key + "."
        _check_j2000(doc, blk, p)
        self.time_dependent_frames = (doc.int_list(blk, "time_dependent_frames", p)
                                      if "time_dependent_frames" in blk else [])
        self.times = _epochs(doc, blk, p)
        n = self.times.size
        q = _unit_quaternions(doc, doc.array(blk, "quaternions", (n, 4), p), p + "quaternions")
        self.rates_given = need_rates or blk.get("angular_velocities") is not None   # null: no rates (ALE)
        if self.rates_given:
            av = doc.array(blk, "angular_velocities", (n, 3), p)
        else:
            av = rates_from_samples(self.times, q)
        own_frames = self.time_dependent_frames[:1]
        if "constant_rotation" in blk and (self.time_dependent_frames or not constant_needs_frames):
            self.constant_rotation = _rotation_matrix(
                doc, doc.array(blk, "constant_rotation", (9,), p).reshape(3, 3), p + "constant_rotation")
            self.constant_frames = (doc.int_list(blk, "constant_frames", p) if "constant_frames" in blk
                                    else own_frames)
        else:
            self.constant_rotation = np.eye(3)
            self.constant_frames = own_frames
        self.quaternions = q
        self.angular_velocities = av


def _identity_pointing(times: Array) -> "_Rotations":
    """The pointing of a SAR ISD without ``instrument_pointing`` (usgscsm's SAR model reads none)."""
    r = object.__new__(_Rotations)
    r.time_dependent_frames, r.times = [], times
    r.quaternions = np.tile([1.0, 0.0, 0.0, 0.0], (times.size, 1))
    r.angular_velocities = np.zeros((times.size, 3))
    r.constant_rotation, r.constant_frames = np.eye(3), []
    r.rates_given = False
    return r


def _resample_pointing(times: Array, q: Array, av: Array, at: Array) -> tuple[Array, Array]:
    """Pointing quaternions and angular velocities at epochs ``at``.

    Between two samples the rotation turns about a fixed axis at a constant rate
    (spherical linear interpolation, extended at the same rate beyond the ends),
    without the sampled angular velocities. That is the model of SPICE's CK
    type 3, which most missions' attitude comes in: piecewise geodesic, with rate
    jumps at the CK records that a smooth interpolant would spread over
    neighbouring samples. The angular velocities SPICE reports for such data
    are interpolated linearly and disagree with the quaternions' own motion (by
    up to 3e-5 rad/s for LRO NAC in the shared set); Kaguya TC's CK even stores
    rates unrelated to its quaternions (about (3.0e-3, 1e-4, 0) rad/s while they
    turn at 9.3e-4 rad/s about another axis), so a Hermite interpolation
    honouring them would import those errors (2e-5 rad for Kaguya samples 65 ms
    apart). The angular velocities themselves (kept only to be written out
    again) are interpolated linearly, as SPICE does. A single sample is
    propagated with its angular velocity held constant.
    """
    if times.size == at.size and np.array_equal(times, at):
        return q, av
    if times.size == 1:
        q_out, w_out = RotationHermite(times, q, av)(at)
        return q_out, w_out
    aligned = align_quaternion_signs(normalize_quat(q))
    k = np.clip(np.searchsorted(times, at, side="right") - 1, 0, times.size - 2)
    s = ((at - times[k]) / (times[k + 1] - times[k]))[:, None]
    # aligned neighbours have a non-negative dot product: the relative rotation's w >= 0
    rel = quat_multiply(aligned[k] * np.array([1.0, -1.0, -1.0, -1.0]), aligned[k + 1])
    q_out = normalize_quat(quat_multiply(aligned[k], quat_exp(s * quat_log(rel))))
    w_out = np.stack([np.interp(at, times, av[:, i]) for i in range(3)], axis=-1)
    hit = np.searchsorted(times, at).clip(0, times.size - 1)
    exact = times[hit] == at
    q_out[exact], w_out[exact] = q[hit[exact]], av[hit[exact]]
    return q_out, w_out


def _merge_epochs(pos_times: Array, att_times: Array) -> Array:
    near = np.zeros(att_times.size, dtype=bool)
    k = np.searchsorted(pos_times, att_times)
    for j in (k - 1, k):
        ok = (j >= 0) & (j < pos_times.size)
        near[ok] |= np.abs(pos_times[j[ok]] - att_times[ok]) < EPOCH_MERGE_TOLERANCE
    return np.union1d(pos_times, att_times[~near])


def _resample_states(t: Array, pos: Array, vel: Array, at: Array) -> tuple[Array, Array]:
    if t.size == at.size and np.array_equal(t, at):
        return pos, vel
    if t.size == 1:
        # one sample: straight-line motion (the table carries no acceleration)
        p, v = pos[0] + (at - t[0])[:, None] * vel[0], np.broadcast_to(vel[0], (at.size, 3)).copy()
    else:
        spline = CubicHermiteSpline(t, pos, vel, axis=0)
        p, v = spline(at), spline(at, 1)
    k = np.searchsorted(t, at).clip(0, t.size - 1)
    exact = t[k] == at
    p[exact], v[exact] = pos[k[exact]], vel[k[exact]]
    return p, v


def _body_frame_name(doc: _Doc, naif: Mapping[str, Any], own: Mapping[str, Any]) -> str:
    if "body_frame" in own:
        return doc.string(own, "body_frame", "lunarmap.")
    code = naif.get("BODY_FRAME_CODE")
    if code is not None and _integral(code):      # _integral(None) is False
        code = int(code)
        named = naif.get(f"FRAME_{code}_NAME")
        if isinstance(named, str):
            return named
        return KNOWN_BODY_FRAMES.get(code, f"FRAME_{code}")
    return "UNKNOWN"


def _distortion(doc: _Doc, d: Mapping[str, Any]) -> dict[str, Any]:
    blk = doc.block(d, "optical_distortion")
    if len(blk) != 1:
        raise doc.error("optical_distortion", f"must name exactly one model, got {sorted(blk)}")
    model, coeffs = next(iter(blk.items()))
    key = f"optical_distortion.{model}"
    bad = distortion_block_problem(str(model), coeffs)
    if bad is not None:
        raise doc.error(f"{key}.{bad[0]}" if bad[0] else key, bad[1])
    return {str(model): json.loads(json.dumps(coeffs))}


def _radii(doc: _Doc, d: Mapping[str, Any]) -> Array:
    """Body radii, km: usgscsm reads ``radii`` in km whatever its ``unit`` says, and so does lunarmap."""
    radii_blk = doc.block(d, "radii")
    if "unit" in radii_blk:
        unit = doc.string(radii_blk, "unit", "radii.")
        if unit.strip().lower() not in ("km", "kilometers", "kilometres"):
            warn(f"{doc.where}: radii.unit is {unit!r}; the radii are read in km, as usgscsm reads them",
                 IsdConventionWarning)
    a = doc.number(radii_blk, "semimajor", "radii.")
    c = doc.number(radii_blk, "semiminor", "radii.")
    if not (a > 0.0 and c > 0.0):
        raise doc.error("radii", f"must be positive, got semimajor {a!r}, semiminor {c!r} km")
    return np.array([a, a, c])


def _boolean(doc: _Doc, d: Mapping[str, Any], key: str) -> bool:
    v = doc.get(d, key)
    if not isinstance(v, bool):
        raise doc.error(key, f"must be true or false, got {v!r:.40}")
    return v


def _push_frame(doc: _Doc, d: Mapping[str, Any], lines: int, summing: int) -> PushFrameTiming:
    timing = PushFrameTiming(
        exposure_duration=doc.number(d, "exposure_duration"),
        interframe_delay=doc.number(d, "interframe_delay"),
        framelet_height=doc.integer(d, "framelet_height", minimum=1),
        framelets_flipped=_boolean(doc, d, "framelets_flipped"),
        framelet_order_reversed=_boolean(doc, d, "framelet_order_reversed"),
        num_lines_overlap=doc.integer(d, "num_lines_overlap", minimum=0, default=0),
        ending_ephemeris_time=doc.number(d, "ending_ephemeris_time") if "ending_ephemeris_time" in d else None)
    bad = timing.problem(lines, summing)
    if bad is not None:
        raise doc.error(*bad)
    return timing


def _sar(doc: _Doc, d: Mapping[str, Any]) -> SarParameters:
    times = doc.array(d, "range_conversion_times", (-1,))
    params = SarParameters(
        wavelength=doc.number(d, "wavelength"),
        line_exposure_duration=doc.number(d, "line_exposure_duration"),
        scaled_pixel_width=doc.number(d, "scaled_pixel_width"),
        range_conversion_times=times,
        range_conversion_coefficients=doc.array(d, "range_conversion_coefficients", (-1, 4)),
        look_direction=doc.string(d, "look_direction"),
        ending_ephemeris_time=doc.number(d, "ending_ephemeris_time"))
    bad = params.problem()
    if bad is not None:
        raise doc.error(*bad)
    return params


def _interior(doc: _Doc, d: Mapping[str, Any]) -> dict[str, Any]:
    """Focal plane, detector and distortion of an optical sensor (frame, line scan, push frame)."""
    focal = doc.number(doc.block(d, "focal_length_model"), "focal_length", "focal_length_model.")
    if focal == 0.0:  # negative: the camera looks along -z of its frame (lunarmap's Lunar Orbiter, Apollo metric)
        raise doc.error("focal_length_model.focal_length", f"must be non-zero (mm), got {focal!r}")
    f2l = doc.array(d, "focal2pixel_lines", (3,))
    f2s = doc.array(d, "focal2pixel_samples", (3,))
    if abs(f2l[1] * f2s[2] - f2l[2] * f2s[1]) == 0.0:
        raise doc.error("focal2pixel_lines", "and focal2pixel_samples form a singular transform")
    centre = doc.block(d, "detector_center")
    return dict(
        focal_length=focal, focal2pixel_lines=f2l.tolist(), focal2pixel_samples=f2s.tolist(),
        detector_center_line=doc.number(centre, "line", "detector_center."),
        detector_center_sample=doc.number(centre, "sample", "detector_center."),
        starting_detector_line=doc.number(d, "starting_detector_line"),
        starting_detector_sample=doc.number(d, "starting_detector_sample"),
        optical_distortion=_distortion(doc, d))


def image_support_fields(d: Mapping[str, Any], source: str = "") -> dict[str, Any]:
    """The :class:`~lunarmap.orientation.isd.ImageSupport` fields of an ISD document (keyword arguments).

    Parameters
    ----------
    d : mapping
        The parsed JSON document (ALE's layout; not modified).
    source : str
        File name for messages.

    Raises
    ------
    IsdFormatError
        Missing key, wrong type or shape, non-finite number, unknown ``name_model``
        or distortion model, inconsistent timing; the file and the key are named.
    """

    doc = _Doc(source)
    if not isinstance(d, Mapping):
        raise IsdFormatError(f"{doc.where}: the document must be a JSON object, got {type(d).__name__}")
    bad = _first_nonfinite(d, "")
    if bad is not None:
        raise doc.error(bad[0], f"holds a non-finite number ({bad[1]!r})")
    name_model = doc.string(d, "name_model")
    if name_model not in SENSOR_MODELS:
        raise doc.error("name_model", f"is {name_model!r}; lunarmap reads {sorted(SENSOR_MODELS)}")
    model = SENSOR_MODELS[name_model]
    if "jitter" in d:
        # usgscsm's rolling-shutter jitter of framing cameras; ignoring it would silently misplace pixels
        raise doc.error("jitter", "(rolling-shutter jitter) is not modelled by lunarmap")
    lines = doc.integer(d, "image_lines", minimum=1)
    samples = doc.integer(d, "image_samples", minimum=1)
    center = doc.number(d, "center_ephemeris_time")
    optical = model != "sar"
    # SAR images have no detector: usgscsm reads no summing for them
    line_summing = doc.integer(d, "detector_line_summing", minimum=1) if optical else 1
    sample_summing = doc.integer(d, "detector_sample_summing", minimum=1) if optical else 1
    rows: Array | None = None
    kind_fields: dict[str, Any] = {}
    line_period = 0.0
    if model == "linescan":
        start = doc.number(d, "starting_ephemeris_time")
        rows = doc.array(d, "line_scan_rate", (-1, 3))
        if np.any(rows[:, 2] <= 0.0):
            raise doc.error("line_scan_rate", "must have positive line periods (third column, s)")
        if np.any(np.diff(rows[:, 0]) <= 0.0):
            raise doc.error("line_scan_rate", "rows must start at increasing lines (first column)")
        line_period = float(rows[0, 2])
    elif model == "pushframe":
        start = doc.number(d, "starting_ephemeris_time")
        kind_fields["push_frame"] = _push_frame(doc, d, lines, line_summing)
    elif model == "sar":
        start = doc.number(d, "starting_ephemeris_time")
        kind_fields["sar"] = sar = _sar(doc, d)
        line_period = sar.line_exposure_duration
    else:
        start = doc.number(d, "starting_ephemeris_time", default=center)

    radii = _radii(doc, d)
    pos_t, pos, vel = _states(doc, d, "instrument_position")
    sun_t, sun_pos, sun_vel = _states(doc, d, "sun_position")
    if optical or "instrument_pointing" in d:
        pointing = _Rotations(doc, d, "instrument_pointing", need_rates=False, constant_needs_frames=True)
    else:
        pointing = _identity_pointing(pos_t)
    body = _Rotations(doc, d, "body_rotation", need_rates=True)

    times = _merge_epochs(pos_t, pointing.times)
    positions, velocities = _resample_states(pos_t, pos, vel, times)
    q_p, w_p = _resample_pointing(pointing.times, pointing.quaternions, pointing.angular_velocities, times)
    # the body rotation is smooth (PCK) and its angular velocities are exact: Hermite on SO(3)
    body_table = RotationTable(body.time_dependent_frames, body.times, body.quaternions, body.angular_velocities,
                               body.constant_frames, body.constant_rotation).interpolated(times)
    body_xf = body_table.state_transforms()
    sun_body = body.constant_rotation @ RotationHermite(body.times, body.quaternions,
                                                        body.angular_velocities).matrices(sun_t)
    if optical:
        kind_fields.update(_interior(doc, d))
    naif = doc.block(d, "naif_keywords") if "naif_keywords" in d else {}
    own = doc.block(d, "lunarmap") if "lunarmap" in d else {}
    provenance = {k: v for k, v in json.loads(json.dumps(own)).items() if k != "body_frame"}
    if source:
        provenance["isd_file"] = source

    return dict(
        model=model, name_platform=doc.string(d, "name_platform"), name_sensor=doc.string(d, "name_sensor"),
        image_lines=lines, image_samples=samples, center_ephemeris_time=center,
        starting_ephemeris_time=start, line_period=line_period, times=times, positions=positions,
        velocities=velocities,
        pointing=RotationTable(pointing.time_dependent_frames, times, q_p, w_p, pointing.constant_frames,
                               pointing.constant_rotation, pointing.rates_given),
        body_rotation=body_table,
        body_state_rotations=body_xf, sun_times=sun_t, sun_positions=sun_pos, sun_velocities=sun_vel,
        radii=radii, body_frame=_body_frame_name(doc, naif, own),
        line_summing=line_summing, sample_summing=sample_summing,
        naif_keywords=json.loads(json.dumps(naif)),
        isis_camera_version=doc.integer(d, "isis_camera_version", default=1),
        provenance=provenance, line_scan_rates=rows, sun_body_rotations=sun_body, **kind_fields,
    )


def read_isd_document(path: str | os.PathLike[str]) -> tuple[Any, str]:
    """The parsed JSON document of an ISD file and its name (see :func:`image_support_fields`).

    A name ending in ``.gz`` is read through gzip (ISDs of long images run to megabytes).

    Raises
    ------
    FileNotFoundError
        No such file.
    IsdFormatError
        Not UTF-8 text, not JSON or a damaged gzip stream; the file is named.
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"ISD file {p} does not exist")
    try:
        if p.name.endswith(".gz"):
            with gzip.open(p, "rb") as fh:
                text = fh.read().decode("utf-8")
        else:
            text = p.read_text(encoding="utf-8")
    except (OSError, EOFError, zlib.error) as err:
        raise IsdFormatError(f"ISD {p}: not a readable gzip file ({err})") from None
    except UnicodeDecodeError as err:
        raise IsdFormatError(f"ISD {p}: not UTF-8 text ({err.reason} at byte {err.start})") from None
    try:
        # NaN / Infinity literals (a Python extension of JSON) are parsed, then refused with their key
        d = json.loads(text)
    except json.JSONDecodeError as err:
        raise IsdFormatError(f"ISD {p}: malformed JSON at line {err.lineno}, column {err.colno}: {err.msg}") from None
    return d, str(p)
