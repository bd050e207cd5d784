"""Multi-ray intersection of points measured on 2..n photos, with the Ranger paper's precision measures.

The paper ("Condition equations", Tables II-IV) intersects every point from all photos it was
measured on: an explicit first approximation from two rays (its Eqs. 1-3: the intersection of the
rays' projections on the ``X'Z'`` plane, then ``X'`` and ``Y'`` along the first ray), then a least-
squares solution of the collinearity equations with equal weights for all photo coordinates,
reporting ``S0`` (standard deviation of unit weight, in photo millimetres) and ``sigma X'``,
``sigma Y'``, ``sigma Z'`` (metres). :func:`intersect_photos` does the same on any lunarmap sensor
models: the least squares are :func:`lunarmap.adjust.intersect_points` (the adjustment's forward
intersection) started from the paper's explicit solution, ``S0 = sqrt(v^T v / (2k - 3))`` per point
and pooled over the run, covariance ``S0^2 N^-1``.

Point-transfer modes (the paper's Tables II and III)
----------------------------------------------------
``"mono"``
    Monoscopic transfer: the point is marked independently on every photo; each measurement carries
    its own identification error, which the intersection sees (it enlarges ``S0``).
``"stereo"``
    Stereoscopic transfer: the point is marked on one ``reference`` photo (the paper used the photo
    of highest resolution) and transferred stereoscopically to the others. The marking on the
    reference photo defines which surface point is measured, so its identification error moves the
    point along the surface, common to all rays, and does not enter ``S0`` (the paper's smaller
    ``S0`` for stereo transfer, Table IV). Every point must then be measured on the reference photo.

The computation (equal weights) is the same in both modes; the mode is checked and recorded.
The paper's frame ``X'Y'Z'`` is lunarmap's body-fixed frame turned 180 degrees about ``X``
(:func:`lunarmap.missions.ranger.body_fixed_to_paper`), so ``sigma X', Y', Z'`` equal the standard
deviations along lunarmap's axes.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Mapping

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from ..adjust import SensorImageModel, intersect_points
from ..camera.geodesy import xyz_to_lonlat_height
from ..camera.sensor import SensorModel
from ..errors import InvalidInputError, UnobservedParameterError
from .flight_parameters import DEFAULT_RADIUS
from .ranger import RangerCamera, body_fixed_to_paper

__all__ = ["TransferMode", "MultiRayResult", "intersect_photos", "first_approximation"]

Array = NDArray[np.float64]


class TransferMode(str, Enum):
    """How corresponding points were transferred between the photos (module docstring)."""

    MONO = "mono"
    STEREO = "stereo"


@dataclass
class MultiRayResult:
    """Intersected points with the paper's precision measures.

    Attributes
    ----------
    point_id : ndarray of str (n,)
    xyz : ndarray (n, 3)
        Body-fixed metres.
    cov : ndarray (n, 3, 3)
        ``S0^2 N^-1`` with each point's own ``S0``, m^2.
    cov_unit : ndarray (n, 3, 3)
        ``N^-1`` for a unit standard deviation of the measurements (photo mm or pixels), m^2 per unit^2.
    s0 : ndarray (n,)
        Standard deviation of unit weight per point, measurement units (from ``redundancy`` degrees of
        freedom: a 2-ray point has one, so its own ``S0`` is a rough estimate; see :meth:`sigma_pooled`).
    redundancy : ndarray (n,) int
        ``2k - 3`` for ``k`` rays.
    n_rays : ndarray (n,) int
    residuals : ndarray (m, 2)
        Measured minus computed, per measurement, measurement units (``x, y`` mm or ``line, sample`` px).
    mode : TransferMode
    reference : str or None
        The reference photo of a stereo transfer.
    units : str
        ``"mm"`` (photo coordinates) or ``"px"``.
    radius : float
        Sphere of the elevations, metres.
    """

    point_id: NDArray
    xyz: Array
    cov: Array
    cov_unit: Array
    s0: Array
    redundancy: NDArray[np.int64]
    n_rays: NDArray[np.int64]
    residuals: Array
    mode: TransferMode
    reference: str | None
    units: str
    radius: float

    @property
    def s0_pooled(self) -> float:
        """``sqrt(sum v^T v / sum (2k - 3))`` over all points, measurement units."""
        return float(np.sqrt(np.sum(self.s0 ** 2 * self.redundancy) / np.sum(self.redundancy)))

    @property
    def sigma(self) -> Array:
        """Standard deviations ``(n, 3)`` along X, Y, Z (= X', Y', Z'), metres, each point's own ``S0``."""
        return np.sqrt(np.diagonal(self.cov, axis1=1, axis2=2))

    def sigma_pooled(self) -> Array:
        """Standard deviations ``(n, 3)`` metres with the pooled ``S0`` of the run (a better estimate for 2-3 rays)."""
        return self.s0_pooled * np.sqrt(np.diagonal(self.cov_unit, axis1=1, axis2=2))

    @property
    def xyz_paper(self) -> Array:
        """The paper's ``X'Y'Z'`` (metres)."""
        return body_fixed_to_paper(self.xyz)

    def summary(self) -> dict[str, float]:
        """The paper's Table IV quantities: average ``S0`` and average ``sigma X', Y', Z'`` of the run."""
        s = self.sigma
        return {"S0": float(np.mean(self.s0)), "S0_pooled": self.s0_pooled, "sigma_X": float(np.mean(s[:, 0])),
                "sigma_Y": float(np.mean(s[:, 1])), "sigma_Z": float(np.mean(s[:, 2])), "points": int(self.xyz.shape[0])}

    def to_dataset(self) -> xr.Dataset:
        """Points, lat/lon/height (north/east, metres above ``radius``), sigmas, S0 as an xarray Dataset."""
        lon, lat, h = xyz_to_lonlat_height(self.xyz, self.radius)
        return xr.Dataset(
            {"xyz": (("point", "axis"), self.xyz, {"units": "m"}),
             "xyz_paper": (("point", "axis"), self.xyz_paper, {"units": "m", "long_name": "the paper's X'Y'Z'"}),
             "sigma": (("point", "axis"), self.sigma, {"units": "m"}),
             "lat": ("point", lat, {"units": "degrees_north"}), "lon": ("point", lon, {"units": "degrees_east"}),
             "height": ("point", h, {"units": "m"}),
             "s0": ("point", self.s0, {"units": self.units}), "n_rays": ("point", self.n_rays)},
            coords={"point": self.point_id.astype(object), "axis": ["x", "y", "z"]},
            attrs={"mode": self.mode.value, "reference": self.reference or "", "S0_pooled": self.s0_pooled,
                   "units": self.units, "radius_m": self.radius})


def first_approximation(c1: Array, d1: Array, c2: Array, d2: Array) -> Array:
    """The paper's explicit two-ray solution (Eqs. 1-3), vectorised: ``(n, 3)`` points.

    ``Z_P = [(X_1 - X_2) z1 z2 - Z_1 x1 z2 + Z_2 x2 z1] / (x2 z1 - x1 z2)`` from the rays' projections on
    the ``X-Z`` plane, then ``X_P = X_1 + (Z_P - Z_1) x1 / z1`` and ``Y_P = Y_1 + (Z_P - Z_1) y1 / z1``
    (``(X_i, Y_i, Z_i)`` the stations, ``(x_i, y_i, z_i)`` the ray directions). The paper's rays were
    far from parallel in that projection; here the coordinate axes are permuted per point so that the
    projection plane is the one in which the rays are least parallel (same formulas).
    """
    c1, d1, c2, d2 = (np.asarray(a, float).reshape(-1, 3) for a in (c1, d1, c2, d2))
    out = np.empty_like(c1)
    perms = [(0, 1, 2), (1, 2, 0), (2, 0, 1)]   # (x, y, z) roles: the plane is (x, z)
    dens = np.stack([np.abs(d2[:, p[0]] * d1[:, p[2]] - d1[:, p[0]] * d2[:, p[2]]) /
                     np.maximum(np.abs(d1[:, p[2]] * d2[:, p[2]]), 1e-300) for p in perms], axis=1)
    best = np.argmax(dens, axis=1)
    for k, (ix, iy, iz) in enumerate(perms):
        m = best == k
        if not m.any():
            continue
        X1, Y1, Z1 = c1[m, ix], c1[m, iy], c1[m, iz]
        X2, Z2 = c2[m, ix], c2[m, iz]
        x1, y1, z1 = d1[m, ix], d1[m, iy], d1[m, iz]
        x2, z2 = d2[m, ix], d2[m, iz]
        zp = ((X1 - X2) * z1 * z2 - Z1 * x1 * z2 + Z2 * x2 * z1) / (x2 * z1 - x1 * z2)
        out[m, ix] = X1 + (zp - Z1) * x1 / z1
        out[m, iy] = Y1 + (zp - Z1) * y1 / z1
        out[m, iz] = zp
    return out


def _widest_pair(centres: Array, pt_idx: NDArray[np.int64], n_pt: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Per point, the two measurements whose stations are farthest apart."""
    a = np.zeros(n_pt, np.int64)
    b = np.zeros(n_pt, np.int64)
    best = np.full(n_pt, -1.0)
    rows = np.argsort(pt_idx, kind="stable")
    bounds = np.searchsorted(pt_idx[rows], np.arange(n_pt + 1))
    for p in range(n_pt):
        r = rows[bounds[p]:bounds[p + 1]]
        dist = np.linalg.norm(centres[r][:, None] - centres[r][None], axis=2)
        i, j = np.unravel_index(np.argmax(dist), dist.shape)
        a[p], b[p], best[p] = r[i], r[j], dist[i, j]
    return a, b


def _reprojection(model: SensorImageModel, params: Array, cam_idx: NDArray[np.int64], pt_idx: NDArray[np.int64],
                  pix: Array, X: Array, n_pt: int) -> Array:
    """RMS reprojection error per point (pixels); inf where not finite."""
    with np.errstate(invalid="ignore"):
        r = model.project(params, cam_idx, X[pt_idx]) - pix
    sq = np.bincount(pt_idx, weights=np.sum(r * r, axis=1), minlength=n_pt)
    return np.where(np.isfinite(sq), sq, np.inf)


def intersect_photos(cameras: Mapping[str, SensorModel], point: ArrayLike, photo: ArrayLike, xy: ArrayLike, *,
                     ranger_camera: RangerCamera | None = None, mode: TransferMode | str = TransferMode.MONO,
                     reference: str | None = None, radius: float = DEFAULT_RADIUS,
                     max_iterations: int = 10) -> MultiRayResult:
    """Intersect points measured on several photos (module docstring), equal weights.

    Parameters
    ----------
    cameras : mapping photo id -> SensorModel
        The photos' sensor models (e.g. :func:`~lunarmap.missions.ranger.ranger_cameras`).
    point, photo : array_like (m,)
        Point id and photo id of every measurement.
    xy : array_like (m, 2)
        Photo coordinates ``(x, y)`` millimetres when ``ranger_camera`` is given, else image coordinates
        ``(line, sample)`` pixels (CSM convention).
    ranger_camera : RangerCamera, optional
        Converts photo millimetres to the cameras' pixels; ``S0`` and residuals are then in millimetres.
    mode : {"mono", "stereo"}
        Point-transfer mode; ``"stereo"`` needs ``reference``, on which every point must be measured.
    reference : str, optional
        Reference photo of a stereo transfer.
    radius : float
        Sphere for heights, metres.

    Raises
    ------
    InvalidInputError
        Unknown photos, non-finite coordinates, a stereo transfer without its reference measurement.
    UnobservedParameterError
        A point measured on fewer than two photos (named).
    """
    mode = TransferMode(mode)
    point = np.asarray(point).astype(str).ravel()
    photo = np.asarray(photo).astype(str).ravel()
    xy = np.asarray(xy, float).reshape(-1, 2)
    if not (point.size == photo.size == xy.shape[0]):
        raise InvalidInputError(f"{point.size} point ids, {photo.size} photo ids and {xy.shape[0]} coordinates")
    if not np.all(np.isfinite(xy)):
        raise InvalidInputError("measured coordinates must be finite")
    names = [str(k) for k in cameras]
    unknown = sorted(set(photo) - set(names))
    if unknown:
        raise InvalidInputError(f"measurements on photo(s) without a camera: {', '.join(unknown[:5])}")
    ids, pt_idx = np.unique(point, return_inverse=True)
    k = np.bincount(pt_idx, minlength=ids.size)
    if np.any(k < 2):
        raise UnobservedParameterError(f"{int(np.sum(k < 2))} point(s) measured on fewer than two photos "
                                       f"(first: {ids[np.argmax(k < 2)]})")
    if mode is TransferMode.STEREO:
        if reference is None or reference not in names:
            raise InvalidInputError(f"a stereo transfer needs its reference photo among the cameras, got {reference!r}")
        on_ref = np.zeros(ids.size, bool)
        on_ref[pt_idx[photo == reference]] = True
        if not on_ref.all():
            raise InvalidInputError(f"stereo transfer from {reference}: point {ids[np.argmin(on_ref)]} is not "
                                    f"measured on the reference photo")
    order = {n: i for i, n in enumerate(names)}
    cam_idx = np.array([order[p] for p in photo], np.int64)
    if ranger_camera is not None:
        line, sample = ranger_camera.photo_to_image(xy[:, 0], xy[:, 1])
        pix, scale, units = np.column_stack([line, sample]), float(ranger_camera.pixel), "mm"
    else:
        pix, scale, units = xy, 1.0, "px"
    sensors = [cameras[n] for n in names]
    model = SensorImageModel(sensors, degree=0, names=names)
    params = model.initial_params()
    c = np.empty((pix.shape[0], 3))
    d = np.empty((pix.shape[0], 3))
    for j, s in enumerate(sensors):
        m = cam_idx == j
        if m.any():
            c[m], d[m] = s.rays(pix[m, 0], pix[m, 1])
    # The paper's explicit first approximation, from each point's two rays with the longest base (with
    # Ranger's base-height ratios of 0.03 two neighbouring rays can put it kilometres off); where the
    # closed-form point nearest to all rays reprojects better, that one starts the least squares.
    a, b = _widest_pair(c, pt_idx, ids.size)
    x_paper = first_approximation(c[a], d[a], c[b], d[b])
    x_mid = model.initial_points(params, cam_idx, pt_idx, pix, ids.size)
    x0 = np.where((_reprojection(model, params, cam_idx, pt_idx, pix, x_paper, ids.size)
                   <= _reprojection(model, params, cam_idx, pt_idx, pix, x_mid, ids.size))[:, None], x_paper, x_mid)
    res = intersect_points(model, params, cam_idx, pt_idx, pix, 1.0, n_pt=ids.size, x0=x0,
                           max_iterations=max_iterations)
    computed = model.project(params, cam_idx, res.xyz[pt_idx])
    v = (pix - computed) * scale
    if ranger_camera is not None:
        v = v[:, ::-1] * np.array([1.0, -1.0])           # (line, sample) -> (x, y) = (sample, -line)
    red = (2 * res.n_rays - 3).astype(np.int64)
    s0 = res.s0 * scale
    cov_unit = res.cov_apriori / scale ** 2
    return MultiRayResult(ids, res.xyz, cov_unit * (s0 ** 2)[:, None, None], cov_unit, s0, red,
                          res.n_rays.astype(np.int64), v, mode, reference if mode is TransferMode.STEREO else None,
                          units, float(radius))
