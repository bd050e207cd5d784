"""Ranger-like descending photo sequences with known truth, and their simulated measurements.

The geometry follows Ranger IX's last B-camera frames as the paper describes them (Table I: base-
height ratios 0.032, 0.054 and 0.081 for frames 435-437, 437-439 and 435-439): the spacecraft falls
along a straight line at ``speed`` towards the impact point, photos are ``interval`` seconds apart,
and the camera axis is held (three-axis stabilised, fixed attitude) ``axis_offset`` degrees off the
flight direction, which is what gives consecutive photos a stereo base at all. With the defaults
(2.67 km/s, 5.12 s between the listed frames, the last at 13.4 km, axis 4.5 degrees off) the ratios
come out as 0.032, 0.054 and 0.080 under :func:`~lunarmap.missions.ranger.base_height_ratio`.

The photo coordinates are those of a print of the B camera's 11 mm vidicon image enlarged
``magnification`` times (the paper measured prints with a glass scale to 10 um); the simulated
measurement noise is in those print millimetres. Everything else is lunarmap's conventions:
body-fixed metres, degrees north/east, the 1736.6 km sphere of the paper.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from numpy.typing import NDArray

from ..camera import FrameCamera
from ..camera.geodesy import enu_basis, lonlat_height_to_xyz, xyz_to_lonlat_height
from ..errors import InvalidInputError, SimulationWarning, warn
from .flight_parameters import DEFAULT_RADIUS, FlightParameters
from .multiray import TransferMode
from .ranger import RangerCamera, ranger_cameras

__all__ = ["RangerSequence", "RangerMeasurements", "ranger_sequence", "simulate_measurements",
           "RANGER_IX_IMPACT_ET", "print_camera"]

Array = NDArray[np.float64]

#: 1965-03-24T14:08:20 UTC (Ranger IX impact) as ET with naif0012's leap seconds (TDB s past J2000).
RANGER_IX_IMPACT_ET = -1097358658.8143659


def print_camera(magnification: float = 15.0, pixel: float = 0.01) -> RangerCamera:
    """The B camera (76 mm, 11 mm vidicon image) on a print enlarged ``magnification`` times."""
    return RangerCamera(focal_length=76.0 * magnification, format=11.0 * magnification, pixel=pixel,
                        name="RANGER B CAMERA (print)")


@dataclass
class RangerSequence:
    """A simulated sequence: truth flight parameters, cameras and terrain.

    Attributes
    ----------
    table : FlightParameters
        The true flight parameters (exact: generated from the true orientation).
    camera : RangerCamera
    cameras : dict photo -> FrameCamera
        The true cameras, built from ``table`` by the five rotations.
    positions : ndarray (n, 3)
        True exposure stations, body-fixed metres.
    rotations : ndarray (n, 3, 3)
        True sensor-to-body rotations.
    site : (lat, lon)
        Impact point, degrees.
    terrain : (mean, amplitude, wavelength)
        The smooth terrain, metres above the sphere (:meth:`height`).
    """

    table: FlightParameters
    camera: RangerCamera
    cameras: dict[str, FrameCamera]
    positions: Array
    rotations: Array
    site: tuple[float, float]
    terrain: tuple[float, float, float] = field(default=(350.0, 150.0, 4000.0))

    @property
    def radius(self) -> float:
        return self.table.radius

    def height(self, lon: Array, lat: Array) -> Array:
        """Terrain height, metres above the sphere, at degrees east / north."""
        mean, amp, wl = self.terrain
        e = np.radians(lon - self.site[1]) * self.radius * np.cos(np.radians(self.site[0]))
        n = np.radians(lat - self.site[0]) * self.radius
        return mean + amp * (0.6 * np.sin(e / wl * 2 * np.pi + 0.4) * np.cos(n / (1.3 * wl) * 2 * np.pi)
                             + 0.4 * np.sin((e + n) / (0.7 * wl) * 2 * np.pi))

    def ground_points(self, n: int, rng: np.random.Generator, photo: str | None = None,
                      margin: float = 0.1) -> Array:
        """``n`` terrain points inside the footprint of ``photo`` (default the last, smallest), body-fixed metres."""
        cam = self.cameras[photo or self.table.photo[-1]]
        size = cam.interior.n_lines
        lines = rng.uniform(margin * size, (1 - margin) * size, n)
        samples = rng.uniform(margin * size, (1 - margin) * size, n)
        g = cam.image_to_ground(lines, samples, height=self.terrain[0])
        for _ in range(6):   # onto the terrain: intersect at the terrain height under the previous point
            lon, lat, _ = xyz_to_lonlat_height(g, self.radius)
            g = cam.image_to_ground(lines, samples, height=self.height(lon, lat))
        return g


def ranger_sequence(photos: Sequence[str] = ("435", "437", "439"), *, last_range: float = 13.4e3,
                    speed: float = 2670.0, interval: float = 5.12, site: tuple[float, float] = (-12.83, -2.37),
                    approach_zenith: float = 30.0, approach_azimuth: float = 270.0, axis_offset: float = 4.5,
                    offset_azimuth: float = 0.0, swing: float = 20.0, camera: RangerCamera | None = None,
                    radius: float = DEFAULT_RADIUS, impact_et: float = RANGER_IX_IMPACT_ET) -> RangerSequence:
    """A Ranger-like sequence (module docstring); distances metres, angles degrees, times seconds.

    Parameters
    ----------
    photos : sequence of str
        Photo ids, in time order (the last is the lowest).
    last_range : float
        Distance from the last exposure station to the impact point along the flight path.
    speed, interval : float
        Approach speed (m/s) and time between listed photos (s).
    site : (lat, lon)
        Impact point, degrees north / east (default: Alphonsus, Ranger IX).
    approach_zenith, approach_azimuth : float
        Flight path: angle from the local vertical and azimuth (from north, clockwise) of the direction
        of motion at the impact point.
    axis_offset, offset_azimuth : float
        Camera axis: angle from the flight direction and the direction of that offset (azimuth of its
        horizontal part).
    swing : float
        Rotation of the camera about its axis.
    camera : RangerCamera, optional
        Default :func:`print_camera` (15x print of the B camera).
    radius : float
        Sphere radius, metres.
    impact_et : float
        Impact time, ET; photo ``k`` is exposed ``(last_range + (n-1-k) speed interval) / speed`` before it.
    """
    n = len(photos)
    if n < 2:
        raise InvalidInputError("a Ranger sequence needs at least 2 photos")
    if not (0 <= approach_zenith < 80 and 0 <= axis_offset < 30 and last_range > 0 and speed > 0 and interval > 0):
        raise InvalidInputError("ranger_sequence: implausible geometry (zenith 0-80 deg, offset 0-30 deg, positive "
                                "range, speed and interval)")
    camera = camera or print_camera()
    lat0, lon0 = site
    E = enu_basis(lon0, lat0)                        # rows east, north, up
    impact = lonlat_height_to_xyz(lon0, lat0, 0.0, radius)
    az, ze = np.radians(approach_azimuth), np.radians(approach_zenith)
    u = np.sin(ze) * (np.sin(az) * E[0] + np.cos(az) * E[1]) - np.cos(ze) * E[2]   # direction of motion
    s = last_range + speed * interval * np.arange(n - 1, -1, -1, dtype=float)
    pos = impact[None, :] - s[:, None] * u[None, :]
    et = impact_et - s / speed
    # camera axis: the flight direction turned by axis_offset towards offset_azimuth
    oa = np.radians(offset_azimuth)
    side = np.sin(oa) * E[0] + np.cos(oa) * E[1]
    side = side - np.dot(side, u) * u
    side /= np.linalg.norm(side)
    axis = np.cos(np.radians(axis_offset)) * u + np.sin(np.radians(axis_offset)) * side
    x0 = np.cross(axis, E[2])
    x0 /= np.linalg.norm(x0)
    y0 = np.cross(axis, x0)
    sw = np.radians(swing)
    xs, ys = np.cos(sw) * x0 + np.sin(sw) * y0, -np.sin(sw) * x0 + np.cos(sw) * y0
    rot = np.repeat(np.stack([xs, ys, axis], axis=-1)[None], n, axis=0)     # sensor -> body, fixed attitude
    table = FlightParameters.from_orientation(list(photos), pos, rot, radius=radius, et=et)
    cams = ranger_cameras(table, camera)
    return RangerSequence(table, camera, cams, pos, rot, (float(lat0), float(lon0)))


@dataclass
class RangerMeasurements:
    """Simulated photo measurements of one run.

    Attributes
    ----------
    point, photo : ndarray of str (m,)
    xy : ndarray (m, 2)
        Photo coordinates, millimetres.
    truth : ndarray (n_points, 3)
        The surface point actually measured (for a stereo transfer: the one marked on the reference
        photo), body-fixed metres; ``intended`` is the point meant.
    intended : ndarray (n_points, 3)
    point_ids : ndarray of str (n_points,)
    mode : TransferMode
    sigma : float
        Noise of the measurements the intersection sees, mm.
    """

    point: NDArray
    photo: NDArray
    xy: Array
    truth: Array
    intended: Array
    point_ids: NDArray
    mode: TransferMode
    sigma: float
    reference: str | None = None


def simulate_measurements(seq: RangerSequence, points: Array, photos: Sequence[str], rng: np.random.Generator, *,
                          mode: TransferMode | str = TransferMode.MONO, sigma: float = 0.33,
                          sigma_identification: float = 0.15, reference: str | None = None) -> RangerMeasurements:
    """Measure ``points`` on ``photos`` (millimetres on the print) in a transfer mode.

    ``"mono"``: every photo's measurement is the true projection plus Gaussian noise of ``sigma`` (which then
    includes the identification error). ``"stereo"``: the point is marked on ``reference`` (default: the last,
    highest-resolution photo) with an identification error of ``sigma_identification`` (mm on that photo),
    which selects a neighbouring surface point; that point is transferred to every photo (the reference
    included) with noise ``sigma``.
    """
    mode = TransferMode(mode)
    photos = [str(p) for p in photos]
    pts = np.asarray(points, float).reshape(-1, 3)
    ids = np.array([f"P{i + 1}" for i in range(pts.shape[0])])
    truth = pts.copy()
    ref = None
    if mode is TransferMode.STEREO:
        ref = reference or seq.table.photo[-1]
        cam = seq.cameras[ref]
        line, sample = cam.ground_to_image(pts, on_miss="nan", within_image=False)
        x, y = seq.camera.image_to_photo(line, sample)
        x = x + rng.normal(0.0, sigma_identification, x.shape)
        y = y + rng.normal(0.0, sigma_identification, y.shape)
        l2, s2 = seq.camera.photo_to_image(x, y)
        lon, lat, _ = xyz_to_lonlat_height(pts, seq.radius)
        h = seq.height(lon, lat)
        truth = cam.image_to_ground(l2, s2, height=h, on_miss="nan")
        for _ in range(4):
            lon, lat, _ = xyz_to_lonlat_height(truth, seq.radius)
            truth = cam.image_to_ground(l2, s2, height=seq.height(lon, lat), on_miss="nan")
    rows_p, rows_ph, rows_xy = [], [], []
    for ph in photos:
        line, sample = seq.cameras[ph].ground_to_image(truth, on_miss="nan")
        ok = np.isfinite(line)
        x, y = seq.camera.image_to_photo(line[ok], sample[ok])
        rows_p.append(ids[ok])
        rows_ph.append(np.full(int(ok.sum()), ph))
        rows_xy.append(np.column_stack([x, y]) + rng.normal(0.0, sigma, (int(ok.sum()), 2)))
    point, photo, xy = np.concatenate(rows_p), np.concatenate(rows_ph), np.concatenate(rows_xy)
    count = {i: 0 for i in ids}
    for p in point:
        count[p] += 1
    full = np.array([count[p] == len(photos) for p in point])
    if not full.all():
        warn(f"{len(ids) - sum(c == len(photos) for c in count.values())} simulated points are not seen on every "
             "photo and were dropped", SimulationWarning)
    keep_ids = np.array([i for i in ids if count[i] == len(photos)])
    sel = np.isin(ids, keep_ids)
    return RangerMeasurements(point[full], photo[full], xy[full], truth[sel], pts[sel], keep_ids, mode, float(sigma),
                              ref)
