"""Adjustment problems of the simulated blocks of :mod:`lunarmap.simulate.blocks`, built with the public API."""

from __future__ import annotations

import numpy as np

from lunarmap.adjust import (BundleProblem, ImageObservations, NavigationObservations, PointPriors,
                             SensorImageModel, intersect_points)
from lunarmap.simulate import SimulatedBlock


def problem(sb: SimulatedBlock, model: SensorImageModel, terms: list, control: bool = True) -> BundleProblem:
    """Navigation start values (zero corrections), points intersected from the measurements, control priors."""
    m = sb.measurements
    params0 = model.initial_params()
    n_pt = sb.true_points.shape[0]
    X0 = intersect_points(model, params0, m.cam_idx, m.pt_idx, m.xy, m.sigma, n_pt=n_pt).xyz
    priors = PointPriors(sb.control, sb.control_xyz, np.full((sb.control.size, 3), sb.control_sigma)) \
        if control and sb.control.size else None
    return BundleProblem(model, params0, X0, ImageObservations(m.cam_idx, m.pt_idx, m.xy, m.sigma), priors,
                         terms=terms)


def frame_problem(sb: SimulatedBlock, offset="observed", drift="observed",
                  control: bool = True) -> tuple[BundleProblem, NavigationObservations]:
    """A :func:`~lunarmap.simulate.frame_block` with navigation observations: zero corrections observed with the
    simulated white-noise sigma, per-orbit offsets and drifts observed with the sigmas they were drawn with."""
    model = SensorImageModel(sb.nav_cameras)
    n, p = model.n_images, model.n_params
    nav = NavigationObservations(np.zeros((n, p)), np.broadcast_to(sb.nav_sigma, (n, p)), sb.orbit, sb.times,
                                 offset=offset, drift=drift, offset_sigma=sb.offset_sigma,
                                 drift_sigma=sb.drift_sigma)
    return problem(sb, model, [nav], control), nav


def linescan_problem(sb: SimulatedBlock, degree: int | None = None,
                     control: bool = True) -> tuple[BundleProblem, NavigationObservations]:
    """A :func:`~lunarmap.simulate.linescan_site` with zero-mean priors of the correction coefficients (the sigmas
    the errors were drawn with; the unsimulated position drift gets a tight prior)."""
    deg = sb.degree if degree is None else degree
    model = SensorImageModel(sb.nav_cameras, degree=deg)
    n, p = model.n_images, model.n_params
    att, pos, drift = sb.nav_sigma[0], sb.nav_sigma[3], sb.drift_sigma[0]
    t_mid = max(abs(c.t_mid) for c in model.corrections)
    t_half = max(c.t_half for c in model.corrections)
    sig = np.full(p, 1e-3)
    sig[0:3] = np.hypot(att, t_mid * drift)
    sig[3:6] = pos
    if p > 6:
        sig[6:9] = t_half * drift
        sig[9:12] = 0.05 * pos
    prior = NavigationObservations(np.zeros((n, p)), np.broadcast_to(sig, (n, p)), np.zeros(n, np.int64),
                                   name="coefficient priors")
    return problem(sb, model, [prior], control), prior


class Case:
    """A simulated block with its problem: ``problem``, ``navigation`` and the truth (``true_params``,
    ``true_points``, ``true_offsets``, ``true_drifts``, ``control``, ``check``, ``block``)."""

    def __init__(self, sb: SimulatedBlock, problem: BundleProblem, navigation: NavigationObservations):
        self.block = sb
        self.problem = problem
        self.navigation = navigation
        self.true_params = sb.true_params
        self.true_points = sb.true_points
        self.true_offsets = sb.true_offsets
        self.true_drifts = sb.true_drifts
        self.control = sb.control
        self.check = sb.check


def frame_case(offset_mode="observed", drift_mode="observed", **kwargs) -> Case:
    """:func:`~lunarmap.simulate.frame_block` (keyword arguments) and its :func:`frame_problem`."""
    from lunarmap.simulate import frame_block

    sb = frame_block(**kwargs)
    pb, nav = frame_problem(sb, offset_mode, drift_mode)
    return Case(sb, pb, nav)


def linescan_case(degree: int | None = None, **kwargs) -> Case:
    """:func:`~lunarmap.simulate.linescan_site` (keyword arguments) and its :func:`linescan_problem`."""
    from lunarmap.simulate import linescan_site

    sb = linescan_site(**kwargs)
    pb, prior = linescan_problem(sb, degree)
    return Case(sb, pb, prior)


def rfm_case(seed: int = 0, origin: str = "center", **kwargs) -> Case:
    """The LROC-like RFM block: RFMs fitted to the navigation cameras of a 7-image
    :func:`~lunarmap.simulate.linescan_site`, affine corrections per image (``seeds/001`` Eq. 13), control
    point priors; no navigation term."""
    from lunarmap.rpc import fit_rpc
    from lunarmap.simulate import linescan_site

    kw = dict(rolls=tuple(np.linspace(-20.0, 22.0, 7)), n_points=60, n_control=4, n_check=15)
    kw.update(kwargs)
    sb = linescan_site(seed=seed, **kw)
    relief = 50.0
    rfms = [fit_rpc(c, (-4 * relief - 100.0, 4 * relief + 100.0), check=False).model for c in sb.nav_cameras]
    model = SensorImageModel(rfms, corrections=[r.corrections(origin=origin) for r in rfms])
    case = Case(sb, problem(sb, model, []), None)   # type: ignore[arg-type]
    case.rfms = rfms
    return case


def check_errors(true_points, check, points, pt_cov=None) -> dict:
    """Check-point errors (metres) along-track (north), cross-track (east) and height, RMS and normalised."""
    from lunarmap.simulate import local_enu

    E = local_enu(true_points[check])[:, [1, 0, 2]]           # rows along (N), cross (E), up
    d = np.einsum("nij,nj->ni", E, points[check] - true_points[check])
    out = {"rms": np.sqrt(np.mean(d * d, axis=0)), "errors": d}
    if pt_cov is not None:
        C = np.einsum("nij,njk,nlk->nil", E, pt_cov[check], E)
        var = np.diagonal(C, axis1=1, axis2=2)
        out["expected"] = np.sqrt(np.mean(var, axis=0))
        out["z"] = d / np.sqrt(var)
    return out
