"""Viewing and illumination geometry of images and stereo pairs, from their sensor models.

Everything is computed at a ground point ``P`` (body-fixed metres) from the sensor model alone:
the image coordinates of ``P`` (``ground_to_image``), the sensor position and time of that pixel
(cameras), the Sun position the camera's exterior orientation carries, and the local surface
normal of the camera's shape. Definitions (angles at ``P`` unless said otherwise):

=============================  ==================================================================
quantity                       definition
=============================  ==================================================================
emission                       angle between the surface normal and the direction to the sensor
incidence                      angle between the surface normal and the direction to the Sun
phase                          angle between the directions to the sensor and to the Sun
sub-solar ground azimuth       azimuth of the Sun's direction in the local horizontal plane,
                               clockwise from north (ISIS ``SubSolarGroundAzimuth``)
sub-solar azimuth              direction towards the Sun *in the image*, clockwise from the
                               +sample axis ("3 o'clock", lines increasing downwards; ISIS
                               ``SubSolarAzimuth``, the study's Tables 2-3)
north azimuth                  the same for the direction to the north
off-nadir                      angle at the sensor between nadir (towards the body centre) and
                               the line of sight to ``P``
slew                           that angle's component across the ground track: positive when the
                               sensor looks to the right of its velocity
scaled pixel width / height    ground distance (at ``P``'s height) between the two ends of the
                               pixel through ``P`` along the sample / line direction: the
                               study's "scaled pixel width/height", which include obliquity
aspect ratio                   scaled pixel width / scaled pixel height
convergence                    angle between the two lines of sight at ``P``
B/H                            distance between the two sensor positions over their mean height
                               above the tangent plane at ``P``
bisector elevation             elevation of the bisector of the two lines of sight above the
                               local horizontal plane (Jeong & Kim 2014)
parallax/height ratio          ``|tan(e1) a1 - tan(e2) a2|`` with ``a`` the horizontal unit vector
                               towards each sensor (Becker et al. 2015)
shadow-tip distance            distance between the tips of the shadows of a unit vertical pole in
                               the two images, ``|tan(i1) s1 - tan(i2) s2|`` with ``s`` the
                               horizontal unit vector towards the Sun (Becker et al. 2015: a
                               measure of the illumination mismatch, dimensionless)
ratio of aspect ratios         larger aspect ratio over the smaller (>= 1)
=============================  ==================================================================

An RFM has no sensor position or Sun: its line of sight is the RFM's ray through ``P`` and the
quantities that need a position or the Sun are NaN unless ``sun`` is given.
"""

from __future__ import annotations

from itertools import combinations
from typing import Any, Mapping, Sequence

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from ..camera.geodesy import xyz_to_lonlat_height
from ..camera.sensor import SensorModel
from ..errors import EvaluationInputError, GeometryError, NoOverlapError
from .footprint import Footprint, footprint, overlap

__all__ = ["ViewGeometry", "view_geometry", "image_geometry", "pair_geometry", "shadow_tip_distance",
           "parallax_height_ratio", "image_centre_point"]

Array = NDArray[np.float64]


def _unit(v: Array) -> Array:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _angle(a: Array, b: Array) -> Array:
    """Angle between vectors (radians), accurate at 0 and pi (atan2 of cross and dot)."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def _normal(sensor: Any, xyz: Array) -> Array:
    """Outward unit normal of the sensor's shape (ellipsoid grown to the point) at ``xyz``."""
    shape = getattr(sensor, "shape", None)
    if shape is None or getattr(shape, "is_sphere", True):
        return _unit(xyz)
    # ellipsoid through the point with the same semi-axis increments: the gradient of
    # x^2/a^2 + y^2/b^2 + z^2/c^2 with the axes grown by the point's height above the shape
    h = np.linalg.norm(xyz, axis=-1) - float(shape.reference_radius)
    ax = shape.axes_at_height(h)
    return _unit(xyz / ax ** 2)


