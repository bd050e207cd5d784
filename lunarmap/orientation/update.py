"""Adjusted exterior orientation written back into image support data.

A bundle adjustment returns, per image, a new body-fixed
:class:`~lunarmap.orientation.exterior.ExteriorOrientation`.
:func:`updated_image_support` turns it back into the ISD's own terms (J2000
kilometres, pointing quaternions J2000 -> ``pointing.time_dependent_frames[0]``)
at the ISD's epochs, through the ISD's own body rotation and constant rotation,
so that ``updated_image_support(isd, eo).exterior_orientation()`` reproduces
``eo`` there and ``write_json`` writes the adjusted ISD.

With ``B`` the J2000 -> body-fixed rotation, ``K`` the constant rotation from
the first time-dependent frame ``F`` to the sensor, ``R`` the EO rotation
(sensor -> body-fixed) and ``Q`` the pointing (J2000 -> ``F``)::

    R = B Q^T K^T        so        Q = K^T R^T B.

Angular velocities (``xf2rav``'s convention, verified against SPICE in the
tests: ``[w]x = dQ^T Q``, the rate of ``F`` relative to J2000 expressed in
J2000) are those of the original ISD plus the rate of the correction
``E = R_new^T R_orig`` (a rotation in the sensor frame)::

    w_new = w_orig + Q_orig^T K^T e,    [e]x = dE^T E,

with ``dE`` from a central difference of the two interpolated EOs. Taking the
original rates as the base keeps the bus's own rotation in frame images, whose
single-sample EO knows no rate at all (their correction is then constant and
``w_new = w_orig``).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

from ..errors import OrientationCoverageError
from .exterior import ExteriorOrientation
from .isd import ImageSupport, RotationTable
from .rotation import matrix_to_quat, quat_to_matrix

__all__ = ["updated_image_support", "resampled_image_support", "TIME_TOLERANCE", "RATE_STEP"]

#: How far (s) an ISD epoch may lie outside the EO's sample range: float rounding of
#: relative times at ET ~ 1e9 s is below 2e-7 s.
TIME_TOLERANCE = 1e-6
#: Half step (s) of the central difference giving the correction's rate.
RATE_STEP = 1e-3


def _vee(m: NDArray[np.float64]) -> NDArray[np.float64]:
    """The vector ``w`` of (the skew part of) matrices ``[w]x``, shape (..., 3)."""
    a = 0.5 * (m - np.swapaxes(m, -1, -2))
    return np.stack([a[..., 2, 1], a[..., 0, 2], a[..., 1, 0]], axis=-1)


def _image_name(isd: ImageSupport) -> str:
    label = str(isd.provenance.get("label", ""))
    return label if label else f"{isd.name_sensor} at ET {isd.center_ephemeris_time:.6f}"


def _check_coverage(isd: ImageSupport, eo: ExteriorOrientation) -> NDArray[np.float64]:
    """ISD epochs relative to ``eo.epoch``, after checking that ``eo`` covers them."""
    if eo.body_frame != isd.body_frame:
        raise OrientationCoverageError(
            f"image {_image_name(isd)}: the exterior orientation is in body frame {eo.body_frame!r}, "
            f"the ISD in {isd.body_frame!r}")
    if isd.pointing.times.shape != isd.times.shape or np.any(isd.pointing.times != isd.times):
        raise OrientationCoverageError(
            f"image {_image_name(isd)}: pointing and position epochs differ; the ISD's body rotation "
            "is known only at the position epochs")
    t = isd.times - eo.epoch
    lo, hi = eo.time_range
    outside = (t < lo - TIME_TOLERANCE) | (t > hi + TIME_TOLERANCE)
    if np.any(outside):
        bad = t[outside]
        raise OrientationCoverageError(
            f"image {_image_name(isd)}: the exterior orientation covers {lo:.6f} .. {hi:.6f} s after ET "
            f"{eo.epoch:.6f}, but {bad.size} ISD epoch(s) lie outside (e.g. {bad[0]:.6f} s); "
            "evaluate the adjustment at the ISD's epochs")
    return t


def resampled_image_support(isd: ImageSupport, times: NDArray[np.float64]) -> ImageSupport:
    """A copy of ``isd`` at other epochs (ephemeris seconds, increasing, within its own).

    Positions by the cubic Hermite of the ISD's positions and velocities, the pointing and the body
    rotation by the cubic Hermite on SO(3) of their samples and angular velocities (as a reader of
    the ISD interpolates them), the body's state transforms from the resampled body rotation.
    """
    from scipy.interpolate import CubicHermiteSpline

    t = np.asarray(times, dtype=float)
    lo, hi = float(isd.times[0]), float(isd.times[-1])
    if t.ndim != 1 or t.size < 2 or np.any(np.diff(t) <= 0) or t[0] < lo - TIME_TOLERANCE or t[-1] > hi + TIME_TOLERANCE:
        raise OrientationCoverageError(f"image {_image_name(isd)}: resampling epochs must increase within the "
                                       f"ISD's {lo:.6f} .. {hi:.6f}")
    t = np.clip(t, lo, hi)
    spline = CubicHermiteSpline(isd.times, isd.positions, isd.velocities, axis=0)
    body = isd.body_rotation.interpolated(t)
    return dataclasses.replace(isd, times=t, positions=spline(t), velocities=spline(t, 1),
                               pointing=isd.pointing.interpolated(t), body_rotation=body,
                               body_state_rotations=body.state_transforms())


def updated_image_support(isd: ImageSupport, eo: ExteriorOrientation, resample: bool | None = None) -> ImageSupport:
    """A copy of ``isd`` whose positions, velocities and pointing are those of ``eo``.

    Parameters
    ----------
    isd : ImageSupport
        The original image support data; it is not modified.
    eo : ExteriorOrientation
        The adjusted exterior orientation (body-fixed, metres), e.g. a bundle
        adjustment's result for this image. It is evaluated with
        ``position_at`` / ``velocity_at`` / ``quaternion_at`` at the ISD's
        epochs, which it must cover (within 1 microsecond).
    resample : bool, optional
        Also take ``eo``'s own samples inside the ISD's span as epochs (the ISD first resampled there,
        :func:`resampled_image_support`), so that an attitude finer than the ISD's epochs (a line-scan
        jitter spline) is in the records. ``None`` (default): when ``eo`` has more samples in that span
        than the ISD has epochs.

    Returns
    -------
    ImageSupport
        New ISD: positions (km) and velocities (km/s) of the sensor relative
        to the body centre in J2000, pointing quaternions J2000 ->
        ``pointing.time_dependent_frames[0]`` with angular velocities (rad/s);
        epochs, frames, constant rotation, body rotation, Sun, interior
        orientation and provenance (plus ``"orientation": "adjusted"``) are
        the original's. Its :meth:`~ImageSupport.exterior_orientation`
        reproduces ``eo`` at the epochs to float rounding (measured
        <= 1e-9 m, 5e-13 m/s, 1.2e-15 rad on the synthetic images).

    Raises
    ------
    OrientationCoverageError
        ``eo`` does not cover the ISD's epochs, uses another body frame, or
        the ISD's pointing epochs differ from its position epochs.
    """
    _check_coverage(isd, eo)
    lo, hi = float(isd.times[0]) - eo.epoch, float(isd.times[-1]) - eo.epoch
    own = eo.times[(eo.times > lo) & (eo.times < hi)]
    if resample is None:
        resample = own.size > isd.times.size
    if resample and own.size:
        extra = own + eo.epoch
        # the ISD's epochs among the EO's samples are dropped where they come closer to one than half the samples'
        # spacing: nearly coincident records make the SPK's Hermite interpolation of the velocities ill-conditioned
        # (measured 4e-5 m/s of velocity misfit from the union of two grids)
        gap = 0.5 * float(np.median(np.diff(extra))) if extra.size > 1 else TIME_TOLERANCE
        j = np.clip(np.searchsorted(extra, isd.times), 1, max(extra.size - 1, 1))
        lo_n, hi_n = extra[np.minimum(j - 1, extra.size - 1)], extra[np.minimum(j, extra.size - 1)]
        keep = np.minimum(np.abs(isd.times - lo_n), np.abs(isd.times - hi_n)) >= gap
        keep[[0, -1]] = True          # the ISD's span stays, without EO samples crowding its ends
        extra = extra[(extra - isd.times[0] >= gap) & (isd.times[-1] - extra >= gap)]
        isd = resampled_image_support(isd, np.union1d(isd.times[keep], extra))
    t = _check_coverage(isd, eo)
    xf = isd.body_state_rotations
    rot, drot = xf[:, :3, :3], xf[:, 3:, :3]
    rot_t = np.swapaxes(rot, 1, 2)
    # inverse of a state transformation [[R, 0], [dR, R]] is [[R^T, 0], [dR^T, R^T]]
    pos_bf, vel_bf = eo.position_at(t) / 1000.0, eo.velocity_at(t) / 1000.0
    positions = np.einsum("nij,nj->ni", rot_t, pos_bf)
    velocities = np.einsum("nij,nj->ni", np.swapaxes(drot, 1, 2), pos_bf) + np.einsum("nij,nj->ni", rot_t, vel_bf)

    k = isd.pointing.constant_rotation
    r_new = eo.rotation_at(t)
    q_new = k.T @ np.swapaxes(r_new, 1, 2) @ rot

    # rate of the sensor-frame correction E = R_new^T R_orig, by central differences
    orig = isd.exterior_orientation(epoch=eo.epoch)

    def correction(tt: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.swapaxes(eo.rotation_at(tt), 1, 2) @ orig.rotation_at(tt)

    e_dot = (correction(t + RATE_STEP) - correction(t - RATE_STEP)) / (2.0 * RATE_STEP)
    e_rate = _vee(np.swapaxes(e_dot, 1, 2) @ correction(t))
    q_orig = quat_to_matrix(isd.pointing.quaternions)
    av = isd.pointing.angular_velocities + np.einsum("nji,nj->ni", q_orig, e_rate @ k)

    pointing = RotationTable(
        time_dependent_frames=list(isd.pointing.time_dependent_frames), times=isd.pointing.times.copy(),
        quaternions=matrix_to_quat(q_new), angular_velocities=av,
        constant_frames=list(isd.pointing.constant_frames), constant_rotation=k.copy())
    return dataclasses.replace(
        isd, times=isd.times.copy(), positions=positions, velocities=velocities, pointing=pointing,
        provenance={**isd.provenance, "orientation": "adjusted"})
