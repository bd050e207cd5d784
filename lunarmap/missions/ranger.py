"""Ranger cameras from flight parameters, the paper's selenocentric frame and its tables' coordinates.

Photo coordinates and pixels
----------------------------
The paper measures photo coordinates ``(x, y)`` in millimetres on the photograph, in axes defined
by the reseau (``x`` right, ``y`` up on the positive). lunarmap's image coordinates are CSM pixels
``(line, sample)``; a :class:`RangerCamera` defines a square image of ``format`` millimetres in
pixels of ``pixel`` millimetres (the measuring resolution, 10 um by default) with the principal
point at its centre: ``sample = n/2 + x/pixel``, ``line = n/2 - y/pixel``. Its focal length is in the
same millimetres as the photo coordinates (on the vidicon face, or on a print enlarged by some
factor: then multiply the focal length by that factor).

The paper's selenocentric frame
-------------------------------
The coordinates printed in the paper's Tables II and III (``X'``, ``Y'``, ``Z'``, metres) come with
"south latitude" and "west longitude" that equal ``asin(Z'/r)`` and ``atan2(Y', X')``: in those
tables ``X'`` points to longitude 0, ``Y'`` to 90 deg *west* and ``Z'`` to the *south* pole, a
right-handed frame turned 180 degrees about ``X`` from lunarmap's body-fixed frame (the text says
``Z'`` points north; the printed numbers do not). :func:`paper_to_body_fixed` and
:func:`table_coordinates` convert; elevations are above the 1736.6 km sphere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..camera import FrameCamera, InteriorOrientation, Shape
from ..errors import InvalidInputError
from ..orientation.exterior import ExteriorOrientation
from ..orientation.rotation import matrix_to_quat
from .flight_parameters import DEFAULT_RADIUS, FlightParameters

__all__ = ["RangerCamera", "RANGER_B", "ranger_cameras", "paper_to_body_fixed", "body_fixed_to_paper",
           "table_coordinates", "base_height_ratio"]

Array = NDArray[np.float64]


@dataclass(frozen=True)
class RangerCamera:
    """A Ranger television camera as a frame camera whose image coordinates are photo millimetres.

    Parameters
    ----------
    focal_length : float
        Focal length, millimetres of the photo coordinates.
    format : float
        Side of the square image area, same millimetres.
    pixel : float
        Size of one image-coordinate pixel, same millimetres (measuring resolution).
    name : str
        Camera name (for messages and labels).
    """

    focal_length: float = 76.0
    format: float = 11.0
    pixel: float = 0.01
    name: str = "RANGER B CAMERA"

    def __post_init__(self) -> None:
        for k in ("focal_length", "format", "pixel"):
            v = getattr(self, k)
            if not (np.isfinite(v) and v > 0):
                raise InvalidInputError(f"RangerCamera.{k} must be a positive number of millimetres, got {v!r}")
        if self.pixel > self.format:
            raise InvalidInputError("RangerCamera.pixel must not exceed the format")

    @property
    def size(self) -> int:
        """Image size, pixels (lines = samples)."""
        return int(round(self.format / self.pixel))

    def interior(self) -> InteriorOrientation:
        """The interior orientation: principal point at the image centre, no distortion (reseau-corrected)."""
        n = self.size
        return InteriorOrientation(
            focal_length=float(self.focal_length), focal2pixel_lines=(0.0, 0.0, 1.0 / self.pixel),
            focal2pixel_samples=(0.0, 1.0 / self.pixel, 0.0), detector_center_line=n / 2.0,
            detector_center_sample=n / 2.0, n_lines=n, n_samples=n, pixel_pitch=float(self.pixel), name=self.name)

    def photo_to_image(self, x: ArrayLike, y: ArrayLike) -> tuple[Array, Array]:
        """``(line, sample)`` pixels of photo coordinates ``(x, y)`` millimetres."""
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        c = self.size / 2.0
        return c - y / self.pixel, c + x / self.pixel

    def image_to_photo(self, line: ArrayLike, sample: ArrayLike) -> tuple[Array, Array]:
        """Photo coordinates ``(x, y)`` millimetres of image coordinates ``(line, sample)`` pixels."""
        line, sample = np.broadcast_arrays(np.asarray(line, float), np.asarray(sample, float))
        c = self.size / 2.0
        return (sample - c) * self.pixel, (c - line) * self.pixel


#: Ranger VII-IX F-channel B camera on its vidicon face: 76 mm lens, 11 mm square image.
RANGER_B = RangerCamera()


def ranger_cameras(table: FlightParameters, camera: RangerCamera = RANGER_B,
                   shape: Shape | None = None) -> dict[str, FrameCamera]:
    """The frame camera of every photo of a flight-parameter table (orientation by the five rotations).

    Parameters
    ----------
    table : FlightParameters
        Flight parameters; the exposure time ``et`` (if present) becomes each camera's time.
    camera : RangerCamera
        Interior orientation shared by the photos.
    shape : Shape, optional
        Body shape; default a sphere of the table's radius.

    Returns
    -------
    dict
        Photo id -> :class:`~lunarmap.camera.FrameCamera` (body-fixed metres, CSM pixels).
    """
    shape = Shape.sphere(table.radius, name="MOON") if shape is None else shape
    rot = table.sensor_rotations()
    pos = table.positions
    io = camera.interior()
    out = {}
    for i, photo in enumerate(table.photo):
        epoch = float(table.et[i]) if table.et is not None else 0.0
        sun = 1.5e11 * pos[i] / np.linalg.norm(pos[i])  # illumination is not modelled here
        eo = ExteriorOrientation(epoch=epoch, times=np.array([0.0]), positions=pos[i][None],
                                 velocities=np.zeros((1, 3)), quaternions=matrix_to_quat(rot[i])[None],
                                 sun_times=np.array([0.0]), sun_positions=sun[None], body_frame="IAU_MOON",
                                 attrs={"source": "lunarmap.missions.ranger (five rotations)", "photo": photo})
        out[photo] = FrameCamera(io, eo, shape)
    return out


def body_fixed_to_paper(xyz: ArrayLike) -> Array:
    """The paper's ``X'Y'Z'`` (module docstring) of lunarmap body-fixed coordinates: ``(x, -y, -z)``."""
    xyz = np.asarray(xyz, float)
    return xyz * np.array([1.0, -1.0, -1.0])


def paper_to_body_fixed(xyz: ArrayLike) -> Array:
    """lunarmap body-fixed coordinates of the paper's ``X'Y'Z'``: ``(X', -Y', -Z')``."""
    return body_fixed_to_paper(xyz)


def table_coordinates(xyz_paper: ArrayLike, radius: float = DEFAULT_RADIUS) -> tuple[Array, Array, Array]:
    """South latitude, west longitude (degrees) and elevation (metres above ``radius``) of ``X'Y'Z'``.

    The quantities of the paper's Tables II and III, computed from its ``X'``, ``Y'``, ``Z'`` (metres).
    """
    p = np.asarray(xyz_paper, float)
    r = np.linalg.norm(p, axis=-1)
    return (np.degrees(np.arcsin(p[..., 2] / r)), np.degrees(np.arctan2(p[..., 1], p[..., 0])), r - radius)


def _principal_point(cam: FrameCamera) -> tuple[Array, Array]:
    io = cam.interior
    c = np.array([io.n_lines / 2.0]), np.array([io.n_samples / 2.0])
    pos = cam.sensor_position(*c)[0]
    ground = cam.image_to_ground(*c, height=0.0)[0]
    return pos, ground


def base_height_ratio(first: FrameCamera, second: FrameCamera) -> float:
    """Base-height ratio of two photos of a descending sequence (the paper's Table I, Fig. 5).

    The base is the component of the vector between the exposure stations perpendicular to the
    mean direction of the two camera axes; the height is the mean distance from the stations to
    their lunar principal points. (Fig. 5's equation is not legible in the OCR; this is the
    stereo base of the two rays to the common scene, which is what the ratio measures.)
    """
    p1, g1 = _principal_point(first)
    p2, g2 = _principal_point(second)
    d = (g1 - p1) / np.linalg.norm(g1 - p1) + (g2 - p2) / np.linalg.norm(g2 - p2)
    d /= np.linalg.norm(d)
    b = p2 - p1
    b_perp = b - np.dot(b, d) * d
    h = 0.5 * (np.linalg.norm(g1 - p1) + np.linalg.norm(g2 - p2))
    return float(np.linalg.norm(b_perp) / h)