def _horizontal_basis(n: Array) -> tuple[Array, Array]:
    """East and north unit vectors of the plane perpendicular to the normal ``n`` (..., 3)."""
    z = np.broadcast_to(np.array([0.0, 0.0, 1.0]), n.shape)
    east = np.cross(z, n)
    small = np.linalg.norm(east, axis=-1) < 1e-12
    east = np.where(small[..., None], np.array([0.0, 1.0, 0.0]), east)
    east = _unit(east)
    return east, np.cross(n, east)


def _azimuth(v: Array, east: Array, north: Array) -> Array:
    """Azimuth (radians, [0, 2 pi)) of vectors in the horizontal plane, clockwise from north."""
    return np.mod(np.arctan2(np.sum(v * east, axis=-1), np.sum(v * north, axis=-1)), 2.0 * np.pi)


def _exposure(sensor: Any, line: Array, sample: Array) -> tuple[Array, Array, Array, Array]:
    """Sensor position (m), velocity (m/s), ET (s) and Sun position (m) of pixels; NaN where unknown."""
    nan3 = np.full(line.shape + (3,), np.nan)
    eo = getattr(sensor, "eo", None)
    if eo is None or not hasattr(sensor, "sensor_position"):
        return nan3, nan3.copy(), np.full(line.shape, np.nan), nan3.copy()
    pos = sensor.sensor_position(line, sample)
    if hasattr(sensor, "image_time"):
        t = np.asarray(sensor.image_time(line), float)          # line scan: per line
    else:
        t = np.full(line.shape, float(getattr(sensor, "time", sensor.center_time - eo.epoch)))
    return pos, eo.velocity_at(t), eo.epoch + t, eo.sun_position_at(t)


class ViewGeometry:
    """Per-point viewing and illumination geometry of one image (see the module docstring).

    All angles in radians, lengths in metres, ``et`` in TDB seconds past J2000; arrays have the
    shape of the points (NaN where the quantity needs what the sensor does not have).

    Attributes
    ----------
    xyz, line, sample, et, sensor_position, sun_position
    emission, incidence, phase, subsolar_ground_azimuth, sensor_ground_azimuth
    subsolar_azimuth, north_azimuth, off_nadir, slew, slant_range, altitude
    pixel_width, pixel_height, inside
    """

    # the fields view_geometry sets (the instance's __dict__)
    xyz: Array
    line: Array
    sample: Array
    et: Array
    sensor_position: Array
    sun_position: Array
    emission: Array
    incidence: Array
    phase: Array
    subsolar_ground_azimuth: Array
    sensor_ground_azimuth: Array
    subsolar_azimuth: Array
    north_azimuth: Array
    off_nadir: Array
    slew: Array
    slant_range: Array
    altitude: Array
    pixel_width: Array
    pixel_height: Array
    normal: Array
    to_sensor: Array
    to_sun: Array
    east: Array
    north: Array
    inside: NDArray[np.bool_]

    def __init__(self, **fields: NDArray) -> None:
        self.__dict__.update(fields)

    @property
    def aspect_ratio(self) -> Array:
        """Scaled pixel width over height (dimensionless)."""
        return self.pixel_width / self.pixel_height

    @property
    def gsd(self) -> Array:
        """Ground sample distance: geometric mean of the scaled pixel width and height, metres."""
        return np.sqrt(self.pixel_width * self.pixel_height)


