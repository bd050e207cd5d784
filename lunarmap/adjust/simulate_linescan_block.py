"""Synthetic line-scan block for :class:`~lunarmap.adjust.linescan_poly.LineScanPolyModel` (tests, demos).

Same site geometry as :mod:`lunarmap.adjust.simulate_rfm_block` (NAC-like cameras on polar orbits,
rolled to look at one site), distortion-free.  The navigation cameras carry a constant position
error ``dpos`` (``pos_sigma`` metres per axis), an attitude bias ``datt`` (``att_sigma`` radians) and
an attitude drift ``ddrift`` (``att_drift_sigma`` radians per second), applied on the sensor side:
``R_nav(t) = R_true(t) exp([datt + t ddrift]x)``.  The polynomial model of degree >= 1 represents
this exactly: ``w_0 = datt + t_mid ddrift``, ``w_1 = t_half ddrift``, ``c_0 = -dpos`` (see
:meth:`SimulatedLineScanBlock.true_params`), so the truth of the image parameters is known.

The parameters get zero-mean pseudo-observations (a :class:`NavigationObservations` term) with the
sigmas the errors were drawn with: the matching stochastic model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..camera.geodesy import xyz_to_lonlat_height
from ..errors import AdjustmentInputError
from .intersection import intersect_points
from .linescan_poly import LineScanPolyModel
from .navigation import NavigationObservations
from .problem import BundleProblem, ImageObservations
from .simulate_rfm_block import _camera, _control_and_check, _observe, _site_points

__all__ = ["SimulatedLineScanBlock", "simulate_linescan_block"]


@dataclass
class SimulatedLineScanBlock:
    """Problem (reference = navigation cameras, zero initial corrections) and truth."""

    problem: BundleProblem
    prior: NavigationObservations
    true_params: NDArray          # (n_img, n_params)
    true_points: NDArray          # (n_pt, 3) metres
    control: NDArray
    check: NDArray
    true_cameras: list


def simulate_linescan_block(rolls=(-15.0, 0.0, 15.0), degree: int = 1, n_points: int = 40, n_control: int = 4,
                            n_check: int = 10, sigma_px: float = 0.3, n_lines: int = 3000, n_samples: int = 1500,
                            altitude: float = 50e3, site: tuple = (30.0, 20.0), pos_sigma: float = 20.0,
                            att_sigma: float = 50e-6, att_drift_sigma: float = 20e-6, control_sigma: float = 0.3,
                            relief: float = 50.0, seed: int = 0) -> SimulatedLineScanBlock:
    """Simulate the block (metres, radians, seconds, pixels); see the module docstring."""
    if degree < 1:
        raise AdjustmentInputError("the simulated attitude drift needs a polynomial degree >= 1")
    rng = np.random.default_rng(seed)
    lon0, lat0 = site
    true_cams, nav_cams, truth = [], [], []
    for roll in rolls:
        lon_o = lon0
        for _ in range(3):
            g = _camera(lon_o, lat0, roll, altitude, n_lines, n_samples, k1=None).image_to_ground(
                n_lines / 2, n_samples / 2, 0.0)
            lon_o -= xyz_to_lonlat_height(g)[0] - lon0
        dpos, datt, ddrift = (rng.normal(0, s, 3) for s in (pos_sigma, att_sigma, att_drift_sigma))
        true_cams.append(_camera(lon_o, lat0, roll, altitude, n_lines, n_samples, k1=None))
        nav_cams.append(_camera(lon_o, lat0, roll, altitude, n_lines, n_samples, dpos, datt, ddrift, k1=None))
        truth.append((dpos, datt, ddrift))
    model = LineScanPolyModel(nav_cams, degree)
    true_params = np.zeros((len(rolls), model.n_params))
    for i, (dpos, datt, ddrift) in enumerate(truth):
        true_params[i, 0:3] = datt + model._t_mid[i] * ddrift
        true_params[i, 3:6] = -dpos
        true_params[i, 6:9] = model._t_half[i] * ddrift

    X = _site_points(rng, site, 0.35, n_points, n_lines, n_samples, altitude, relief)
    cam_idx, pt_idx, xy, X = _observe(true_cams, X, n_points, sigma_px, rng)
    control, check, priors = _control_and_check(X, n_control, n_check, control_sigma, rng, with_centre=False)

    # a-priori sigmas of the coefficients: those the errors were drawn with (higher terms: small)
    n_img = len(rolls)
    sig = np.full(model.n_params, 1e-3)
    sig[0:3] = np.hypot(att_sigma, np.max(np.abs(model._t_mid)) * att_drift_sigma)
    sig[3:6] = pos_sigma
    sig[6:9] = np.max(model._t_half) * att_drift_sigma
    sig[9:12] = 0.05 * pos_sigma             # no position drift simulated: a tight prior
    prior = NavigationObservations(np.zeros((n_img, model.n_params)), np.broadcast_to(sig, (n_img, model.n_params)),
                                   np.zeros(n_img, np.int64), name="coefficient priors")
    params0 = model.initial_params()
    x0 = intersect_points(model, params0, cam_idx, pt_idx, xy, sigma_px, n_pt=X.shape[0]).xyz
    problem = BundleProblem(model, params0, x0, ImageObservations(cam_idx, pt_idx, xy, sigma_px), priors,
                            terms=[prior])
    return SimulatedLineScanBlock(problem, prior, true_params, X, control, check, true_cams)

