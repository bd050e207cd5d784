"""Multi-ray forward intersection: simulation with known truth (fixed, exact cameras)."""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.adjust import UnobservedParameterError
from lunarmap.adjust.intersection import intersect_points
from blockhelp import frame_case


def test_intersection_errors_match_covariance():
    sb = frame_case(orbits=3, per_orbit=8, points=3000, seed=11)
    pb = sb.problem
    o = pb.obs
    res = intersect_points(pb.model, sb.true_params, o.cam_idx, o.pt_idx, o.xy, 0.3, n_pt=pb.n_points)
    e = res.xyz - sb.true_points
    # points are independent given exact cameras: Mahalanobis with the a-priori cofactor ~ chi2(3)
    m = np.einsum("ni,nij,nj->n", e, np.linalg.inv(res.cov_apriori), e)
    assert np.mean(m) / 3 == pytest.approx(1.0, abs=0.1)
    z = (e / np.sqrt(np.diagonal(res.cov_apriori, axis1=1, axis2=2))).ravel()
    assert abs(z.mean()) < 0.1 and abs(np.sqrt(np.mean(z ** 2)) - 1) < 0.1
    # S0 (Ranger): its square has expectation 1 over many points
    assert np.mean(res.s0 ** 2) == pytest.approx(1.0, abs=0.1)


def test_intersection_needs_two_rays():
    sb = frame_case(orbits=2, per_orbit=3, points=50, seed=2)
    o = sb.problem.obs
    keep = np.ones(o.n, bool)
    keep[np.nonzero(o.pt_idx == 0)[0][1:]] = False
    with pytest.raises(UnobservedParameterError, match="point 0"):
        intersect_points(sb.problem.model, sb.true_params, o.cam_idx[keep], o.pt_idx[keep], o.xy[keep], 0.3)