def view_geometry(sensor: SensorModel, xyz: ArrayLike, sun: ArrayLike | None = None,
                  name: str = "image") -> ViewGeometry:
    """Viewing and illumination geometry of ``sensor`` at ground points.

    Parameters
    ----------
    sensor : SensorModel
        Frame or line-scan camera (everything), RFM (angles from its rays; no position or Sun).
    xyz : array_like (..., 3)
        Ground points, body-fixed metres.
    sun : array_like (3,) or (..., 3), optional
        Sun position, body-fixed metres, overriding the camera's.
    name : str
        Image name for messages.

    Raises
    ------
    GeometryError
        A point behind the sensor or hidden by the body (named image).
    """
    P = np.asarray(xyz, float)
    if P.shape[-1:] != (3,) or not np.all(np.isfinite(P)):
        raise EvaluationInputError(f"{name}: ground points must be finite arrays (..., 3), got shape {P.shape}")
    line, sample = sensor.ground_to_image(P, on_miss="nan", within_image=False)
    line, sample = np.asarray(line, float), np.asarray(sample, float)
    if not (np.all(np.isfinite(line)) and np.all(np.isfinite(sample))):
        raise GeometryError(f"{name}: {int(np.sum(~np.isfinite(line)))} point(s) are not seen by the sensor "
                            "(behind it or hidden by the body)")
    inside = (line >= 0) & (line <= sensor.n_lines) & (sample >= 0) & (sample <= sensor.n_samples)
    C, V, et, S = _exposure(sensor, line, sample)
    has_pos = np.all(np.isfinite(C), axis=-1)
    origin, look = sensor.rays(line, sample)
    # the line of sight from the point to the sensor: exactly (C - P) for a camera
    to_sensor = np.where(has_pos[..., None], _unit(np.where(has_pos[..., None], C, 0.0) - P), -look)
    if sun is not None:
        S = np.broadcast_to(np.asarray(sun, float), P.shape)
    to_sun = _unit(S - P)
    n = _normal(sensor, P)
    east, north = _horizontal_basis(n)
    emission = _angle(n, to_sensor)
    incidence = _angle(n, to_sun)
    phase = _angle(to_sensor, to_sun)
    az_sun = _azimuth(to_sun, east, north)
    az_sensor = _azimuth(to_sensor, east, north)

    # directions in the image: the image-space image of a horizontal ground direction (ground partials)
    _, _, J = sensor.ground_partials(P)

    def image_azimuth(d: Array) -> Array:
        dl = np.einsum("...j,...j->...", J[..., 0, :], d)
        ds = np.einsum("...j,...j->...", J[..., 1, :], d)
        return np.mod(np.arctan2(dl, ds), 2.0 * np.pi)

    sun_h = to_sun - np.sum(to_sun * n, axis=-1, keepdims=True) * n
    subsolar_azimuth = image_azimuth(sun_h)
    north_azimuth = image_azimuth(north)

    # off-nadir and slew at the sensor
    nadir = -_unit(np.where(has_pos[..., None], C, 1.0))
    los = -to_sensor
    off_nadir = np.where(has_pos, _angle(nadir, los), np.nan)
    right = _unit(np.cross(np.where(has_pos[..., None], V, 1.0), -nadir))
    slew = np.where(has_pos, np.arctan2(np.sum(los * right, axis=-1), np.sum(los * nadir, axis=-1)), np.nan)
    slant = np.where(has_pos, np.linalg.norm(np.where(has_pos[..., None], C, 0.0) - P, axis=-1), np.nan)
    altitude = np.where(has_pos, np.linalg.norm(np.where(has_pos[..., None], C, 0.0), axis=-1)
                        - float(sensor.reference_radius), np.nan)

    # scaled pixel: ground distance across the pixel through P at P's height
    h = np.linalg.norm(P, axis=-1) - float(sensor.reference_radius)
    gw = sensor.image_to_ground(np.stack([line, line], -1), np.stack([sample - 0.5, sample + 0.5], -1),
                                height=h[..., None], on_miss="nan")
    gh = sensor.image_to_ground(np.stack([line - 0.5, line + 0.5], -1), np.stack([sample, sample], -1),
                                height=h[..., None], on_miss="nan")
    width = np.linalg.norm(gw[..., 1, :] - gw[..., 0, :], axis=-1)
    height = np.linalg.norm(gh[..., 1, :] - gh[..., 0, :], axis=-1)
    return ViewGeometry(xyz=P, line=line, sample=sample, et=et, sensor_position=C, sun_position=S,
                        emission=emission, incidence=incidence, phase=phase, subsolar_ground_azimuth=az_sun,
                        sensor_ground_azimuth=az_sensor, subsolar_azimuth=subsolar_azimuth,
                        north_azimuth=north_azimuth, off_nadir=off_nadir, slew=slew, slant_range=slant,
                        altitude=altitude, pixel_width=width, pixel_height=height, inside=inside,
                        normal=n, to_sensor=to_sensor, to_sun=to_sun, east=east, north=north)


