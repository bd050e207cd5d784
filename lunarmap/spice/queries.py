"""Vectorised, locked wrappers around the SPICE queries lunarmap needs.

Every function takes the :data:`~lunarmap.spice.pool.SPICE_LOCK`, loops over
epochs inside one lock acquisition, and converts SPICE failures into lunarmap
exceptions naming the object and the epoch. Units are SPICE's (km, km/s,
radians) here; conversion to metres happens in :mod:`lunarmap.orientation`.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import spiceypy
from numpy.typing import ArrayLike, NDArray
from spiceypy.utils.exceptions import SpiceyError

from ..errors import KernelCoverageError, UnknownInstrumentError
from .pool import SPICE_LOCK, spice_errors

__all__ = [
    "states", "surface_lt_states", "rotations", "state_rotations", "angular_velocities",
    "str2et", "scs2e", "sct2e", "sce2s", "et2utc", "frame_id", "frame_name", "frame_info", "frame_trace",
    "pool_values", "pool_has", "body_radii", "body_code", "body_frame", "instrument_keywords", "C_KM_S",
    "light_times", "ck_clock", "sclk_ticks",
]

#: Speed of light, km/s (SPICE's clight()).
C_KM_S = 299792.458


def _ets(ets: ArrayLike) -> NDArray[np.float64]:
    return np.atleast_1d(np.asarray(ets, dtype=float))


def states(target: int | str, ets: ArrayLike, frame: str, abcorr: str, observer: int | str) -> NDArray[np.float64]:
    """States (km, km/s) of ``target`` relative to ``observer``; shape (n, 6)."""
    ets = _ets(ets)
    out = np.empty((ets.size, 6))
    with SPICE_LOCK:
        for i, et in enumerate(ets):
            with spice_errors(f"state of {target} relative to {observer} in {frame} ({abcorr}) at ET {et:.6f}"):
                if isinstance(target, str) or isinstance(observer, str):
                    out[i] = spiceypy.spkezr(str(target), et, frame, abcorr, str(observer))[0]
                else:
                    out[i] = spiceypy.spkez(int(target), et, frame, abcorr, int(observer))[0]
    return out


def light_times(target: int, ets: ArrayLike, frame: str, abcorr: str, observer: int) -> NDArray[np.float64]:
    """One-way light times (s) from ``observer`` to ``target``; shape (n,)."""
    ets = _ets(ets)
    out = np.empty(ets.size)
    with SPICE_LOCK:
        for i, et in enumerate(ets):
            with spice_errors(f"light time {observer}->{target} at ET {et:.6f}"):
                out[i] = spiceypy.spkez(int(target), et, frame, abcorr, int(observer))[1]
    return out


def surface_lt_states(spacecraft: int, body: int, ets: ArrayLike, frame: str,
                      radius_km: float) -> NDArray[np.float64]:
    """Spacecraft state w.r.t. the body with ISIS's "light time to the surface" correction.

    The body's state is taken at ``et - lt + R/c`` where ``lt`` is the
    ``LT+S`` light time from the spacecraft to the body centre and ``R`` the
    mean radius: light from the surface, not the centre (ISIS
    ``SpicePosition`` with ``LT_SURFACE_CORRECT``; see shared kernel README 5.2).
    """
    ets = _ets(ets)
    out = np.empty((ets.size, 6))
    with SPICE_LOCK:
        for i, et in enumerate(ets):
            with spice_errors(f"surface-light-time state of {spacecraft} w.r.t. {body} at ET {et:.6f}"):
                lt = spiceypy.spkez(body, et, frame, "LT+S", spacecraft)[1]
                sc = spiceypy.spkez(spacecraft, et, frame, "NONE", 0)[0]
                bd = spiceypy.spkez(body, et - lt + radius_km / C_KM_S, frame, "NONE", 0)[0]
                out[i] = np.asarray(sc) - np.asarray(bd)
    return out


def rotations(frame_from: str | int, frame_to: str | int, ets: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrices (n, 3, 3) taking ``frame_from`` vectors into ``frame_to``."""
    ets = _ets(ets)
    f_from, f_to = frame_name(frame_from), frame_name(frame_to)
    out = np.empty((ets.size, 3, 3))
    with SPICE_LOCK:
        for i, et in enumerate(ets):
            with spice_errors(f"rotation {f_from} -> {f_to} at ET {et:.6f}"):
                out[i] = spiceypy.pxform(f_from, f_to, et)
    return out


