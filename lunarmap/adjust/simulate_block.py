"""Synthetic Clementine-like frame-camera block with navigation errors (for tests and demos).

Geometry (the DLR paper's simulation set-up, ``seeds/004`` Section on simulations, with a
Clementine-UVVIS-like camera: 384 x 288 pixels of 23 um, f = 90 mm): several parallel
north-bound orbits at ``altitude`` over a spherical Moon, nadir looking, 60 % forward and
30 % side overlap; ground points on a smooth random terrain; image noise ``sigma_px``.

Navigation data = truth corrupted by a per-orbit offset ``c_o`` and drift ``d_o`` (per unit of
time ``s`` in seconds) and white noise of ``nav_sigma``, for positions (metres) and attitude
(radians, as the rotation vector of the attitude correction relative to the navigation
attitude, which is the reference attitude ``R0`` of the image model).  Control points are
truth + noise of ``control_sigma`` metres.

The offsets and drifts are drawn per orbit from ``N(0, offset_*)`` and ``N(0, drift_*)``; the
matching stochastic model is ``"observed"`` offsets/drifts with those sigmas (the default).
``"free"`` for both the attitude and the position parameters is ill-posed in practice (see
:mod:`lunarmap.adjust.navigation`): the estimator then leaves the linear regime and its errors
no longer follow the linearised covariance.  Per-parameter modes (a sequence of 6) allow the DLR
paper's practice of freeing only some offsets, e.g. ``("fixed",) * 3 + ("free",) * 3`` with
``offset_att = drift_att = 0``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..camera.shape import MOON_RADIUS
from .collinearity import FrameModel, project_frame
from .intersection import intersect_points
from .navigation import NavigationObservations
from .problem import BundleProblem, ImageObservations, PointPriors
from .rotation import matrix_to_rotvec, rotvec_to_matrix

__all__ = ["SimulatedBlock", "simulate_frame_block"]


@dataclass
class SimulatedBlock:
    """A simulated block: the adjustment problem plus the truth it was made from (SI units)."""

    problem: BundleProblem
    navigation: NavigationObservations
    true_params: NDArray        # (n_img, 6) [w (rad), C (m)] relative to the model's R0
    true_points: NDArray        # (n_pt, 3) m, body-fixed
    true_offsets: NDArray       # (n_orb, 6)
    true_drifts: NDArray        # (n_orb, 6) per second
    control: NDArray            # indices of control points


def _enu(lat, lon):
    cl, sl, co, so = np.cos(lat), np.sin(lat), np.cos(lon), np.sin(lon)
    up = np.stack([cl * co, cl * so, sl], -1)
    east = np.stack([-so, co, np.zeros_like(lat)], -1)
    north = np.stack([-sl * co, -sl * so, cl], -1)
    return east, north, up


def simulate_frame_block(orbits: int = 4, per_orbit: int = 12, points: int = 1500, n_control: int = 4,
                         sigma_px: float = 0.3, altitude: float = 400e3, focal_mm: float = 90.0,
                         pitch_um: float = 23.0, width: int = 384, height: int = 288,
                         nav_sigma_pos: float = 10.0, nav_sigma_att: float = np.radians(0.001),
                         offset_pos: float = 100.0, offset_att: float = np.radians(0.01),
                         drift_pos: float = 0.5, drift_att: float = np.radians(0.0002),
                         control_sigma: float = 5.0, relief: float = 2000.0, speed: float = 1600.0,
                         offset_mode="observed", drift_mode="observed", seed: int = 0) -> SimulatedBlock:
    """Simulate the block; returns the adjustment problem (initial values from navigation) and truth.

    Lengths in metres, angles in radians, ``drift_*`` per second, ``speed`` ground speed m/s.
    ``offset_mode``, ``drift_mode``: one of "fixed", "free", "observed" or a sequence of 6
    (``[w_x, w_y, w_z, C_x, C_y, C_z]``); "observed" uses ``offset_*`` / ``drift_*`` as sigmas.
    The initial points are multi-ray intersections with the navigation orientation.
    """
    rng = np.random.default_rng(seed)
    f_px = focal_mm / (pitch_um * 1e-3)
    R = MOON_RADIUS
    gsd = altitude / f_px
    base = 0.4 * height * gsd
    strip = 0.7 * width * gsd
    lats = (np.arange(per_orbit) - (per_orbit - 1) / 2) * base / R
    lons = (np.arange(orbits) - (orbits - 1) / 2) * strip / R
    LON, LAT = np.meshgrid(lons, lats, indexing="ij")
    LAT, LON = LAT.ravel(), LON.ravel()
    n = LAT.size
    orbit = np.repeat(np.arange(orbits), per_orbit)
    t = np.tile(np.arange(per_orbit) * base / speed, orbits)
    t = t - t.reshape(orbits, per_orbit).mean(axis=1)[orbit]   # s centred per orbit
    east, north, up = _enu(LAT, LON)
    C_true = (R + altitude + rng.normal(0, 500.0, n))[:, None] * up
    R_nadir = np.stack([east, north, up], axis=1)              # body -> camera (x east, y north, z up)
    R_true = rotvec_to_matrix(rng.normal(0, np.radians(0.05), (n, 3))) @ R_nadir

    # navigation = truth - (offset + s drift + noise) so that truth = nav + offset + s drift + noise
    off = np.column_stack([rng.normal(0, offset_att, (orbits, 3)), rng.normal(0, offset_pos, (orbits, 3))])
    dr = np.column_stack([rng.normal(0, drift_att, (orbits, 3)), rng.normal(0, drift_pos, (orbits, 3))])
    nav_sig = np.array([nav_sigma_att] * 3 + [nav_sigma_pos] * 3)
    err = off[orbit] + t[:, None] * dr[orbit] + rng.normal(0, 1, (n, 6)) * nav_sig
    C_nav = C_true - err[:, 3:6]
    R_nav = rotvec_to_matrix(-err[:, 0:3]) @ R_true            # R_true = exp(err_w) R_nav (first order)
    w_true = matrix_to_rotvec(R_true @ np.transpose(R_nav, (0, 2, 1)))
    true_params = np.column_stack([w_true, C_true])
    model = FrameModel(R_nav, f_px)

    # ground points: uniform over the block, smooth terrain
    margin = 0.5 * np.hypot(width, height) * gsd / R
    plat = rng.uniform(lats.min() - margin, lats.max() + margin, 6 * points)
    plon = rng.uniform(lons.min() - margin, lons.max() + margin, 6 * points)
    _, _, pup = _enu(plat, plon)
    h = relief * (0.5 * np.sin(plat * R / 37e3 + 1.0) * np.cos(plon * R / 53e3) + 0.2 * np.sin(plon * R / 11e3))
    X = (R + h)[:, None] * pup
    # visibility of every point in every image (blocks are small: dense test is fine)
    ci, pi = np.meshgrid(np.arange(n), np.arange(X.shape[0]), indexing="ij")
    ci, pi = ci.ravel(), pi.ravel()
    x = project_frame(true_params[ci, 0:3], R_nav[ci], C_true[ci], np.full(ci.size, f_px), 0.0, 0.0, X[pi])
    P_z = np.einsum("nij,nj->ni", R_true[ci], X[pi] - C_true[ci])[:, 2]
    vis = (P_z < 0) & (np.abs(x[:, 0]) <= width / 2) & (np.abs(x[:, 1]) <= height / 2)
    cnt = np.bincount(pi[vis], minlength=X.shape[0])
    keep = np.nonzero(cnt >= 2)[0][:points]
    remap = -np.ones(X.shape[0], np.int64)
    remap[keep] = np.arange(keep.size)
    sel = vis & (remap[pi] >= 0)
    cam_idx, pt_idx, xy_true = ci[sel], remap[pi[sel]], x[sel]
    X = X[keep]
    xy = xy_true + rng.normal(0, sigma_px, xy_true.shape)

    # control points: well-observed points spread over the block (extreme corners + centre)
    track = np.bincount(pt_idx, minlength=X.shape[0])
    cand = np.nonzero(track >= 3)[0]
    e = np.einsum("ni,i->n", X[cand], east[0])
    nn = np.einsum("ni,i->n", X[cand], north[0])
    picks = [np.argmin(e + nn), np.argmax(e + nn), np.argmin(e - nn), np.argmax(e - nn),
             np.argmin(np.hypot(e - e.mean(), nn - nn.mean()))]
    control = np.unique(cand[np.array(picks[:max(n_control, 0)], dtype=np.int64)]) if n_control else \
        np.zeros(0, np.int64)
    priors = None
    if control.size:
        priors = PointPriors(control, X[control] + rng.normal(0, control_sigma, (control.size, 3)),
                             np.full((control.size, 3), control_sigma))

    off_sig = np.array([offset_att] * 3 + [offset_pos] * 3)
    dr_sig = np.array([drift_att] * 3 + [drift_pos] * 3)
    nav = NavigationObservations(np.column_stack([np.zeros((n, 3)), C_nav]), np.broadcast_to(nav_sig, (n, 6)),
                                 orbit, t, offset=offset_mode, drift=drift_mode,
                                 offset_sigma=off_sig, drift_sigma=dr_sig)
    params0 = np.column_stack([np.zeros((n, 3)), C_nav])
    X0 = intersect_points(model, params0, cam_idx, pt_idx, xy, sigma_px, n_pt=X.shape[0]).xyz
    problem = BundleProblem(model, params0, X0, ImageObservations(cam_idx, pt_idx, xy, sigma_px), priors,
                            terms=[nav])
    return SimulatedBlock(problem, nav, true_params, X, off, dr, control)
