"""Jitter splines through the block API (issue 30, item 3): ``build_block(jitter=JitterSpec(...))`` puts the
spline on the chosen line-scan images and its smoothness prior in the problem as its own observation group;
the adjusted sensors carry the spline (oracle: the simulation's measurements, and the adjusted model's own
projection for the adjusted cameras)."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

import lunarmap
from lunarmap.adjust import JitterSpec, NavigationSpec, SolverOptions, build_block, observation_groups
from lunarmap.errors import AdjustmentInputError, JitterKnotSpacingError
from lunarmap.simulate import linescan_site

NAMES = ["nac0", "nac1", "nac2"]


@pytest.fixture(scope="module")
def site():
    sb = linescan_site(rolls=(-10.0, 0.0, 10.0), n_points=250, n_lines=1500, n_samples=600, sigma_px=0.05, seed=8,
                       point_extent=1.0, n_control=0, n_check=0, jitter=[(3e-6, 6.0)], jitter_images=(0, 2))
    m = sb.measurements
    ties = xr.Dataset({"point_id": ("observation", m.pt_idx), "image_id": ("observation", m.cam_idx),
                       "line": ("observation", m.xy[:, 0]), "sample": ("observation", m.xy[:, 1]),
                       "sigma_line": ("observation", np.full(m.pt_idx.size, m.sigma)),
                       "sigma_sample": ("observation", np.full(m.pt_idx.size, m.sigma))},
                      coords={"image": NAMES})
    spec = NavigationSpec(orbit={n: n for n in NAMES}, position_sigma=sb.nav_sigma[3], attitude_sigma=1e-4,
                          position_rate_sigma=1.0, attitude_rate_sigma=1e-4)
    return sb, ties, spec


def test_block_with_jitter_splines(site):
    sb, ties, spec = site
    sensors = dict(zip(NAMES, sb.nav_cameras))
    plain = build_block(sensors, ties, navigation=spec)
    block = lunarmap.build_block(sensors, ties, navigation=spec,
                                 jitter=lunarmap.JitterSpec(knot_lines=75.0, sigma=2e-6, zero_sigma=1e-5,
                                                            images=["nac0", "nac2"]))
    spl = [c.jitter_lines for c in block.model.corrections]
    assert spl == [75.0, None, 75.0] and block.jitter is not None and block.jitter.images == [0, 2]
    assert "jitter smoothness" in observation_groups(block.problem).names
    b0 = lunarmap.solve(plain, SolverOptions(ftol=1e-10))
    b1 = lunarmap.solve(block, SolverOptions(ftol=1e-10))
    assert b0.converged and b1.converged
    r0, r1 = b0.result, b1.result
    # 3 urad at 10 urad a pixel: the polynomial leaves ~0.2 px; the spline goes back to the 0.05 px noise
    assert r0.rms_px() > 2.5 * r1.rms_px() and r1.rms_px() < 1.2 * 0.05 * np.sqrt(2)
    # the adjusted cameras carry the spline: they project as the adjusted model does
    adjusted = list(b1.adjusted_sensors().values())
    o = block.problem.obs
    X = r1.points[o.pt_idx]
    for i in (0, 2):
        m = o.cam_idx == i
        li, sa = adjusted[i].ground_to_image(X[m], within_image=False)
        want = block.model.project(r1.cam_params, o.cam_idx[m], X[m])
        assert np.max(np.abs(np.column_stack([li, sa]) - want)) < 1e-4


def test_jitter_spec_errors(site):
    sb, ties, spec = site
    sensors = dict(zip(NAMES, sb.nav_cameras))
    with pytest.raises(AdjustmentInputError, match="not in the block"):
        build_block(sensors, ties, navigation=spec, jitter=JitterSpec(100.0, 2e-6, images=["nac9"]))
    with pytest.raises(JitterKnotSpacingError):
        build_block(sensors, ties, navigation=spec, jitter=JitterSpec(0.25, 2e-6))
    with pytest.raises(AdjustmentInputError):
        build_block(sensors, ties, navigation=spec, jitter=JitterSpec(100.0, -1.0))