def shadow_tip_distance(incidence1: ArrayLike, azimuth1: ArrayLike, incidence2: ArrayLike,
                        azimuth2: ArrayLike) -> Array:
    """Shadow-tip distance of two illuminations (Becker et al. 2015), dimensionless.

    The shadow of a vertical pole of unit height has length ``tan(i)`` and points away from the
    Sun's ground azimuth; the distance between the two shadow tips measures how differently two
    images are lit (0: identical).

    Parameters
    ----------
    incidence1, incidence2 : array_like
        Incidence angles, radians.
    azimuth1, azimuth2 : array_like
        Sub-solar ground azimuths, radians clockwise from north.
    """
    i1, a1, i2, a2 = (np.asarray(v, float) for v in (incidence1, azimuth1, incidence2, azimuth2))
    x1, y1 = -np.tan(i1) * np.sin(a1), -np.tan(i1) * np.cos(a1)
    x2, y2 = -np.tan(i2) * np.sin(a2), -np.tan(i2) * np.cos(a2)
    return np.hypot(x1 - x2, y1 - y2)


def parallax_height_ratio(emission1: ArrayLike, azimuth1: ArrayLike, emission2: ArrayLike,
                          azimuth2: ArrayLike) -> Array:
    """Parallax/height ratio of two views (Becker et al. 2015): ``|tan(e1) a1 - tan(e2) a2|``, dimensionless.

    ``azimuth`` is the ground azimuth of the direction to each sensor (radians, clockwise from north).
    """
    return shadow_tip_distance(emission1, azimuth1, emission2, azimuth2)


def image_centre_point(sensor: SensorModel, height: float = 0.0) -> Array:
    """The ground point (body-fixed metres, at ``height``) seen at the centre of the image."""
    return np.asarray(sensor.image_to_ground(0.5 * sensor.n_lines, 0.5 * sensor.n_samples, height=height), float)


def _sensors(sensors: Mapping[str, SensorModel] | Sequence[SensorModel] | SensorModel) -> dict[str, SensorModel]:
    if isinstance(sensors, Mapping):
        out = {str(k): v for k, v in sensors.items()}
    elif isinstance(sensors, SensorModel):
        out = {"image": sensors}
    else:
        out = {f"image{i}": s for i, s in enumerate(sensors)}
    for k, s in out.items():
        if not isinstance(s, SensorModel):
            raise EvaluationInputError(f"{k}: not a SensorModel ({type(s).__name__})")
    if not out:
        raise EvaluationInputError("no images given")
    return out


_DEG = {"units": "degree"}


def image_geometry(sensors: Mapping[str, SensorModel] | Sequence[SensorModel] | SensorModel,
                   point: ArrayLike | None = None, height: float = 0.0, sun: ArrayLike | None = None) -> xr.Dataset:
    """Per-image geometry table (the study's Tables 2-3, ISIS ``camstats``-like), at one ground point.

    Parameters
    ----------
    sensors : mapping name -> SensorModel, sequence, or one SensorModel
    point : array_like (3,), optional
        Body-fixed ground point, metres; default: each image's centre at ``height``.
    height : float
        Metres above the reference sphere for the default points.
    sun : array_like (3,), optional
        Sun position overriding the cameras', body-fixed metres.

    Returns
    -------
    xarray.Dataset
        Over ``image``: ``lon``, ``lat``, ``height`` of the point; ``et``; ``emission``,
        ``incidence``, ``phase``, ``subsolar_ground_azimuth``, ``subsolar_azimuth``,
        ``north_azimuth``, ``off_nadir``, ``slew`` (degrees); ``slant_range``, ``altitude``,
        ``pixel_width``, ``pixel_height``, ``gsd`` (metres); ``aspect_ratio``; ``inside``.
    """
    cams = _sensors(sensors)
    rows = []
    for name, s in cams.items():
        P = image_centre_point(s, height) if point is None else np.asarray(point, float)
        rows.append(view_geometry(s, P, sun=sun, name=name))
    return _image_dataset(list(cams), rows)


