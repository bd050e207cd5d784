"""Check points: errors of adjusted or triangulated points against reference coordinates.

Errors are split two ways, per point and as RMS, each next to the sigma the adjustment (or the
forward intersection) predicts for the same point:

* along-track, cross-track and height (the study's Tables 4-6): the along-track axis is the
  horizontal direction of the images' ground tracks (the principal axis of the sensors' horizontal
  velocities, so ascending and descending images agree), cross-track is 90 degrees clockwise from
  it (to the right of a northbound track), height is up;
* east (longitude), north (latitude) and up, in metres, plus the latitude and longitude errors in
  degrees.

The overall error of a table row is ``sqrt(rms_along^2 + rms_cross^2 + rms_height^2)`` (the study's
"overall precision"). :func:`block_check_errors` takes a solved
:class:`~lunarmap.adjust.BlockResult` (it supersedes ``BlockResult.check_points``, which gives
east/north/up only); :func:`triangulate` intersects measured points through any sensor models
(for instance the adjusted ones) with their a-priori covariance.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np
import xarray as xr
from numpy.typing import ArrayLike, NDArray

from ..adjust.block import BlockResult
from ..adjust.intersection import intersect_points
from ..adjust.sensors import SensorImageModel
from ..camera.geodesy import enu_basis, xyz_to_lonlat_height
from ..camera.sensor import SensorModel
from ..camera.shape import MOON_RADIUS
from ..errors import CheckPointError, EvaluationInputError

__all__ = ["along_track_azimuth", "track_basis", "check_point_errors", "block_check_errors", "triangulate",
           "Triangulation", "TRACK", "ENU"]

Array = NDArray[np.float64]
TRACK = ["along", "cross", "height"]
ENU = ["east", "north", "up"]


def along_track_azimuth(sensors: Mapping[str, Any] | Sequence[Any], at: ArrayLike) -> float | None:
    """Azimuth (degrees clockwise from north) of the images' ground-track axis at a ground point.

    The principal axis of the horizontal components of the sensors' unit velocities at their centre
    times, oriented to point north (or east when exactly east-west). ``None`` when no sensor has an
    exterior orientation (RFMs).
    """
    items = list(sensors.values()) if isinstance(sensors, Mapping) else list(sensors)
    at = np.asarray(at, float).reshape(3)
    lon, lat, _ = xyz_to_lonlat_height(at)
    E = enu_basis(lon, lat)
    vs = []
    for s in items:
        eo = getattr(s, "eo", None)
        if eo is None or not hasattr(s, "center_time"):
            continue
        v = eo.velocity_at(float(s.center_time) - eo.epoch)
        h = E[:2] @ v
        if np.linalg.norm(h) > 0:
            vs.append(h / np.linalg.norm(h))
    if not vs:
        return None
    V = np.array(vs)
    w, U = np.linalg.eigh(V.T @ V)
    axis = U[:, -1]                                            # (east, north)
    if axis[1] < 0 or (axis[1] == 0 and axis[0] < 0):
        axis = -axis
    return float(np.degrees(np.arctan2(axis[0], axis[1])) % 360.0)


def track_basis(xyz: ArrayLike, azimuth_deg: float) -> Array:
    """Rows along-track, cross-track, up (unit vectors, body-fixed) at points ``(..., 3)``: ``(..., 3, 3)``."""
    lon, lat, _ = xyz_to_lonlat_height(np.asarray(xyz, float))
    E = enu_basis(lon, lat)
    a = np.radians(azimuth_deg)
    along = np.sin(a) * E[..., 0, :] + np.cos(a) * E[..., 1, :]
    cross = np.cos(a) * E[..., 0, :] - np.sin(a) * E[..., 1, :]
    return np.stack([along, cross, E[..., 2, :]], axis=-2)


def check_point_errors(estimated: ArrayLike, reference: ArrayLike, covariance: ArrayLike | None = None, *,
                       names: Sequence[str] | NDArray | None = None, along_track: float | None = None,
                       sensors: Mapping[str, Any] | Sequence[Any] | None = None,
                       radius: float = MOON_RADIUS, skipped: Sequence[str] = ()) -> xr.Dataset:
    """Errors of estimated points against reference coordinates (see the module docstring).

    Parameters
    ----------
    estimated, reference : array_like (n, 3)
        Body-fixed metres.
    covariance : array_like (n, 3, 3), optional
        Covariance of the estimated points, m^2 (their predicted precision).
    names : sequence of str, optional
        Point names.
    along_track : float, optional
        Along-track azimuth, degrees clockwise from north; default from ``sensors``
        (:func:`along_track_azimuth`), else north.
    sensors : mapping or sequence of SensorModel, optional
        For the default along-track direction.
    radius : float
        Reference sphere of the heights, metres.
    skipped : sequence of str
        Points left out upstream, with the reason (kept in ``attrs["skipped"]``).

    Returns
    -------
    xarray.Dataset
        ``error``, ``sigma``, ``normalized`` over (``check``, ``component`` = along/cross/height),
        metres; ``error_enu``, ``sigma_enu`` over (``check``, ``enu``); ``error_lat``, ``error_lon``
        (degrees); attributes ``rms`` (along, cross, height), ``rms_enu``, ``overall_rms``,
        ``expected_rms`` (RMS of the predicted sigma), ``normalized_rms``, ``along_track_azimuth``,
        ``n_check``, ``skipped``.
    """
    X = np.asarray(estimated, float).reshape(-1, 3)
    R = np.asarray(reference, float).reshape(-1, 3)
    if X.shape != R.shape:
        raise EvaluationInputError(f"{X.shape[0]} estimated points for {R.shape[0]} reference points")
    if X.shape[0] == 0:
        raise CheckPointError("no check point to evaluate" + (f" ({'; '.join(skipped)})" if skipped else ""))
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(R))):
        raise EvaluationInputError("check points must have finite estimated and reference coordinates")
    names = [f"check{i}" for i in range(X.shape[0])] if names is None else [str(n) for n in names]
    if len(names) != X.shape[0]:
        raise EvaluationInputError(f"{len(names)} names for {X.shape[0]} check points")
    source = "given"
    if along_track is None:
        along_track = along_track_azimuth(sensors, R.mean(axis=0)) if sensors is not None else None
        source = "sensors" if along_track is not None else "north (no sensor velocities)"
    az = 0.0 if along_track is None else float(along_track)
    T = track_basis(R, az)
    lon, lat, _ = xyz_to_lonlat_height(R, radius)
    E = enu_basis(lon, lat)
    d = X - R
    err = np.einsum("kij,kj->ki", T, d)
    err_enu = np.einsum("kij,kj->ki", E, d)
    if covariance is not None:
        C = np.asarray(covariance, float).reshape(-1, 3, 3)
        sig = np.sqrt(np.diagonal(np.einsum("kij,kjl,kml->kim", T, C, T), axis1=1, axis2=2))
        sig_enu = np.sqrt(np.diagonal(np.einsum("kij,kjl,kml->kim", E, C, E), axis1=1, axis2=2))
    else:
        sig = sig_enu = np.full_like(err, np.nan)
    lon_e, lat_e, _ = xyz_to_lonlat_height(X, radius)
    z = err / sig
    rms = np.sqrt(np.mean(err ** 2, axis=0))
    return xr.Dataset(
        {"error": (("check", "component"), err, {"units": "m"}),
         "sigma": (("check", "component"), sig, {"units": "m"}),
         "normalized": (("check", "component"), z),
         "error_enu": (("check", "enu"), err_enu, {"units": "m"}),
         "sigma_enu": (("check", "enu"), sig_enu, {"units": "m"}),
         "error_lat": ("check", lat_e - lat, {"units": "degree"}),
         "error_lon": ("check", (lon_e - lon + 180.0) % 360.0 - 180.0, {"units": "degree"})},
        coords={"check": np.array(names, dtype=object), "component": TRACK, "enu": ENU},
        attrs={"rms": rms, "rms_enu": np.sqrt(np.mean(err_enu ** 2, axis=0)),
               "overall_rms": float(np.sqrt(np.sum(rms ** 2))),
               "expected_rms": np.sqrt(np.mean(sig ** 2, axis=0)),
               "normalized_rms": float(np.sqrt(np.mean(z ** 2))) if covariance is not None else float("nan"),
               "along_track_azimuth": az, "along_track_source": source,
               "n_check": int(X.shape[0]), "skipped": list(skipped)})


def block_check_errors(result: BlockResult, points: ArrayLike | None = None,
                       along_track: float | None = None) -> xr.Dataset:
    """Check-point errors of a solved block (along/cross/height and east/north/up, with posterior sigma).

    Parameters
    ----------
    result : BlockResult
    points : array_like (n_points, 3), optional
        Coordinates to evaluate instead of the adjusted points (e.g. the start values, for the
        errors before the adjustment); the sigma stays the adjustment's.
    along_track : float, optional
        Degrees clockwise from north; default from the block's sensors.

    Raises
    ------
    CheckPointError
        The block has no check points.
    """
    if not isinstance(result, BlockResult):
        raise EvaluationInputError(f"expected a BlockResult, got {type(result).__name__}")
    net = result.block.network
    c = np.flatnonzero(net.point_type == "check")
    if c.size == 0:
        raise CheckPointError("the block has no check points")
    X = result.result.points if points is None else np.asarray(points, float)
    cov = result.result.precision().pt_cov[c]
    return check_point_errors(X[c], net.xyz[c], cov, names=net.point_id[c], along_track=along_track,
                              sensors=result.block.sensors, radius=net.radius)


@dataclass
class Triangulation:
    """Points intersected from their image measurements.

    Attributes
    ----------
    point_id : ndarray of str
        The points triangulated (those with >= 2 rays inside the images).
    xyz : ndarray (n, 3)
        Body-fixed metres.
    covariance : ndarray (n, 3, 3)
        A-priori covariance from the measurement sigmas (m^2).
    n_rays : ndarray (n,)
    skipped : list of str
        Points left out, with the reason.
    """

    point_id: NDArray
    xyz: Array
    covariance: Array
    n_rays: NDArray[np.int64]
    skipped: list[str] = field(default_factory=list)


def triangulate(sensors: Mapping[str, SensorModel], measurements: xr.Dataset,
                images: Sequence[str] | None = None) -> Triangulation:
    """Forward-intersect measured points through sensor models (e.g. the adjusted cameras).

    Parameters
    ----------
    sensors : mapping image name -> SensorModel
    measurements : xarray.Dataset
        :func:`~lunarmap.simulate.block_check_points` layout: ``point_id``, ``image_id`` (index
        into the ``image`` coordinate), ``line``, ``sample`` and optionally ``sigma_line`` /
        ``sigma_sample`` per observation (default 1 pixel); points are named by the ``point``
        coordinate when there is one, else by their index.
    images : sequence of str, optional
        Use only these images' measurements (default: every image that has a sensor).

    Returns
    -------
    Triangulation
        Measurements outside their image (or NaN) are dropped; points left with fewer than two
        rays are listed in ``skipped``.

    Raises
    ------
    EvaluationInputError
        Unknown image names, a dataset without the needed variables.
    CheckPointError
        No point has two rays.
    """
    need = ("point_id", "image_id", "line", "sample")
    missing = [k for k in need if k not in measurements]
    if missing or "image" not in measurements.coords:
        raise EvaluationInputError(f"measurements lack {missing or ['the image coordinate']}")
    img_names = [str(v) for v in measurements["image"].values]
    use = list(img_names if images is None else images)
    unknown = [n for n in use if n not in sensors]
    if images is not None and (unknown or not use):
        raise EvaluationInputError(f"no sensor model for image(s) {unknown or 'none given'}; "
                                   f"have {list(sensors)}")
    use = [n for n in use if n in sensors and n in img_names]
    if len(use) < 2:
        raise EvaluationInputError(f"triangulation needs at least two images with measurements, got {use}")
    pid = np.asarray(measurements["point_id"].values, np.int64)
    iid = np.asarray(measurements["image_id"].values, np.int64)
    line = np.asarray(measurements["line"].values, float)
    sample = np.asarray(measurements["sample"].values, float)
    sl = np.asarray(measurements["sigma_line"].values, float) if "sigma_line" in measurements else np.ones_like(line)
    ss = np.asarray(measurements["sigma_sample"].values, float) if "sigma_sample" in measurements else np.ones_like(line)
    n_pt = int(measurements.sizes["point"]) if "point" in measurements.dims else int(pid.max()) + 1
    names = ([str(v) for v in measurements["point"].values] if "point" in measurements.coords
             else [f"point{i}" for i in range(n_pt)])
    order = {n: k for k, n in enumerate(use)}
    model = SensorImageModel([sensors[n] for n in use], degree=0, names=use)
    cam = np.array([order.get(img_names[i], -1) for i in iid], np.int64)
    ok = cam >= 0
    for n, k in order.items():
        s = sensors[n]
        m = cam == k
        ok[m] &= (np.isfinite(line[m]) & np.isfinite(sample[m]) & (line[m] >= 0) & (line[m] <= s.n_lines)
                  & (sample[m] >= 0) & (sample[m] <= s.n_samples))
    rays = np.bincount(pid[ok], minlength=n_pt)
    good = rays >= 2
    skipped = [f"{names[i]}: {int(rays[i])} ray(s) inside the images {use}" for i in np.flatnonzero(~good)]
    if not good.any():
        raise CheckPointError(f"no point has two rays inside the images {use}" +
                              (f" ({'; '.join(skipped[:3])} ...)" if skipped else ""))
    remap = -np.ones(n_pt, np.int64)
    remap[good] = np.arange(int(good.sum()))
    sel = ok & good[pid]
    res = intersect_points(model, model.initial_params(), cam[sel], remap[pid[sel]],
                           np.column_stack([line[sel], sample[sel]]), np.column_stack([sl[sel], ss[sel]]),
                           n_pt=int(good.sum()))
    return Triangulation(np.array(names, dtype=object)[good], res.xyz, res.cov_apriori, res.n_rays, skipped)
