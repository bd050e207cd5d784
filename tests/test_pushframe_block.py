"""A push-frame (WAC-like) block adjusted with navigation observations (issue 26).

Two adjacent polar orbits, two WAC-UV-like push-frame images each (the images of an orbit follow
each other); the navigation cameras carry position, attitude and rate errors as degree-1 push-frame
corrections; the points are measured in the true cameras (0.2 px). The adjustment must reach the
noise (sigma0 ~ 1), bring the cameras to the truth and agree with its own posterior sigma.
``bench/wac_block.py`` is the same block with rendered images and matched tie points.

The framelets leave small gaps (1 s between framelets of 1.54 km at 1.61 km/s), as the WAC's even and
odd framelet images do (ISIS and ALE split a WAC image in two for that reason): where framelets overlap,
a ground point is imaged twice and the model gives it to one framelet (usgscsm's rule), so a point
measured in the other has a residual of up to the overlap and the cost jumps where the choice flips.
"""

from __future__ import annotations

import numpy as np

import lunarmap
from lunarmap.adjust import ControlNetwork, NavigationSpec
from lunarmap.simulate.blocks import observe
from lunarmap.simulate.orbits import wac_like_camera

FRAMELETS, DELAY = 40, 1.0


def test_corrected_projection_is_the_corrected_cameras():
    """PushFrameCorrections.project(p) == corrections.apply(p).ground_to_image, framelet choice included."""
    rng = np.random.default_rng(5)
    cam = wac_like_camera(30.0, 10.0, 0.0, FRAMELETS, 0.9)          # overlapping framelets: choices matter
    corr = cam.corrections(degree=1)
    X = cam.image_to_ground(rng.uniform(0, 4 * FRAMELETS, 400), rng.uniform(0, 128, 400), height=0.0)
    for k in range(corr.n_params):
        p = np.zeros(corr.n_params)
        p[k] = 5e-3 if k % 6 < 3 else 1000.0
        moved = np.column_stack(corr.apply(p).ground_to_image(X, within_image=False))
        assert np.nanmax(np.abs(corr.project(p, X) - moved)) < 1e-6, corr.names[k]


def test_push_frame_block_with_navigation_reaches_the_noise():
    rng = np.random.default_rng(3)
    names = [f"orbit{o}_img{k}" for o in (0, 1) for k in (0, 1)]
    truth = [wac_like_camera(30.0 + 0.45 * o, 10.0, (k - 0.5) * 0.95 * FRAMELETS * DELAY, FRAMELETS, DELAY)
             for o in (0, 1) for k in (0, 1)]
    # the flipped framelets join into a continuous image: ground north increases with the line
    lat = np.degrees(np.arcsin(truth[0].image_to_ground(np.arange(0.25, 12, 0.5), np.full(24, 64.0),
                                                        height=0.0)[:, 2] / 1737400.0))
    assert np.all(np.diff(lat) > 0)
    t_half = 0.5 * (FRAMELETS - 1) * DELAY
    nav = []
    for cam in truth:
        p = np.concatenate([rng.normal(0, 5e-3, 3), rng.normal(0, 1000.0, 3), rng.normal(0, 5e-4, 3),
                            rng.normal(0, 50.0, 3)])
        nav.append(cam.corrections(degree=1).apply(-p))
    seeds = np.concatenate([cam.image_to_ground(rng.uniform(1, 4 * FRAMELETS - 1, 150), rng.uniform(2, 126, 150),
                                                height=rng.uniform(-2e3, 2e3, 150)) for cam in truth])
    seen = np.array([np.isfinite(cam.ground_to_image(seeds)[0]) for cam in truth])
    X = seeds[seen[:2].any(axis=0) & seen[2:].any(axis=0)]           # seen from both orbits
    X = X[rng.permutation(X.shape[0])]                                 # control and check all over the block
    meas, X, _ = observe(truth, X, 0.2, rng)
    n = X.shape[0]
    kind = np.full(n, "tie", dtype=object)
    kind[:12], kind[12:42] = "control", "check"
    cov = np.full((n, 3, 3), np.nan)
    cov[:12] = np.eye(3) * 1.0
    net = ControlNetwork(point_id=[f"p{i}" for i in range(n)], point_type=kind, xyz=X, measure_point=meas.pt_idx,
                         measure_image=meas.cam_idx, line_sample=meas.xy, measure_sigma=0.2, image_id=names,
                         xyz_cov=cov)
    spec = NavigationSpec(orbit={nm: nm[:6] for nm in names}, position_sigma=1000.0, attitude_sigma=5e-3,
                          position_rate_sigma=50.0 / t_half, attitude_rate_sigma=5e-4 / t_half)
    block = lunarmap.build_block(dict(zip(names, nav)), net, degree=1, navigation=spec)
    result = lunarmap.solve(block)
    before = result.check_points(points=block.problem.points).attrs
    after = result.check_points().attrs
    assert result.converged
    assert 0.75 < result.sigma0 < 1.25
    assert np.all(after["rms_m"] < 0.75 * before["rms_m"])     # both are mostly the 0.2 px measuring noise
    assert 0.5 < after["normalized_rms"] < 1.6

    # the adjusted cameras image the true points where the true cameras do (pixels)
    def pixel_rms(cams):
        d = [np.column_stack(c.ground_to_image(X, within_image=False)) -
             np.column_stack(t.ground_to_image(X, within_image=False)) for c, t in zip(cams, truth)]
        return float(np.sqrt(np.nanmean(np.concatenate(d) ** 2)))

    adjusted = result.adjusted_sensors()
    rms_nav, rms_adj = pixel_rms(nav), pixel_rms([adjusted[nm] for nm in names])
    assert rms_adj < 0.3 * rms_nav and rms_adj < 0.4, (rms_nav, rms_adj)