def _image_dataset(names: list[str], rows: list[ViewGeometry]) -> xr.Dataset:
    def col(attr: str) -> Array:
        return np.array([float(np.asarray(getattr(r, attr))) for r in rows])

    def deg(attr: str) -> tuple[str, Array, dict]:
        return ("image", np.degrees(col(attr)), _DEG)

    xyz = np.array([r.xyz for r in rows]).reshape(-1, 3)
    lon, lat, h = xyz_to_lonlat_height(xyz)
    return xr.Dataset(
        {"lon": ("image", lon, {"units": "degrees_east"}), "lat": ("image", lat, {"units": "degrees_north"}),
         "height": ("image", h, {"units": "m"}), "et": ("image", col("et"), {"units": "s TDB past J2000"}),
         "line": ("image", col("line"), {"units": "pixel"}), "sample": ("image", col("sample"), {"units": "pixel"}),
         "emission": deg("emission"), "incidence": deg("incidence"), "phase": deg("phase"),
         "subsolar_ground_azimuth": deg("subsolar_ground_azimuth"), "subsolar_azimuth": deg("subsolar_azimuth"),
         "north_azimuth": deg("north_azimuth"), "sensor_ground_azimuth": deg("sensor_ground_azimuth"),
         "off_nadir": deg("off_nadir"), "slew": deg("slew"),
         "slant_range": ("image", col("slant_range"), {"units": "m"}),
         "altitude": ("image", col("altitude"), {"units": "m"}),
         "pixel_width": ("image", col("pixel_width"), {"units": "m"}),
         "pixel_height": ("image", col("pixel_height"), {"units": "m"}),
         "gsd": ("image", col("gsd"), {"units": "m"}), "aspect_ratio": ("image", col("aspect_ratio")),
         "inside": ("image", np.array([bool(r.inside) for r in rows]))},
        coords={"image": np.array(names, dtype=object)},
        attrs={"source": "lunarmap.evaluate.image_geometry"})


def _pair_row(g1: ViewGeometry, g2: ViewGeometry) -> dict[str, float]:
    conv = float(_angle(g1.to_sensor, g2.to_sensor))
    bis = _unit(g1.to_sensor + g2.to_sensor)
    bie = float(np.pi / 2 - _angle(g1.normal, bis))
    C1, C2 = g1.sensor_position, g2.sensor_position
    base = float(np.linalg.norm(C1 - C2))
    H = 0.5 * float(np.dot(C1 - g1.xyz, g1.normal) + np.dot(C2 - g2.xyz, g2.normal))
    ar1, ar2 = float(g1.aspect_ratio), float(g2.aspect_ratio)
    return {
        "convergence": conv, "bisector_elevation": bie, "base": base, "base_height": base / H, "height_above": H,
        "parallax_height_ratio": float(parallax_height_ratio(g1.emission, g1.sensor_ground_azimuth,
                                                             g2.emission, g2.sensor_ground_azimuth)),
        "shadow_tip_distance": float(shadow_tip_distance(g1.incidence, g1.subsolar_ground_azimuth,
                                                         g2.incidence, g2.subsolar_ground_azimuth)),
        "aspect_ratio_ratio": max(ar1, ar2) / min(ar1, ar2),
        "resolution_ratio": float(max(g1.gsd, g2.gsd) / min(g1.gsd, g2.gsd)),
        "incidence_difference": float(abs(g1.incidence - g2.incidence)),
        "emission1": float(g1.emission), "emission2": float(g2.emission),
    }


