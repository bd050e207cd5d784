"""Interpolation of sampled rotations that carry their angular velocities (SPICE convention).

ALE's ISDs (and SPICE's ``sxform``/``xf2rav``) give, at each epoch ``t_k``, the
rotation ``R_k`` taking vectors of a *from* frame (J2000) into a *to* frame,
as a quaternion ``(w, x, y, z)``, and the angular velocity ``w_k`` (rad/s)
returned by ``xf2rav``. Its sign convention, checked against SPICE in the
tests, is

    dR/dt = -R [w]x          (w expressed in the *from* frame),

so that a constant ``w`` gives ``R(t) = R_k exp(-(t - t_k) [w]x)``.

:class:`RotationHermite` writes the rotation inside each sample interval as
``R(t) = R_k exp(-[phi(t)]x)`` and takes the rotation vector ``phi`` as the cubic
Hermite polynomial with ``phi(t_k) = 0``, ``phi(t_k+1) = -log(R_k^T R_k+1)`` and
end derivatives that reproduce ``w_k`` and ``w_k+1`` exactly (through the SO(3)
right Jacobian, so the ends need not be small rotations about a common axis).
It is exact for a constant angular velocity and fourth-order accurate
otherwise; outside the sampled span (and for a single sample) the rotation
is propagated with the angular velocity of the nearest sample held constant.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InvalidInputError
from .rotation import align_quaternion_signs, normalize_quat, quat_to_matrix

__all__ = ["RotationHermite", "quat_multiply", "quat_exp", "quat_log", "state_transform", "rates_from_samples"]

Array = NDArray[np.float64]

# Below this rotation angle (rad) the Jacobian coefficients use their Taylor
# series: the closed forms lose all digits to cancellation near zero.
_SMALL_ANGLE = 1e-4


def quat_multiply(p: ArrayLike, q: ArrayLike) -> Array:
    """Hamilton product ``p q`` of ``(w, x, y, z)`` quaternions (broadcast).

    With SPICE's ``q2m``, ``quat_to_matrix(p q) = quat_to_matrix(p) @ quat_to_matrix(q)``.
    """
    p, q = np.broadcast_arrays(np.asarray(p, dtype=float), np.asarray(q, dtype=float))
    pw, pv = p[..., :1], p[..., 1:]
    qw, qv = q[..., :1], q[..., 1:]
    w = pw * qw - np.sum(pv * qv, axis=-1, keepdims=True)
    v = pw * qv + qw * pv + np.cross(pv, qv)
    return np.concatenate([w, v], axis=-1)


def _skew(v: Array) -> Array:
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def state_transform(matrices: ArrayLike, angular_velocities: ArrayLike) -> Array:
    """SPICE 6x6 state transformations from rotations and ``xf2rav`` angular velocities.

    The equivalent of ``spiceypy.rav2xf``, vectorised: ``[[R, 0], [dR/dt, R]]``
    with ``dR/dt = -R [w]x``.

    Parameters
    ----------
    matrices : array_like, shape (..., 3, 3)
        Rotations from -> to.
    angular_velocities : array_like, shape (..., 3)
        rad/s, in the *from* frame (as ``xf2rav`` returns them).

    Returns
    -------
    ndarray, shape (..., 6, 6)
    """
    m = np.asarray(matrices, dtype=float)
    w = np.asarray(angular_velocities, dtype=float)
    xf = np.zeros(m.shape[:-2] + (6, 6))
    xf[..., :3, :3] = m
    xf[..., 3:, 3:] = m
    xf[..., 3:, :3] = -m @ _skew(w)
    return xf


def quat_exp(v: Array) -> Array:
    """Unit quaternion of the rotation vector ``v`` (rad): ``quat_to_matrix = exp([v]x)``."""
    theta = np.linalg.norm(v, axis=-1, keepdims=True)
    half = 0.5 * theta
    # sin(theta/2)/theta, with its series near 0
    small = theta < _SMALL_ANGLE
    ratio = np.where(small, 0.5 - theta * theta / 48.0, np.sin(half) / np.where(small, 1.0, theta))
    return np.concatenate([np.cos(half), ratio * v], axis=-1)


def quat_log(q: Array) -> Array:
    """Rotation vector (rad) of unit quaternions with ``w >= 0`` (inverse of :func:`quat_exp`)."""
    w = np.clip(q[..., :1], -1.0, 1.0)
    s = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    theta = 2.0 * np.arctan2(s, w)
    small = s < 0.5 * _SMALL_ANGLE
    ratio = np.where(small, 2.0 / np.where(w > 0.0, w, 1.0), theta / np.where(small, 1.0, s))
    return ratio * q[..., 1:]


def _jacobian_coefficients(theta: Array) -> tuple[Array, Array]:
    """``(a, b)`` of the SO(3) right Jacobian ``J_r(v) = I - a [v]x + b [v]x^2``."""
    small = theta < _SMALL_ANGLE
    t = np.where(small, 1.0, theta)
    t2 = theta * theta
    a = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(t)) / (t * t))
    b = np.where(small, 1.0 / 6.0 - t2 / 120.0, (t - np.sin(t)) / (t * t * t))
    return a, b


def _right_jacobian_apply(v: Array, x: Array) -> Array:
    """``J_r(v) @ x`` for rotation vectors ``v`` and vectors ``x`` (both (..., 3))."""
    a, b = _jacobian_coefficients(np.linalg.norm(v, axis=-1, keepdims=True))
    vx = np.cross(v, x)
    return x - a * vx + b * np.cross(v, vx)


def _right_jacobian_inverse_apply(v: Array, x: Array) -> Array:
    """``J_r(v)^-1 @ x``: ``x + [v]x x / 2 + c [v]x^2 x``."""
    theta = np.linalg.norm(v, axis=-1, keepdims=True)
    small = theta < _SMALL_ANGLE
    t = np.where(small, 1.0, theta)
    c = np.where(small, 1.0 / 12.0 + theta * theta / 720.0,
                 1.0 / (t * t) - (1.0 + np.cos(t)) / (2.0 * t * np.sin(t)))
    vx = np.cross(v, x)
    return x + 0.5 * vx + c * np.cross(v, vx)


def rates_from_samples(times: Array, q: Array) -> Array:
    """Angular velocities (``xf2rav`` convention) of sampled rotations that came without them.

    Each interval's constant rate (its geodesic), averaged over the two intervals
    meeting at a sample; zero for a single sample.
    """
    if times.size == 1:
        return np.zeros((1, 3))
    qn = q / np.linalg.norm(q, axis=1, keepdims=True)
    rel = quat_multiply(qn[:-1] * np.array([1.0, -1.0, -1.0, -1.0]), qn[1:])
    rel *= np.where(rel[:, :1] < 0.0, -1.0, 1.0)
    rate = -quat_log(rel) / np.diff(times)[:, None]
    out = np.empty((times.size, 3))
    out[0], out[-1] = rate[0], rate[-1]
    out[1:-1] = 0.5 * (rate[:-1] + rate[1:])
    return out



class RotationHermite:
    """Rotations ``from -> to`` sampled with angular velocities, interpolated on SO(3).

    Parameters
    ----------
    times : array_like, shape (n,)
        Strictly increasing sample epochs, s (any origin).
    quaternions : array_like, shape (n, 4)
        SPICE ``(w, x, y, z)`` of the rotations ``from -> to`` (``q`` and ``-q`` alike).
    angular_velocities : array_like, shape (n, 3)
        rad/s, ``xf2rav`` convention (see the module docstring).
    rates : {"linear", "derivative"}
        Angular velocities returned between samples: ``"linear"`` interpolates the
        sampled ones (best when, as from SPICE's PCKs, they are exact derivatives
        while the sampled rotations carry rounding noise: the interpolant's own
        derivative turns a noise ``e`` (rad) into a rate error ``~1.5 e / h`` over
        an interval of ``h`` seconds, 6e-13 rad/s for ALE's LRO NAC body rotation,
        0.4 s apart); ``"derivative"`` returns the interpolant's exact derivative.
    """

    def __init__(self, times: ArrayLike, quaternions: ArrayLike, angular_velocities: ArrayLike,
                 rates: str = "linear") -> None:
        if rates not in ("linear", "derivative"):
            raise InvalidInputError(f"rates must be 'linear' or 'derivative', got {rates!r}")
        self.rates = rates
        self.times = np.atleast_1d(np.asarray(times, dtype=float))
        n = self.times.size
        q = np.asarray(quaternions, dtype=float)
        w = np.asarray(angular_velocities, dtype=float)
        if n == 0 or q.shape != (n, 4) or w.shape != (n, 3):
            raise InvalidInputError(f"rotation samples need shapes (n,), (n, 4), (n, 3) with n >= 1; got "
                                    f"{self.times.shape}, {q.shape}, {w.shape}")
        if not (np.all(np.isfinite(self.times)) and np.all(np.isfinite(q)) and np.all(np.isfinite(w))):
            raise InvalidInputError("rotation samples hold NaN or infinite values")
        if n > 1 and np.any(np.diff(self.times) <= 0.0):
            raise InvalidInputError("rotation sample times must be strictly increasing")
        self._given = q.copy()
        self.quaternions = align_quaternion_signs(normalize_quat(q))
        self.angular_velocities = w
        if n > 1:
            h = np.diff(self.times)[:, None]
            rel = quat_multiply(self._conj(self.quaternions[:-1]), self.quaternions[1:])  # R_k^T R_k+1
            # R_k+1 = R_k exp(-[phi1]x): phi1 = -log(rel); sign-aligned neighbours keep w >= 0
            self._phi1 = -quat_log(rel * np.where(rel[:, :1] < 0.0, -1.0, 1.0))
            self._d0 = h * self.angular_velocities[:-1]
            # phi'(t_k+1) solves w_k+1 = J_r(-phi1) phi'
            self._d1 = h * _right_jacobian_inverse_apply(-self._phi1, self.angular_velocities[1:])

    @staticmethod
    def _conj(q: Array) -> Array:
        return q * np.array([1.0, -1.0, -1.0, -1.0])

    def __call__(self, t: ArrayLike) -> tuple[Array, Array]:
        """Quaternions and angular velocities at epochs ``t``.

        Parameters
        ----------
        t : array_like, shape (m,)
            Epochs, s, on the origin of ``times``.

        Returns
        -------
        quaternions : ndarray (m, 4)
            Unit ``(w, x, y, z)``; at a sample epoch the sample exactly as given,
            elsewhere in the hemisphere of the sign-aligned samples.
        angular_velocities : ndarray (m, 3)
            rad/s, ``xf2rav`` convention (see ``rates``).
        """
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if not np.all(np.isfinite(t)):
            raise InvalidInputError("rotation interpolation times must be finite")
        n = self.times.size
        k = np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, max(n - 2, 0))
        q_out = np.empty((t.size, 4))
        w_out = np.empty((t.size, 3))
        inside = (t >= self.times[0]) & (t <= self.times[-1]) if n > 1 else np.zeros(t.shape, bool)
        if np.any(inside):
            ki = k[inside]
            h = (self.times[ki + 1] - self.times[ki])[:, None]
            s = ((t[inside] - self.times[ki]) / h[:, 0])[:, None]
            s2, s3 = s * s, s * s * s
            phi = ((s3 - 2.0 * s2 + s) * self._d0[ki] + (-2.0 * s3 + 3.0 * s2) * self._phi1[ki]
                   + (s3 - s2) * self._d1[ki])
            dphi = ((3.0 * s2 - 4.0 * s + 1.0) * self._d0[ki] + (-6.0 * s2 + 6.0 * s) * self._phi1[ki]
                    + (3.0 * s2 - 2.0 * s) * self._d1[ki]) / h
            q_out[inside] = quat_multiply(self.quaternions[ki], quat_exp(-phi))
            if self.rates == "linear":
                w_out[inside] = (1.0 - s) * self.angular_velocities[ki] + s * self.angular_velocities[ki + 1]
            else:
                w_out[inside] = _right_jacobian_apply(-phi, dphi)
        outside = ~inside
        if np.any(outside):
            # constant angular velocity from the nearest sample
            j = np.where(t[outside] < self.times[0], 0, n - 1)
            dt = (t[outside] - self.times[j])[:, None]
            w_j = self.angular_velocities[j]
            q_out[outside] = quat_multiply(self.quaternions[j], quat_exp(-dt * w_j))
            w_out[outside] = w_j
        q_out = normalize_quat(q_out)
        # the samples themselves, bit for bit (so that a table read and written again is unchanged)
        hit = np.searchsorted(self.times, t).clip(0, n - 1)
        exact = self.times[hit] == t
        q_out[exact] = self._given[hit[exact]]
        w_out[exact] = self.angular_velocities[hit[exact]]
        return q_out, w_out

    def matrices(self, t: ArrayLike) -> Array:
        """Rotation matrices ``from -> to`` at epochs ``t``, shape (m, 3, 3)."""
        return quat_to_matrix(self(t)[0])

    def state_transforms(self, t: ArrayLike) -> Array:
        """6x6 state transformations ``from -> to`` at epochs ``t`` (as ``sxform``), shape (m, 6, 6)."""
        q, w = self(t)
        return state_transform(quat_to_matrix(q), w)