def state_rotations(frame_from: str | int, frame_to: str | int, ets: ArrayLike) -> NDArray[np.float64]:
    """State transformation matrices (n, 6, 6) from ``frame_from`` to ``frame_to``."""
    ets = _ets(ets)
    f_from, f_to = frame_name(frame_from), frame_name(frame_to)
    out = np.empty((ets.size, 6, 6))
    with SPICE_LOCK:
        for i, et in enumerate(ets):
            with spice_errors(f"state rotation {f_from} -> {f_to} at ET {et:.6f}"):
                out[i] = spiceypy.sxform(f_from, f_to, et)
    return out


def angular_velocities(frame_from: str | int, frame_to: str | int, ets: ArrayLike) -> NDArray[np.float64]:
    """Angular velocity (rad/s) of ``frame_to`` relative to ``frame_from``, as ``xf2rav`` gives it."""
    xf = state_rotations(frame_from, frame_to, ets)
    with SPICE_LOCK:
        return np.array([spiceypy.xf2rav(x)[1] for x in xf])


def str2et(utc: str) -> float:
    """UTC (or any SPICE time string) to ephemeris time, s past J2000."""
    with SPICE_LOCK, spice_errors(f"converting time string {utc!r}"):
        return float(spiceypy.str2et(utc))


def et2utc(et: float, fmt: str = "ISOC", prec: int = 6) -> str:
    """Ephemeris time to a UTC string."""
    with SPICE_LOCK, spice_errors(f"converting ET {et} to UTC"):
        return str(spiceypy.et2utc(et, fmt, prec))


def scs2e(spacecraft: int, sclk: str) -> float:
    """Spacecraft clock string (e.g. ``"1/270649237:07208"``) to ET."""
    with SPICE_LOCK, spice_errors(f"converting clock string {sclk!r} of spacecraft {spacecraft}"):
        return float(spiceypy.scs2e(int(spacecraft), str(sclk)))


def sct2e(spacecraft: int, ticks: float) -> float:
    """Encoded spacecraft clock (ticks) to ET."""
    with SPICE_LOCK, spice_errors(f"converting encoded clock {ticks!r} of spacecraft {spacecraft}"):
        return float(spiceypy.sct2e(int(spacecraft), float(ticks)))


def sce2s(spacecraft: int, et: float) -> str:
    """ET to a spacecraft clock string (rounded to the clock's tick)."""
    with SPICE_LOCK, spice_errors(f"converting ET {et} to the clock of spacecraft {spacecraft}"):
        return str(spiceypy.sce2s(int(spacecraft), float(et)))


def frame_id(frame: str | int) -> int:
    """NAIF frame id of a frame name (or id)."""
    if isinstance(frame, (int, np.integer)):
        return int(frame)
    with SPICE_LOCK:
        code = spiceypy.namfrm(frame)
    if code == 0:
        raise KernelCoverageError(f"frame {frame!r} is not defined by the loaded kernels")
    return int(code)


def frame_name(frame: str | int) -> str:
    """Frame name of a NAIF frame id (or name)."""
    if isinstance(frame, str):
        return frame
    with SPICE_LOCK:
        name = spiceypy.frmnam(int(frame))
    if not name:
        raise KernelCoverageError(f"frame id {frame} is not defined by the loaded kernels")
    return str(name)


def frame_info(frame: str | int) -> tuple[int, int, int]:
    """``(center, class, class_id)`` of a frame (SPICE ``frinfo``)."""
    fid = frame_id(frame)
    with SPICE_LOCK, spice_errors(f"frame info of {frame}"):
        center, cls, clsid = spiceypy.frinfo(fid)
    return int(center), int(cls), int(clsid)


def frame_trace(frame: str | int, et: float) -> tuple[list[int], list[int]]:
    """The chain of frames from ``frame`` to J2000 at ``et``, split as ALE splits it.

    Returns ``(constant_frames, time_dependent_frames)``: the leading run of
    fixed-offset (TK, class 4) frames ending at the first time-dependent frame,
    and the path from that frame to J2000 (id 1). Mirrors ALE's
    ``FrameChain.frame_trace`` so the ISD lists the same frames.
    """
    codes = [frame_id(frame)]
    classes: list[int] = []
    with SPICE_LOCK:
        while codes[-1] != 1:
            _, cls, clsid = frame_info(codes[-1])
            classes.append(cls)
            with spice_errors(f"tracing frame {codes[-1]} towards J2000 at ET {et:.6f}"):
                if cls in (1, 2, 6):  # inertial, PCK, switch: ALE links them straight to J2000
                    nxt = 1
                elif cls == 3:
                    nxt = int(spiceypy.ckfrot(clsid, et)[1])
                elif cls == 4:
                    nxt = int(spiceypy.tkfram(clsid)[1])
                elif cls == 5 and _dtpool(f"FRAME_{clsid}_RELATIVE")[0]:
                    # a dynamic frame is listed with the frame it is defined relative to, as ALE does
                    # (Apollo's APOLLO_15_NADIR -> B1950 -> J2000); issue 13
                    rel = spiceypy.gcpool(f"FRAME_{clsid}_RELATIVE", 0, 1)[0] \
                        if _dtpool(f"FRAME_{clsid}_RELATIVE")[2] == "C" \
                        else int(spiceypy.gipool(f"FRAME_{clsid}_RELATIVE", 0, 1)[0])
                    nxt = frame_id(rel)
                else:  # other dynamic frames have no simple parent; ALE treats them likewise
                    nxt = 1
            if nxt in codes or len(codes) > 32:
                raise KernelCoverageError(f"frame chain of {frame} does not reach J2000: {codes}")
            codes.append(nxt)
    classes.append(1)
    constant: list[int] = []
    i = 0
    while i < len(codes) and classes[i] == 4:
        constant.append(codes[i])
        i += 1
    constant.append(codes[i])
    return constant, codes[i:]


