"""Exterior orientation: the sampled trajectory and attitude of one image.

An :class:`ExteriorOrientation` is plain numpy data, sampled once from SPICE
(or built from a table, a simulation or an adjustment) and interpolated
afterwards. Nothing downstream of this module calls SPICE.

Frames and units
----------------
* Positions are of the sensor (spacecraft) relative to the body centre, in the
  body-fixed frame, in **metres**; velocities in **m/s**.
* ``quaternions`` ``(w, x, y, z)`` rotate vectors from the **sensor frame** into
  the **body-fixed frame**: ``v_body = quat_to_matrix(q) @ v_sensor``.
* Times are given in seconds relative to ``epoch`` (an ephemeris time, TDB
  seconds past J2000). Relative times keep sub-microsecond resolution: an
  absolute ET near 3e8 s has a float64 spacing of 6e-8 s, which is 2e-4 of an
  LRO NAC line.

Interpolation
-------------
Positions use the cubic Hermite spline of positions *and* velocities (exact
for cubic motion; on a lunar orbit sampled every second its error is below a
micrometre). Quaternions are sign-aligned and interpolated component-wise by a
cubic spline, then renormalised; with samples a few milliseconds to a second
apart this is far below a milliarcsecond.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import CubicHermiteSpline, CubicSpline

from ..errors import InvalidInputError
from .rotation import align_quaternion_signs, normalize_quat, quat_to_matrix

__all__ = ["ExteriorOrientation"]


def _as_times(t: ArrayLike) -> NDArray[np.float64]:
    t = np.asarray(t, dtype=float)
    if not np.all(np.isfinite(t)):
        raise InvalidInputError("times must be finite (got NaN or infinity)")
    return t


@dataclass(frozen=True, eq=False)
class ExteriorOrientation:
    """Sampled sensor position and attitude in the body-fixed frame.

    Parameters
    ----------
    epoch : float
        Reference ephemeris time (TDB seconds past J2000).
    times : ndarray, shape (n,)
        Sample times in seconds relative to ``epoch``, strictly increasing.
    positions : ndarray, shape (n, 3)
        Sensor position relative to the body centre, body-fixed, metres.
    velocities : ndarray, shape (n, 3)
        Sensor velocity, body-fixed, m/s.
    quaternions : ndarray, shape (n, 4)
        ``(w, x, y, z)`` rotating sensor-frame vectors into the body-fixed frame.
    sun_times : ndarray, shape (m,)
        Times of the Sun samples, seconds relative to ``epoch``.
    sun_positions : ndarray, shape (m, 3)
        Sun position relative to the body centre, body-fixed, metres.
    body_frame : str
        Name of the body-fixed frame (e.g. ``"MOON_ME"``).
    attrs : dict
        Provenance (instrument, kernels, aberration correction...).
    """

    epoch: float
    times: NDArray[np.float64]
    positions: NDArray[np.float64]
    velocities: NDArray[np.float64]
    quaternions: NDArray[np.float64]
    sun_times: NDArray[np.float64]
    sun_positions: NDArray[np.float64]
    body_frame: str = "MOON_ME"
    attrs: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        times = np.atleast_1d(np.asarray(self.times, dtype=float))
        n = times.size
        pos = np.asarray(self.positions, dtype=float).reshape(n, 3)
        vel = np.asarray(self.velocities, dtype=float).reshape(n, 3)
        quat = align_quaternion_signs(normalize_quat(np.asarray(self.quaternions, dtype=float).reshape(n, 4)))
        sun_t = np.atleast_1d(np.asarray(self.sun_times, dtype=float))
        sun = np.asarray(self.sun_positions, dtype=float).reshape(sun_t.size, 3)
        for name, arr in (("times", times), ("positions", pos), ("velocities", vel),
                          ("quaternions", quat), ("sun_positions", sun)):
            if not np.all(np.isfinite(arr)):
                raise InvalidInputError(f"ExteriorOrientation.{name} holds NaN or infinite values")
        if n == 0:
            raise InvalidInputError("ExteriorOrientation needs at least one sample")
        if n > 1 and np.any(np.diff(times) <= 0):
            raise InvalidInputError("ExteriorOrientation.times must be strictly increasing")
        object.__setattr__(self, "epoch", float(self.epoch))
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "positions", pos)
        object.__setattr__(self, "velocities", vel)
        object.__setattr__(self, "quaternions", quat)
        object.__setattr__(self, "sun_times", sun_t)
        object.__setattr__(self, "sun_positions", sun)
        object.__setattr__(self, "attrs", dict(self.attrs))
        self._build_splines()

    # -- interpolation -------------------------------------------------
    def position_at(self, t: ArrayLike) -> NDArray[np.float64]:
        """Sensor position (metres, body-fixed) at times ``t`` (s after ``epoch``); shape ``t.shape + (3,)``."""
        t = _as_times(t)
        if self.times.size == 1:
            return self.positions[0] + (t[..., None] - self.times[0]) * self.velocities[0]
        return self._pos_spline(t)  # type: ignore[attr-defined]

    def velocity_at(self, t: ArrayLike) -> NDArray[np.float64]:
        """Sensor velocity (m/s, body-fixed) at times ``t``; shape ``t.shape + (3,)``."""
        t = _as_times(t)
        if self.times.size == 1:
            return np.broadcast_to(self.velocities[0], t.shape + (3,)).copy()
        return self._pos_spline(t, 1)  # type: ignore[attr-defined]

    def acceleration_at(self, t: ArrayLike) -> NDArray[np.float64]:
        """Sensor acceleration (m/s², body-fixed) of the position spline at times ``t``; zero for one sample."""
        t = _as_times(t)
        if self.times.size == 1:
            return np.zeros(t.shape + (3,))
        return self._pos_spline(t, 2)  # type: ignore[attr-defined]

    def quaternion_at(self, t: ArrayLike) -> NDArray[np.float64]:
        """Unit quaternions (sensor to body-fixed) at times ``t``; shape ``t.shape + (4,)``."""
        t = _as_times(t)
        if self.times.size == 1:
            return np.broadcast_to(self.quaternions[0], t.shape + (4,)).copy()
        return normalize_quat(self._quat_spline(t))  # type: ignore[attr-defined]

    def rotation_at(self, t: ArrayLike) -> NDArray[np.float64]:
        """Matrices taking sensor-frame vectors to body-fixed ones; shape ``t.shape + (3, 3)``."""
        return quat_to_matrix(self.quaternion_at(t))

    def sun_position_at(self, t: ArrayLike) -> NDArray[np.float64]:
        """Sun position (metres, body-fixed) at times ``t``, linearly interpolated."""
        t = _as_times(t)
        if self.sun_times.size == 1:
            return np.broadcast_to(self.sun_positions[0], t.shape + (3,)).copy()
        return np.stack([np.interp(t, self.sun_times, self.sun_positions[:, k]) for k in range(3)], axis=-1)

    def et_to_t(self, et: ArrayLike) -> NDArray[np.float64]:
        """Convert ephemeris times (s past J2000) to times relative to ``epoch``."""
        return np.asarray(et, dtype=float) - self.epoch

    @property
    def time_range(self) -> tuple[float, float]:
        """First and last sample time, seconds relative to ``epoch``."""
        return float(self.times[0]), float(self.times[-1])

    # -- xarray --------------------------------------------------------
    def to_dataset(self) -> xr.Dataset:
        """The samples as an ``xarray.Dataset`` (units in variable attributes)."""
        ds = xr.Dataset(
            {
                "position": (("time", "xyz"), self.positions, {"units": "m", "frame": self.body_frame}),
                "velocity": (("time", "xyz"), self.velocities, {"units": "m s-1", "frame": self.body_frame}),
                "quaternion": (("time", "wxyz"), self.quaternions,
                               {"convention": "SPICE (w,x,y,z); rotates sensor-frame vectors into body_frame"}),
                "sun_position": (("sun_time", "xyz"), self.sun_positions, {"units": "m", "frame": self.body_frame}),
            },
            coords={
                "time": ("time", self.times, {"units": "s", "description": "seconds after epoch"}),
                "sun_time": ("sun_time", self.sun_times, {"units": "s", "description": "seconds after epoch"}),
                "xyz": ["x", "y", "z"],
                "wxyz": ["w", "x", "y", "z"],
            },
            attrs={"epoch_et": self.epoch, "body_frame": self.body_frame,
                   **{k: v for k, v in self.attrs.items() if isinstance(v, (str, int, float))}},
        )
        return ds

    @classmethod
    def from_dataset(cls, ds: xr.Dataset) -> "ExteriorOrientation":
        """Inverse of :meth:`to_dataset`."""
        attrs = {k: v for k, v in ds.attrs.items() if k not in ("epoch_et", "body_frame")}
        return cls(epoch=float(ds.attrs["epoch_et"]), times=ds["time"].values,
                   positions=ds["position"].values, velocities=ds["velocity"].values,
                   quaternions=ds["quaternion"].values, sun_times=ds["sun_time"].values,
                   sun_positions=ds["sun_position"].values, body_frame=str(ds.attrs["body_frame"]),
                   attrs=attrs)

    def __reduce__(self):  # splines are rebuilt on unpickling rather than shipped
        return (_rebuild, (self.epoch, self.times, self.positions, self.velocities, self.quaternions,
                           self.sun_times, self.sun_positions, self.body_frame, self.attrs))

    def _build_splines(self) -> None:
        if self.times.size > 1:
            object.__setattr__(self, "_pos_spline", CubicHermiteSpline(self.times, self.positions,
                                                                       self.velocities, axis=0))
            object.__setattr__(self, "_quat_spline", CubicSpline(self.times, self.quaternions, axis=0))


def _rebuild(epoch: float, times: NDArray[np.float64], positions: NDArray[np.float64],
             velocities: NDArray[np.float64], quaternions: NDArray[np.float64], sun_times: NDArray[np.float64],
             sun_positions: NDArray[np.float64], body_frame: str, attrs: dict[str, Any]) -> ExteriorOrientation:
    # The state was validated and normalised when first built; restoring it bit for bit (no
    # re-normalisation) keeps results of unpickled copies on dask workers identical to the original's.
    eo = object.__new__(ExteriorOrientation)
    for name, value in (("epoch", epoch), ("times", times), ("positions", positions), ("velocities", velocities),
                        ("quaternions", quaternions), ("sun_times", sun_times), ("sun_positions", sun_positions),
                        ("body_frame", body_frame), ("attrs", dict(attrs))):
        object.__setattr__(eo, name, value)
    eo._build_splines()
    return eo
