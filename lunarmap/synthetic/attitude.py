"""Attitude of the synthetic spacecraft bus: nadir pointing, a slow wobble, a yaw flip.

Nominal attitude: bus +z toward the Moon's centre, +y along the negative
orbit normal of the motion *relative to the rotating Moon* (velocity minus the
Moon's spin times position), +x completing the triad - roughly along the
ground-track velocity. A sum of three slow sinusoidal rotations (about 0.01
degree, periods of 25 to 40 minutes) is applied on top so that the attitude
is not trivially a function of the orbit. Inside the yaw-flip interval the
bus is additionally rotated by 180 degrees about +z (so +x points backwards
and a pushbroom's scan direction is reversed).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..orientation.rotation import align_quaternion_signs, matrix_to_quat
from .bodies import frame_rotation, j2000_to_iau_moon, moon_spin_rate
from .orbit import KeplerOrbit

__all__ = ["NadirAttitude"]

_FLIP = np.diag([-1.0, -1.0, 1.0])  # frame rotation by 180 degrees about +z
#: Step of the central differences giving the angular velocity, s: truncation
#: (~h^2 * |omega|^3 / 6 ~ 1e-13 rad/s) and rounding (~1e-16 / h) both stay tiny.
_DIFF_STEP = 0.05


def _unit(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@dataclass(frozen=True)
class NadirAttitude:
    """Bus attitude model.

    Parameters
    ----------
    orbit : KeplerOrbit
        The spacecraft trajectory.
    wobble_amplitude : tuple of 3 float
        Amplitudes of the sinusoidal rotations about bus x, y, z, rad.
    wobble_period : tuple of 3 float
        Their periods, s.
    wobble_phase : tuple of 3 float
        Their phases, rad.
    flip_start, flip_end : float
        The yaw-flipped interval ``[flip_start, flip_end)``, TDB seconds past J2000.
    """

    orbit: KeplerOrbit
    wobble_amplitude: tuple[float, float, float]
    wobble_period: tuple[float, float, float]
    wobble_phase: tuple[float, float, float]
    flip_start: float
    flip_end: float

    def nominal(self, et: ArrayLike) -> NDArray[np.float64]:
        """Unperturbed nadir-pointing matrices J2000 -> bus, shape ``et.shape + (3, 3)``."""
        et = np.asarray(et, dtype=float)
        st = self.orbit.state(et)
        r, v = st[..., :3], st[..., 3:]
        pole = j2000_to_iau_moon(et)[..., 2, :]  # Moon's spin axis in J2000
        v_ground = v - moon_spin_rate() * np.cross(pole, r)
        z = _unit(-r)
        y = _unit(np.cross(z, v_ground))
        x = np.cross(y, z)
        return np.stack([x, y, z], axis=-2)

    def wobble(self, et: ArrayLike) -> NDArray[np.float64]:
        """Small rotation matrices bus_nominal -> bus, shape ``et.shape + (3, 3)``."""
        et = np.asarray(et, dtype=float)
        dt = et - self.orbit.epoch
        ang = [a * np.sin(2.0 * np.pi * dt / p + ph) for a, p, ph in
               zip(self.wobble_amplitude, self.wobble_period, self.wobble_phase)]
        return frame_rotation(ang[2], 3) @ frame_rotation(ang[1], 2) @ frame_rotation(ang[0], 1)

    def flipped(self, et: ArrayLike) -> NDArray[np.bool_]:
        """True inside the yaw-flipped interval."""
        et = np.asarray(et, dtype=float)
        return (et >= self.flip_start) & (et < self.flip_end)

    def matrix(self, et: ArrayLike, flipped: ArrayLike | None = None) -> NDArray[np.float64]:
        """Rotation matrices J2000 -> bus (``pxform('J2000', 'SIM_SC_BUS', et)``).

        Parameters
        ----------
        et : array_like
            TDB seconds past J2000.
        flipped : array_like of bool, optional
            Override of the flip state (used to evaluate the two sides of a
            flip boundary); by default :meth:`flipped`.

        Returns
        -------
        ndarray, shape ``et.shape + (3, 3)``
        """
        et = np.asarray(et, dtype=float)
        m = self.wobble(et) @ self.nominal(et)
        f = self.flipped(et) if flipped is None else np.broadcast_to(np.asarray(flipped, bool), et.shape)
        return np.where(f[..., None, None], _FLIP @ m, m)

    def angular_velocity(self, et: ArrayLike) -> NDArray[np.float64]:
        """Angular velocity of the bus relative to J2000, in J2000 components, rad/s.

        The yaw flip is a constant rotation, so it does not change the
        angular velocity; it is computed from the unflipped attitude.
        """
        et = np.asarray(et, dtype=float)
        c = self.matrix(et, flipped=np.zeros(et.shape, bool))
        dc = (self.matrix(et + _DIFF_STEP, flipped=np.zeros(et.shape, bool))
              - self.matrix(et - _DIFF_STEP, flipped=np.zeros(et.shape, bool))) / (2.0 * _DIFF_STEP)
        # rows of C are the bus axes in J2000; d(axis)/dt = w x axis  =>  [w]x = -C^T dC/dt
        s = -np.swapaxes(c, -1, -2) @ dc
        return 0.5 * np.stack([s[..., 2, 1] - s[..., 1, 2], s[..., 0, 2] - s[..., 2, 0],
                               s[..., 1, 0] - s[..., 0, 1]], axis=-1)

    def quaternions(self, et: ArrayLike) -> NDArray[np.float64]:
        """SPICE quaternions of :meth:`matrix`, sign-aligned along the time axis, shape (n, 4)."""
        return align_quaternion_signs(matrix_to_quat(self.matrix(np.atleast_1d(et))))