def pool_has(name: str) -> bool:
    """Whether the kernel pool defines variable ``name``."""
    with SPICE_LOCK:
        return _dtpool(name)[0]


def pool_values(name: str) -> list[float] | list[str]:
    """All values of kernel-pool variable ``name`` (numbers as floats)."""
    with SPICE_LOCK:
        found, n, typ = _dtpool(name)
        if not found:
            raise KernelCoverageError(f"kernel-pool variable {name} is not defined by the loaded kernels")
        with spice_errors(f"reading kernel-pool variable {name}"):
            if typ == "C":
                return [str(v) for v in spiceypy.gcpool(name, 0, n)]
            return [float(v) for v in spiceypy.gdpool(name, 0, n)]


def _dtpool(name: str) -> tuple[bool, int, str]:
    try:
        n, typ = spiceypy.dtpool(name)
    except Exception:  # spiceypy raises NotFoundError when absent
        return False, 0, ""
    return bool(n), int(n), str(typ)


def body_radii(body: int) -> NDArray[np.float64]:
    """Body radii (km) from ``BODY<id>_RADII``."""
    with SPICE_LOCK, spice_errors(f"radii of body {body}"):
        return np.asarray(spiceypy.bodvcd(int(body), "RADII", 3)[1], dtype=float)


def body_code(name: str) -> int:
    """NAIF id of a body name."""
    with SPICE_LOCK:
        try:
            return int(spiceypy.bods2c(name))
        except Exception as err:
            raise UnknownInstrumentError(f"body or instrument name {name!r} is not known to SPICE") from err


def instrument_keywords(instrument_id: int, extra_prefixes: Sequence[str] = ()) -> dict[str, list]:
    """Every kernel-pool variable of an instrument (``INS<id>_*``), like ALE's ``naif_keywords``."""
    out: dict[str, list] = {}
    prefixes = [f"INS{instrument_id}_", *extra_prefixes]
    with SPICE_LOCK:
        for prefix in prefixes:
            try:
                names = spiceypy.gnpool(prefix + "*", 0, 1000)
            except Exception:
                names = []
            for name in names:
                out[name] = pool_values(name)
    if not out:
        raise UnknownInstrumentError(f"no INS{instrument_id}_* keywords in the loaded kernels "
                                     f"(unknown instrument id {instrument_id} or IK not loaded)")
    return out


def body_frame(body: int) -> tuple[int, str]:
    """The body-fixed frame associated with a body (honours ``OBJECT_<id>_FRAME``), as ``cidfrm``."""
    with SPICE_LOCK:
        try:
            res = spiceypy.cidfrm(int(body))
        except SpiceyError as err:
            raise KernelCoverageError(f"no body-fixed frame is associated with body {body}") from err
    return int(res[0]), str(res[1])


# --- used by lunarmap.orientation.kernels (adjusted orientation kernels) ---

def ck_clock(ck_id: int) -> int:
    """The spacecraft clock id a CK's data for ``ck_id`` are encoded with.

    SPICE's own rule (``ckmeta``): ``CK_<ck_id>_SCLK`` from the kernel pool
    when defined, otherwise ``ck_id / 1000`` truncated.
    """
    with SPICE_LOCK, spice_errors(f"spacecraft clock of CK id {ck_id}"):
        return int(spiceypy.ckmeta(int(ck_id), "SCLK"))


def sclk_ticks(clock: int, ets: ArrayLike) -> NDArray[np.float64]:
    """Continuous encoded spacecraft-clock ticks (``sce2c``) of ephemeris times; shape (n,)."""
    ets = _ets(ets)
    out = np.empty(ets.size)
    with SPICE_LOCK:
        for i, et in enumerate(ets):
            with spice_errors(f"converting ET {et:.6f} to spacecraft clock {clock}"):
                out[i] = spiceypy.sce2c(int(clock), float(et))
    return out