def pair_geometry(sensors: Mapping[str, SensorModel] | Sequence[SensorModel],
                  pairs: Sequence[tuple[str, str]] | None = None, point: ArrayLike | None = None,
                  height: float = 0.0, on_no_overlap: str = "skip", per_side: int = 32) -> xr.Dataset:
    """Stereo geometry of every pair of images (the study's supplementary pair tables).

    Parameters
    ----------
    sensors : mapping name -> SensorModel (or a sequence, named ``image0``...)
    pairs : sequence of (name, name), optional
        Pairs to evaluate (default: all).
    point : array_like (3,), optional
        Body-fixed ground point (metres) for every pair; default: the centroid of each pair's
        overlap at ``height``.
    height : float
        Height of the footprints (and default points) above the reference sphere, metres.
    on_no_overlap : {"skip", "raise"}
        Disjoint pairs: left out and listed in ``attrs["skipped"]``, or
        :class:`~lunarmap.errors.NoOverlapError`.
    per_side : int
        Footprint border samples per image edge.

    Returns
    -------
    xarray.Dataset
        Over ``pair`` (coords ``image1``, ``image2``): ``convergence``, ``bisector_elevation``,
        ``emission1``, ``emission2``, ``incidence_difference`` (degrees); ``base``, ``height_above``
        (m), ``base_height`` (B/H), ``parallax_height_ratio``, ``shadow_tip_distance``,
        ``aspect_ratio_ratio``, ``resolution_ratio``; ``overlap_area`` (m^2), ``overlap_fraction``;
        ``lon``, ``lat``, ``height`` of the evaluation point.

    Raises
    ------
    EvaluationInputError
        Fewer than two images, unknown names in ``pairs``.
    NoOverlapError
        A disjoint pair with ``on_no_overlap="raise"``.
    """
    cams = _sensors(sensors)
    if len(cams) < 2:
        raise EvaluationInputError(f"a stereo pair needs two images, got {len(cams)}: {list(cams)}")
    if on_no_overlap not in ("skip", "raise"):
        raise EvaluationInputError(f"on_no_overlap must be 'skip' or 'raise', got {on_no_overlap!r}")
    todo = list(combinations(list(cams), 2)) if pairs is None else [(str(a), str(b)) for a, b in pairs]
    unknown = sorted({n for p in todo for n in p if n not in cams})
    if unknown:
        raise EvaluationInputError(f"unknown image(s) {unknown}; the images are {list(cams)}")
    same = [p for p in todo if p[0] == p[1]]
    if same:
        raise EvaluationInputError(f"a pair needs two different images, got {same[0]}")
    fps: dict[str, Footprint] = {}
    rows, keys, skipped = [], [], []
    for a, b in todo:
        for n in (a, b):
            if n not in fps:
                fps[n] = footprint(cams[n], height, per_side, name=n)
        ov = overlap(fps[a], fps[b], (a, b), require=(on_no_overlap == "raise"))
        if ov.area <= 0.0:
            skipped.append(f"{a}/{b}: no overlap")
            continue
        P = ov.centroid if point is None else np.asarray(point, float)
        g1 = view_geometry(cams[a], P, name=a)
        g2 = view_geometry(cams[b], P, name=b)
        row = _pair_row(g1, g2)
        row.update(overlap_area=ov.area, overlap_fraction=ov.fraction)
        lon, lat, h = xyz_to_lonlat_height(P)
        row.update(lon=float(lon), lat=float(lat), height=float(h))
        rows.append(row)
        keys.append((a, b))
    if not rows and on_no_overlap == "raise":   # pragma: no cover - raised above
        raise NoOverlapError("no pair overlaps")
    angles = ("convergence", "bisector_elevation", "emission1", "emission2", "incidence_difference")
    units = {"base": "m", "height_above": "m", "overlap_area": "m2", "lon": "degrees_east",
             "lat": "degrees_north", "height": "m"}
    cols = list(rows[0]) if rows else []
    data = {}
    for c in cols:
        v = np.array([r[c] for r in rows], float)
        data[c] = ("pair", np.degrees(v) if c in angles else v, _DEG if c in angles else
                   ({"units": units[c]} if c in units else {}))
    return xr.Dataset(data, coords={"pair": [f"{a}/{b}" for a, b in keys],
                                    "image1": ("pair", np.array([a for a, _ in keys], dtype=object)),
                                    "image2": ("pair", np.array([b for _, b in keys], dtype=object))},
                      attrs={"skipped": skipped, "footprint_height_m": float(height),
                             "source": "lunarmap.evaluate.pair_geometry"})
