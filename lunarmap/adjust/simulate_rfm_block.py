"""Synthetic LROC-like multi-image RFM block over one site (for tests and demos).

Set-up (after the LROC multi-image study, ``seeds/001``: seven NAC images of one landing site
at different look angles, RFM + affine block adjustment, control and check points):

* ``n_images`` NAC-like line-scan cameras (:mod:`lunarmap.testing.cameras`) on polar,
  north-bound orbits at ``altitude``, rolled by ``rolls`` (degrees) and shifted in longitude
  so that every image is centred on the site;
* the "navigation" cameras: the true cameras with a constant position error (``pos_sigma``
  metres per axis), an attitude bias (``att_sigma`` radians per axis) and an attitude drift
  (``att_drift_sigma`` radians per second), as from noisy orbit and pointing knowledge;
* one RFM per image fitted (:func:`lunarmap.rpc.fit_rpc`) to the navigation camera: these are
  the RFMs the adjustment starts from;
* ground points on smooth terrain (``relief`` metres) inside the common footprint, measured in
  every image that sees them by the TRUE camera plus white noise of ``sigma_px`` pixels;
* control points (truth + ``control_sigma`` metres per axis) near the corners of the point
  cloud, check points (measured like tie points, their truth held back) among the rest.

Along-track is north and cross-track is east (polar north-bound orbits).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..camera import LineScanCamera, Shape
from ..camera.geodesy import lonlat_height_to_xyz, xyz_to_lonlat_height
from ..errors import SimulationWarning, warn
from ..orientation.exterior import ExteriorOrientation
from ..orientation.rotation import matrix_to_quat, quat_to_matrix
from ..rpc import fit_rpc
from ..testing.cameras import NAC_LINE_TIME, nac_like_interior, polar_orbit_eo
from .intersection import intersect_points
from .problem import BundleProblem, ImageObservations, PointPriors
from .rfm_affine import AffineRFMModel
from .rotation import rotvec_to_matrix

__all__ = ["SimulatedRfmBlock", "simulate_rfm_block", "local_enu", "check_point_errors"]


@dataclass
class SimulatedRfmBlock:
    """The adjustment problem (initial points intersected with the navigation RFMs) and its truth.

    Attributes
    ----------
    problem : BundleProblem
        ``AffineRFMModel`` over the navigation RFMs, zero initial corrections.
    rfms : list of RationalFunctionModel
    true_points : (n_pt, 3) metres, body-fixed
    control, check : int arrays
        Indices of the control points (with priors) and of the check points (tie points whose
        truth is only used for evaluation).
    rolls : (n_img,) degrees
    site : (lon, lat) degrees
    """

    problem: BundleProblem
    rfms: list
    true_points: NDArray
    control: NDArray
    check: NDArray
    rolls: NDArray
    site: tuple


def local_enu(xyz: NDArray) -> NDArray[np.float64]:
    """Rows east, north, up (unit vectors) at body-fixed points ``(..., 3)``: ``(..., 3, 3)``."""
    lon, lat, _ = xyz_to_lonlat_height(xyz)
    lon, lat = np.radians(lon), np.radians(lat)
    cl, sl, co, so = np.cos(lat), np.sin(lat), np.cos(lon), np.sin(lon)
    east = np.stack([-so, co, np.zeros_like(lat)], -1)
    north = np.stack([-sl * co, -sl * so, cl], -1)
    up = np.stack([cl * co, cl * so, sl], -1)
    return np.stack([east, north, up], axis=-2)


def _camera(lon_orbit, lat, roll, altitude, n_lines, n_samples, dpos=None, datt=None, ddrift=None, k1=1.81e-5):
    eo = polar_orbit_eo(lat_center=lat, lon=lon_orbit, altitude=altitude, half_span=2.0 + n_lines * NAC_LINE_TIME,
                        step=0.05, roll_deg=roll)
    if dpos is not None:
        # sensor-frame attitude error exp([bias + t drift]x): applied on the sensor side of sensor->body
        M = quat_to_matrix(eo.quaternions)
        E = rotvec_to_matrix(datt[None, :] + eo.times[:, None] * ddrift[None, :])
        eo = ExteriorOrientation(epoch=eo.epoch, times=eo.times, positions=eo.positions + dpos,
                                 velocities=eo.velocities, quaternions=matrix_to_quat(M @ E),
                                 sun_times=eo.sun_times, sun_positions=eo.sun_positions,
                                 attrs={**eo.attrs, "perturbed": 1})
    return LineScanCamera(nac_like_interior(n_lines=n_lines, n_samples=n_samples, k1=k1), eo, Shape.moon(),
                          line_times=(-n_lines * NAC_LINE_TIME / 2.0, NAC_LINE_TIME))


def _terrain(lon, lat, site, relief):
    # smooth hills of a few hundred metres wavelength (the footprint is ~1 km)
    x = np.radians(lon - site[0]) * 1737.4e3 * np.cos(np.radians(site[1]))
    y = np.radians(lat - site[1]) * 1737.4e3
    return relief * (0.6 * np.sin(x / 210.0 + 0.3) * np.cos(y / 330.0) + 0.4 * np.sin((x + y) / 500.0))


def simulate_rfm_block(n_images: int = 7, rolls=None, n_points: int = 60, n_control: int = 4, n_check: int = 15,
                       sigma_px: float = 0.3, n_lines: int = 3000, n_samples: int = 1500,
                       altitude: float = 50e3, site: tuple = (30.0, 20.0), pos_sigma: float = 20.0,
                       att_sigma: float = 50e-6, att_drift_sigma: float = 20e-6, control_sigma: float = 0.3,
                       relief: float = 50.0, origin: str = "center", seed: int = 0) -> SimulatedRfmBlock:
    """Simulate the block (see the module docstring).

    Parameters
    ----------
    rolls : (n_images,) degrees, optional
        Look angles across track; by default evenly spread over -20 .. +22 degrees.
    sigma_px : float
        Image measurement noise, pixels.
    pos_sigma, att_sigma, att_drift_sigma : float
        Navigation errors: metres, radians, radians per second (per axis, constant per image).
    control_sigma : float
        Control point noise and prior sigma, metres per axis.
    relief : float
        Terrain amplitude, metres.
    """
    rng = np.random.default_rng(seed)
    rolls = np.linspace(-20.0, 22.0, n_images) if rolls is None else np.asarray(rolls, float)
    lon0, lat0 = site
    cams_true, rfms = [], []
    for roll in rolls:
        lon_o = lon0
        for _ in range(3):   # shift the orbit until the centre pixel looks at the site
            g = _camera(lon_o, lat0, roll, altitude, n_lines, n_samples).image_to_ground(
                n_lines / 2, n_samples / 2, 0.0)
            lon_o -= xyz_to_lonlat_height(g)[0] - lon0
        cams_true.append(_camera(lon_o, lat0, roll, altitude, n_lines, n_samples))
        nav = _camera(lon_o, lat0, roll, altitude, n_lines, n_samples, rng.normal(0, pos_sigma, 3),
                      rng.normal(0, att_sigma, 3), rng.normal(0, att_drift_sigma, 3))
        rfms.append(fit_rpc(nav, (-4 * relief - 100.0, 4 * relief + 100.0), check=False).model)

    # points: uniform in the inner footprint, kept if seen by >= 2 images (most are seen by all)
    X = _site_points(rng, site, 0.4, n_points, n_lines, n_samples, altitude, relief)
    cam_idx, pt_idx, xy, X = _observe(cams_true, X, n_points, sigma_px, rng)
    if X.shape[0] < n_points:
        warn(f"only {X.shape[0]} of {n_points} points are seen by 2 or more images", SimulationWarning)
    # control: the points nearest the four corners (and centre) of the cloud; check: random others
    control, check, priors = _control_and_check(X, n_control, n_check, control_sigma, rng, with_centre=True)

    model = AffineRFMModel(rfms, origin=origin)
    params0 = model.initial_params()
    X0 = intersect_points(model, params0, cam_idx, pt_idx, xy, sigma_px, n_pt=X.shape[0]).xyz
    problem = BundleProblem(model, params0, X0, ImageObservations(cam_idx, pt_idx, xy, sigma_px), priors)
    return SimulatedRfmBlock(problem, rfms, X, control, check, rolls, (lon0, lat0))


def check_point_errors(block: SimulatedRfmBlock, points: NDArray, pt_cov: NDArray | None = None) -> dict:
    """Check-point errors of estimated ``points (n_pt, 3)`` (metres) in along-track/cross-track/height.

    Returns a dict with ``rms`` ``(3,)`` metres (along = north, cross = east, height = up) and, when
    the posterior point covariances ``pt_cov (n_pt, 3, 3)`` (m^2) are given, ``expected`` ``(3,)``:
    the RMS a noise-only adjustment should show, ``sqrt(mean sigma^2)`` per component, and ``z``
    ``(n_check, 3)``, the errors divided by their sigma.
    """
    c = block.check
    E = local_enu(block.true_points[c])[:, [1, 0, 2]]           # rows along (N), cross (E), up
    d = np.einsum("nij,nj->ni", E, points[c] - block.true_points[c])
    out = {"rms": np.sqrt(np.mean(d * d, axis=0)), "errors": d}
    if pt_cov is not None:
        C = np.einsum("nij,njk,nlk->nil", E, pt_cov[c], E)
        var = np.diagonal(C, axis1=1, axis2=2)
        out["expected"] = np.sqrt(np.mean(var, axis=0))
        out["z"] = d / np.sqrt(var)
    return out


def _site_points(rng: np.random.Generator, site: tuple[float, float], frac: float, n_points: int, n_lines: int,
                 n_samples: int, altitude: float, relief: float) -> NDArray:
    """``4 n_points`` candidate ground points (metres, body-fixed) uniform in the central ``frac`` of the footprint."""
    lon0, lat0 = site
    half = frac * min(n_lines, n_samples) * 0.5 * altitude * 0.007 / 699.62 / 1737.4e3 * 180 / np.pi
    m = 4 * n_points
    lon = lon0 + rng.uniform(-half, half, m) / np.cos(np.radians(lat0))
    lat = lat0 + rng.uniform(-half, half, m) * n_lines / min(n_lines, n_samples)
    return lonlat_height_to_xyz(lon, lat, _terrain(lon, lat, site, relief))


def _observe(cams, X: NDArray, n_points: int, sigma_px: float, rng: np.random.Generator):
    """Noisy image observations of the first ``n_points`` candidates seen by >= 2 cameras.

    Returns ``cam_idx, pt_idx, xy`` (pixels, with Gaussian noise ``sigma_px``) and the kept points.
    """
    m = X.shape[0]
    ci, pi, xy = [], [], []
    for i, cam in enumerate(cams):
        li, sa = cam.ground_to_image(X, on_miss="nan")
        ok = np.isfinite(li) & np.isfinite(sa)
        ci.append(np.full(ok.sum(), i))
        pi.append(np.nonzero(ok)[0])
        xy.append(np.column_stack([li[ok], sa[ok]]))
    ci, pi, xy = np.concatenate(ci), np.concatenate(pi), np.concatenate(xy)
    keep = np.nonzero(np.bincount(pi, minlength=m) >= 2)[0][:n_points]
    remap = -np.ones(m, np.int64)
    remap[keep] = np.arange(keep.size)
    sel = remap[pi] >= 0
    return ci[sel], remap[pi[sel]], xy[sel] + rng.normal(0.0, sigma_px, (sel.sum(), 2)), X[keep]


def _control_and_check(X: NDArray, n_control: int, n_check: int, control_sigma: float, rng: np.random.Generator,
                       with_centre: bool):
    """Control points nearest the cloud's corners (and centre), random check points, and the control priors."""
    enu = local_enu(X.mean(axis=0))
    e, nn = (X - X.mean(axis=0)) @ enu[0], (X - X.mean(axis=0)) @ enu[1]
    picks = [np.argmin(e + nn), np.argmax(e + nn), np.argmin(e - nn), np.argmax(e - nn)]
    if with_centre:
        picks.append(np.argmin(np.hypot(e, nn)))
    control = np.unique(np.array(picks[:n_control], np.int64))
    rest = np.setdiff1d(np.arange(X.shape[0]), control)
    check = np.sort(rng.choice(rest, size=min(n_check, rest.size), replace=False))
    priors = PointPriors(control, X[control] + rng.normal(0.0, control_sigma, (control.size, 3)),
                         np.full((control.size, 3), control_sigma)) if control.size else None
    return control, check, priors
