"""A time-dependent rotation table of image support data (ALE ISD ``instrument_pointing`` / ``body_rotation``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .rotation import quat_to_matrix

__all__ = ["RotationTable", "J2000"]

#: NAIF id of the J2000 frame, the reference of every ISD table.
J2000 = 1


@dataclass
class RotationTable:
    """A time-dependent rotation J2000 -> ``time_dependent_frames[0]`` plus a constant one.

    Parameters
    ----------
    time_dependent_frames : list of int
        NAIF frame ids from the first time-dependent frame down to J2000 (ISIS order); empty when the
        ISD named none (usgscsm does not need them).
    times : ndarray (n,)
        Ephemeris times, s.
    quaternions : ndarray (n, 4)
        SPICE ``(w, x, y, z)`` of ``pxform('J2000', time_dependent_frames[0], et)``.
    angular_velocities : ndarray (n, 3)
        rad/s, as ``xf2rav`` returns them.
    constant_frames : list of int
        From the destination frame (sensor or body-fixed) to ``time_dependent_frames[0]``.
    constant_rotation : ndarray (3, 3)
        ``pxform(time_dependent_frames[0], constant_frames[0])``.
    rates_given : bool
        Whether the angular velocities came from SPICE or the ISD; ``False``: derived from the
        samples (CKs without rates, e.g. Chandrayaan's, for which ALE writes none), and not written.
    """

    time_dependent_frames: list[int]
    times: NDArray[np.float64]
    quaternions: NDArray[np.float64]
    angular_velocities: NDArray[np.float64]
    constant_frames: list[int]
    constant_rotation: NDArray[np.float64]
    rates_given: bool = True

    def matrices(self) -> NDArray[np.float64]:
        """J2000 -> destination-frame rotation matrices, shape (n, 3, 3)."""
        return self.constant_rotation @ quat_to_matrix(self.quaternions)

    def interpolated(self, times: NDArray[np.float64]) -> "RotationTable":
        """The table at other epochs, by the cubic Hermite on SO(3) of its samples and angular velocities.

        For a smooth rotation with exact rates (a body's rotation from a PCK) this is as accurate as
        SPICE itself (measured 8e-13 rad over 16 s from 2 samples: SPICE's own rounding noise), and
        it is what an ISD file, which lists the body rotation at its first and last epochs only,
        can be read back to; sampling the body rotation this way in memory too makes a written
        and re-read ISD the same camera.
        """
        from .rotation_hermite import RotationHermite

        q, w = RotationHermite(self.times, self.quaternions, self.angular_velocities)(np.asarray(times, float))
        return RotationTable(list(self.time_dependent_frames), np.asarray(times, float).copy(), q, w,
                             list(self.constant_frames), self.constant_rotation.copy(), self.rates_given)

    def state_transforms(self) -> NDArray[np.float64]:
        """6x6 state transforms J2000 -> destination frame at the epochs, ``(n, 6, 6)``."""
        from .rotation_hermite import state_transform

        return state_transform(self.matrices(), self.angular_velocities)

    def to_dict(self, every: slice = slice(None), always_constant: bool = True) -> dict[str, Any]:
        t = self.times[every]
        out: dict[str, Any] = {}
        if self.time_dependent_frames:   # an ISD that named none (usgscsm's test ISDs) gets none back
            out["time_dependent_frames"] = list(self.time_dependent_frames)
        out.update({
            "ck_table_start_time": float(t[0]),
            "ck_table_end_time": float(t[-1]),
            "ck_table_original_size": int(t.size),
            "ephemeris_times": t.tolist(),
            "quaternions": self.quaternions[every].tolist(),
        })
        # without rates the key is null, as ALE writes it: usgscsm needs the key and reads null as no rates
        out["angular_velocities"] = self.angular_velocities[every].tolist() if self.rates_given else None
        frames_differ = self.constant_frames[:1] != self.time_dependent_frames[:1]
        if always_constant or frames_differ or not np.array_equal(self.constant_rotation, np.eye(3)):
            out["constant_frames"] = list(self.constant_frames)
            out["constant_rotation"] = self.constant_rotation.flatten().tolist()
        out["reference_frame"] = J2000
        return out
