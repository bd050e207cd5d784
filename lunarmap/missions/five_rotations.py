"""The Ranger paper's orientation of a photograph from JPL flight parameters: five rotations (``seeds/000``).

The paper ("Coordinate transformation") turns the measured image vector into a vector parallel to
the selenocentric frame by the product ``M = R5 R4 R3 R2 R1``:

1. ``R1`` rotates the photo coordinates about the photo normal by ``AZN`` so that ``y'`` points to
   lunar north;
2. ``R2`` translates the origin to the photographic nadir point, which lies ``f tan t`` from the
   principal point along the principal line towards its nadir end, in the direction ``omega =
   270 deg - AZS/C - AZN`` (the vectors are homogeneous, so the translation is a shear);
3. ``R3`` transforms the nadir-centred coordinates into a plane perpendicular to the local vertical
   (third row ``sin phi, sin theta, sec t`` with ``sin theta = sin omega sin t``, ``sin phi =
   cos omega sin t``); ``t`` is the tilt of the camera axis from the vertical, from the triangle
   lunar centre - camera - principal point: ``cos t = (R^2 + Range^2 - radius^2) / (2 R Range)``;
4. ``R4`` rotates about x by ``psi = 90 deg - LATs`` and
5. ``R5`` about z by ``beta = 90 deg + LONs`` (local east/north/up at the sub-spacecraft point to the
   selenocentric frame).

Reconstructed here (the OCR of the paper's matrices is garbled; the structure of each matrix is the
printed one):

* **exact step 3.** The paper prints the upper-left block of ``R3`` as ``diag(cos phi, cos theta)``.
  ``R3 R2`` is a rotation only with the exact block ``I - (1 - cos t) w w^T`` (``w = (cos omega,
  -sin omega)``, i.e. ``1 - sin^2 phi / (1 + cos t)`` on the diagonal and ``sin phi sin theta /
  (1 + cos t)`` off it), which lunarmap uses; the printed block is its first-order form (the
  difference is ``sin^2 t sin 2 omega / 4``, 1.9 mrad at t = 5 deg, omega = 45 deg:
  :func:`paper_step3`);
* **signs.** Photo coordinates are those of a positive viewed normally: ``x`` right, ``y`` up, ``z``
  towards the lens (out of the print), so the look vector of photo point ``(x, y)`` is ``(x, y, -f)``
  (the paper writes ``(x, y, f)``, which flips the signs of the third columns of ``R2`` and ``R3``).
  ``AZN`` is clockwise from ``+y`` to north and ``AZS/C`` counterclockwise from ``+y`` to the nadir
  end of the principal line, both seen on that positive. ``LATs`` is planetocentric north latitude
  and ``LONs`` east longitude in lunarmap's body-fixed frame;
* **what "north in the photo" is.** For the chain to be exact, the north direction that ``AZN``
  measures is the one that the rabatment of the photograph about its axis of tilt (the horizontal
  line of the photo plane, perpendicular to the principal line) turns into lunar north at the
  sub-spacecraft point; for a vertical photo it is the ordinary north direction, for a tilted one it
  differs from the projection of north by terms of order ``t^2``.

With these, :func:`orientation_angles` inverts the chain exactly (tilt, ``AZS/C`` from the nadir's
image, ``AZN`` from the rabatment), so any orientation survives the round trip to rounding.
lunarmap's sensor frame (NAIF convention, boresight ``+z``, look vector ``(x_s, y_s, f)``) is the
photo frame turned by 180 degrees about x: ``x_s = x``, ``y_s = -y`` (image lines run down).
Angles are degrees at the interface, lengths metres.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import GeometryError, InvalidInputError

__all__ = ["PHOTO_TO_SENSOR", "tilt_from_ranges", "omega_angle", "five_rotations", "photo_to_body",
           "sensor_to_body", "paper_step3", "orientation_angles"]

Array = NDArray[np.float64]

#: Photo frame (x right, y up, z towards the lens) <-> lunarmap sensor frame (boresight +z, lines down).
PHOTO_TO_SENSOR = np.diag([1.0, -1.0, -1.0])


def tilt_from_ranges(r: ArrayLike, range_: ArrayLike, radius: float) -> Array:
    """Tilt of the camera axis from the local vertical, degrees (law of cosines, the paper's ``t``).

    Parameters
    ----------
    r : array_like
        Distance lunar centre - camera (``R``), metres.
    range_ : array_like
        Distance camera - lunar principal point along the camera axis (``Range``), metres.
    radius : float
        Radius of the lunar principal point, metres.

    Raises
    ------
    GeometryError
        No such triangle: ``Range`` shorter than the altitude ``R - radius`` or longer than the
        tangent ``sqrt(R^2 - radius^2)`` (the axis would meet the far side), or ``R <= radius``.
    """
    r, rg = np.broadcast_arrays(np.asarray(r, float), np.asarray(range_, float))
    if np.any(r <= radius):
        raise GeometryError(f"camera at or below the {radius:.1f} m sphere (R <= radius)")
    bad = ~((rg >= r - radius - 1e-9 * r) & (rg <= np.sqrt(r * r - radius * radius) * (1 + 1e-12)))
    if np.any(bad):
        i = int(np.argmax(bad.ravel()))
        raise GeometryError(f"Range {rg.ravel()[i]:.1f} m is impossible for R {r.ravel()[i]:.1f} m on a "
                            f"{radius:.1f} m sphere: it must lie between the altitude {r.ravel()[i] - radius:.1f} m "
                            f"and the horizon distance {np.sqrt(r.ravel()[i] ** 2 - radius ** 2):.1f} m")
    # The angle opposite the side ``radius`` by Kahan's formula for needle-like triangles: the plain law
    # of cosines, arccos of a number near 1, loses half the digits of a small tilt.
    a, b, c = r, rg, radius              # a >= b: Range is shorter than the horizon distance < R
    mu = np.where(b >= c, c - (a - b), b - (a - c))   # Range - altitude, formed without cancellation
    num = np.maximum(((a - b) + c) * mu, 0.0)
    den = (a + (b + c)) * ((a - c) + b)
    return np.degrees(2.0 * np.arctan(np.sqrt(num / den)))


def omega_angle(azn: ArrayLike, azsc: ArrayLike) -> Array:
    """The paper's ``omega = 270 deg - AZS/C - AZN``, degrees."""
    return 270.0 - np.asarray(azsc, float) - np.asarray(azn, float)


def _rz(a: Array) -> Array:
    c, s = np.cos(a), np.sin(a)
    m = np.zeros(a.shape + (3, 3))
    m[..., 0, 0], m[..., 0, 1], m[..., 1, 0], m[..., 1, 1], m[..., 2, 2] = c, -s, s, c, 1.0
    return m


def _rx(a: Array) -> Array:
    c, s = np.cos(a), np.sin(a)
    m = np.zeros(a.shape + (3, 3))
    m[..., 0, 0], m[..., 1, 1], m[..., 1, 2], m[..., 2, 1], m[..., 2, 2] = 1.0, c, -s, s, c
    return m


def five_rotations(azn: ArrayLike, azsc: ArrayLike, tilt: ArrayLike, lat_s: ArrayLike,
                   lon_s: ArrayLike) -> tuple[Array, Array, Array, Array, Array]:
    """The matrices ``R1 ... R5`` of the paper's chain (module docstring), shapes ``(..., 3, 3)``.

    Parameters
    ----------
    azn, azsc : array_like
        ``AZN`` and ``AZS/C``, degrees.
    tilt : array_like
        ``t``, degrees (:func:`tilt_from_ranges`).
    lat_s, lon_s : array_like
        ``LATs`` (north) and ``LONs`` (east), degrees.
    """
    azn, azsc, t, lat, lon = np.broadcast_arrays(*(np.asarray(v, float) for v in (azn, azsc, tilt, lat_s, lon_s)))
    w = np.radians(omega_angle(azn, azsc))
    t = np.radians(t)
    if np.any(np.abs(t) >= np.pi / 2):
        raise GeometryError("the camera axis is tilted 90 degrees or more from the vertical")
    cw, sw, ct, st = np.cos(w), np.sin(w), np.cos(t), np.sin(t)
    r1 = _rz(np.radians(azn))
    r2 = np.zeros(w.shape + (3, 3))
    r2[..., 0, 0] = r2[..., 1, 1] = r2[..., 2, 2] = 1.0
    r2[..., 0, 2] = np.tan(t) * cw     # the nadir point lies at f tan t (cos omega, -sin omega); z = -f
    r2[..., 1, 2] = -np.tan(t) * sw
    r3 = np.zeros(w.shape + (3, 3))
    r3[..., 0, 0] = 1.0 - (1.0 - ct) * cw * cw
    r3[..., 0, 1] = r3[..., 1, 0] = (1.0 - ct) * sw * cw
    r3[..., 1, 1] = 1.0 - (1.0 - ct) * sw * sw
    r3[..., 2, 0] = -st * cw           # -sin phi
    r3[..., 2, 1] = st * sw            # sin theta
    r3[..., 2, 2] = 1.0 / ct           # sec t
    r4 = _rx(np.radians(90.0 - lat))
    r5 = _rz(np.radians(90.0 + lon))
    return r1, r2, r3, r4, r5


def paper_step3(tilt: ArrayLike, omega: ArrayLike) -> Array:
    """``R3`` as the paper prints it (upper-left block ``diag(cos phi, cos theta)``), in lunarmap's signs.

    For comparison only: its product with ``R2`` is a rotation only when ``sin 2 omega = 0``.
    """
    t, w = np.broadcast_arrays(np.radians(np.asarray(tilt, float)), np.radians(np.asarray(omega, float)))
    sphi, stheta = np.cos(w) * np.sin(t), np.sin(w) * np.sin(t)
    m = np.zeros(t.shape + (3, 3))
    m[..., 0, 0], m[..., 1, 1] = np.sqrt(1 - sphi ** 2), np.sqrt(1 - stheta ** 2)
    m[..., 2, 0], m[..., 2, 1], m[..., 2, 2] = -sphi, stheta, 1.0 / np.cos(t)
    return m


def photo_to_body(azn: ArrayLike, azsc: ArrayLike, tilt: ArrayLike, lat_s: ArrayLike, lon_s: ArrayLike) -> Array:
    """``M = R5 R4 R3 R2 R1``: photo-frame vectors to body-fixed (selenocentric) vectors, ``(..., 3, 3)``."""
    r1, r2, r3, r4, r5 = five_rotations(azn, azsc, tilt, lat_s, lon_s)
    return r5 @ r4 @ r3 @ r2 @ r1


def sensor_to_body(azn: ArrayLike, azsc: ArrayLike, tilt: ArrayLike, lat_s: ArrayLike, lon_s: ArrayLike) -> Array:
    """The rotation lunarmap's exterior orientation holds: sensor frame (boresight +z) to body-fixed."""
    return photo_to_body(azn, azsc, tilt, lat_s, lon_s) @ PHOTO_TO_SENSOR


def _unit(v: Array) -> Array:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def orientation_angles(position: ArrayLike, sensor_rotation: ArrayLike, radius: float) -> dict[str, Array]:
    """Flight parameters of known orientations: the exact inverse of :func:`sensor_to_body`.

    Parameters
    ----------
    position : array_like, shape (n, 3)
        Camera positions, body-fixed, metres.
    sensor_rotation : array_like, shape (n, 3, 3)
        Sensor frame (boresight +z) to body-fixed rotations.
    radius : float
        Radius of the sphere the principal point lies on, metres.

    Returns
    -------
    dict of ndarray (n,)
        ``LATs``, ``LONs``, ``LATp``, ``LONp`` (degrees), ``R``, ``Range``, ``Alt`` (metres), ``AZN``,
        ``AZSC`` (degrees, in [0, 360)) and ``tilt`` (degrees).

    Raises
    ------
    GeometryError
        A camera axis that misses the sphere, or a camera below it.
    InvalidInputError
        Wrong shapes or a matrix that is not a rotation.
    """
    pos = np.asarray(position, float).reshape(-1, 3)
    rot = np.asarray(sensor_rotation, float).reshape(-1, 3, 3)
    if rot.shape[0] != pos.shape[0]:
        raise InvalidInputError(f"{pos.shape[0]} positions for {rot.shape[0]} rotations")
    err = np.abs(rot @ np.transpose(rot, (0, 2, 1)) - np.eye(3)).max(axis=(1, 2))
    if np.any(err > 1e-9) or np.any(np.linalg.det(rot) < 0):
        raise InvalidInputError("sensor_rotation must hold proper rotation matrices")
    r = np.linalg.norm(pos, axis=1)
    if np.any(r <= radius):
        raise GeometryError(f"camera at or below the {radius:.1f} m sphere")
    up = pos / r[:, None]
    m = rot @ PHOTO_TO_SENSOR                        # photo -> body
    axis = rot[:, :, 2]                              # look direction of the principal point
    b = np.einsum("ni,ni->n", pos, axis)
    disc = b * b - (r * r - radius * radius)
    if np.any((disc < 0) | (b >= 0)):
        raise GeometryError("a camera axis misses the sphere: no lunar principal point")
    rng = -b - np.sqrt(disc)
    p = pos + rng[:, None] * axis
    lat_s, lon_s = np.degrees(np.arcsin(up[:, 2])), np.degrees(np.arctan2(up[:, 1], up[:, 0]))
    lat_p = np.degrees(np.arcsin(p[:, 2] / radius))
    lon_p = np.degrees(np.arctan2(p[:, 1], p[:, 0]))
    level = np.transpose(_rz(np.radians(90.0 + lon_s)) @ _rx(np.radians(90.0 - lat_s)), (0, 2, 1)) @ m  # photo -> ENU
    nadir = np.einsum("nji,j->ni", level, np.array([0.0, 0.0, -1.0]))   # nadir look, photo coordinates
    tilt = np.degrees(np.arccos(np.clip(-nadir[:, 2], -1.0, 1.0)))
    vertical = np.hypot(nadir[:, 0], nadir[:, 1]) < 1e-15
    azsc = np.where(vertical, 0.0, np.degrees(np.arctan2(-nadir[:, 0], nadir[:, 1])))
    # rabatment: the rotation about the axis of tilt taking the photo normal to the vertical
    normal = level[:, :, 2]
    ax = np.cross(normal, np.array([0.0, 0.0, 1.0]))
    s = np.linalg.norm(ax, axis=1)
    k = np.where(s[:, None] > 0, ax / np.where(s > 0, s, 1.0)[:, None], 0.0)
    ang = np.arctan2(s, normal[:, 2])
    kx = np.zeros((k.shape[0], 3, 3))
    kx[:, 0, 1], kx[:, 0, 2], kx[:, 1, 0], kx[:, 1, 2], kx[:, 2, 0], kx[:, 2, 1] = \
        -k[:, 2], k[:, 1], k[:, 2], -k[:, 0], -k[:, 1], k[:, 0]
    rab = np.eye(3) + np.sin(ang)[:, None, None] * kx + (1 - np.cos(ang))[:, None, None] * (kx @ kx)
    r1 = rab @ level
    azn = np.degrees(np.arctan2(r1[:, 1, 0], r1[:, 0, 0]))
    return {"LATs": lat_s, "LONs": lon_s, "LATp": lat_p, "LONp": lon_p, "R": r, "Range": rng, "Alt": r - radius,
            "AZN": _azimuth(azn), "AZSC": _azimuth(azsc), "tilt": tilt}


def _azimuth(a: Array) -> Array:
    """Degrees in [0, 360) (``np.mod`` of a tiny negative angle gives 360)."""
    m = np.mod(a, 360.0)
    return np.where(m >= 360.0, m - 360.0, m)
