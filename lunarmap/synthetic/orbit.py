"""Analytic lunar orbit: a Keplerian ellipse whose line of apsides drifts slowly.

The drift of the argument of periapsis stands in for the perturbations of a
real low lunar orbit, so that the orbit is neither exactly circular nor
exactly two-body, while position and velocity stay analytic and mutually
consistent (velocity is the exact time derivative of position), which is what
an SPK type 13 (Hermite) segment needs.

Elements are referred to a fixed "Moon-equator inertial" frame: the IAU_MOON
frame frozen at the epoch without its spin (z along the Moon's pole, x along
the ascending node of the Moon's equator on the J2000 equator).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .bodies import MOON_GM, frame_rotation, moon_euler_angles

__all__ = ["KeplerOrbit"]


def _vector_rotation(angle: ArrayLike, axis: int) -> NDArray[np.float64]:
    """Matrices rotating *vectors* by ``angle`` (rad) about ``axis``."""
    return np.swapaxes(frame_rotation(angle, axis), -1, -2)


@dataclass(frozen=True)
class KeplerOrbit:
    """A Keplerian orbit about the Moon with linear apsidal drift.

    Parameters
    ----------
    epoch : float
        Reference epoch, TDB seconds past J2000.
    semi_major_axis : float
        km.
    eccentricity : float
        Dimensionless, ``0 <= e < 0.1``.
    inclination : float
        Inclination to the Moon's equator (of date at ``epoch``), rad.
    node : float
        Right ascension of the ascending node in the Moon-equator inertial
        frame, rad.
    periapsis : float
        Argument of periapsis at ``epoch``, rad.
    periapsis_rate : float
        Drift of the argument of periapsis, rad/s.
    mean_anomaly : float
        Mean anomaly at ``epoch``, rad.
    gm : float
        Gravitational parameter, km^3/s^2.
    """

    epoch: float
    semi_major_axis: float
    eccentricity: float
    inclination: float
    node: float
    periapsis: float
    periapsis_rate: float
    mean_anomaly: float
    gm: float = MOON_GM

    @property
    def mean_motion(self) -> float:
        """rad/s."""
        return float(np.sqrt(self.gm / self.semi_major_axis ** 3))

    @property
    def period(self) -> float:
        """Anomalistic period, s."""
        return 2.0 * np.pi / self.mean_motion

    @property
    def moon_equator_to_j2000(self) -> NDArray[np.float64]:
        """3x3 matrix rotating Moon-equator-inertial vectors into J2000."""
        ra, dec, _ = moon_euler_angles(self.epoch)
        m = frame_rotation(np.pi / 2 - dec, 1) @ frame_rotation(np.pi / 2 + ra, 3)
        return np.ascontiguousarray(m.T)

    def _eccentric_anomaly(self, mean: NDArray[np.float64]) -> NDArray[np.float64]:
        e = self.eccentricity
        big_e = mean + e * np.sin(mean)
        for _ in range(12):  # Newton; e < 0.1 converges to machine precision long before
            big_e = big_e - (big_e - e * np.sin(big_e) - mean) / (1.0 - e * np.cos(big_e))
        return big_e

    def state(self, et: ArrayLike) -> NDArray[np.float64]:
        """State of the spacecraft relative to the Moon in J2000.

        Parameters
        ----------
        et : array_like
            TDB seconds past J2000.

        Returns
        -------
        ndarray, shape ``et.shape + (6,)``
            Position (km) and velocity (km/s).
        """
        et = np.asarray(et, dtype=float)
        dt = et - self.epoch
        a, e, n = self.semi_major_axis, self.eccentricity, self.mean_motion
        big_e = self._eccentric_anomaly(self.mean_anomaly + n * dt)
        ce, se = np.cos(big_e), np.sin(big_e)
        b = a * np.sqrt(1.0 - e * e)
        denom = 1.0 - e * ce
        zero = np.zeros_like(ce)
        r_pf = np.stack([a * (ce - e), b * se, zero], axis=-1)
        v_pf = np.stack([-a * n * se / denom, b * n * ce / denom, zero], axis=-1)
        # the perifocal frame turns at periapsis_rate about the orbit normal
        v_pf = v_pf + self.periapsis_rate * np.stack([-r_pf[..., 1], r_pf[..., 0], zero], axis=-1)
        q = (self.moon_equator_to_j2000 @ _vector_rotation(self.node, 3)
             @ _vector_rotation(self.inclination, 1)
             @ _vector_rotation(self.periapsis + self.periapsis_rate * dt, 3))
        pos = np.einsum("...ij,...j->...i", q, r_pf)
        vel = np.einsum("...ij,...j->...i", q, v_pf)
        return np.concatenate([pos, vel], axis=-1)

    def argument_of_latitude(self, et: ArrayLike) -> NDArray[np.float64]:
        """Argument of latitude (periapsis + true anomaly), rad, unwrapped as time runs."""
        et = np.asarray(et, dtype=float)
        dt = et - self.epoch
        e = self.eccentricity
        mean = self.mean_anomaly + self.mean_motion * dt
        big_e = self._eccentric_anomaly(mean)
        nu = 2.0 * np.arctan2(np.sqrt(1.0 + e) * np.sin(big_e / 2), np.sqrt(1.0 - e) * np.cos(big_e / 2))
        # arctan2 wraps nu into (-pi, pi]; restore the revolutions from E
        nu = nu + 2.0 * np.pi * np.round((big_e - nu) / (2.0 * np.pi))
        return self.periapsis + self.periapsis_rate * dt + nu

    @staticmethod
    def mean_anomaly_for(true_anomaly: float, eccentricity: float) -> float:
        """Mean anomaly (rad) of a true anomaly (rad)."""
        e = eccentricity
        big_e = 2.0 * np.arctan2(np.sqrt(1.0 - e) * np.sin(true_anomaly / 2),
                                 np.sqrt(1.0 + e) * np.cos(true_anomaly / 2))
        return float(big_e - e * np.sin(big_e))
