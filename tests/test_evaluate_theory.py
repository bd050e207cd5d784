"""Eq. 15 of the LROC study (reconstructed) against closed forms and the adjustment's propagated precision."""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.errors import EvaluationInputError
from lunarmap.evaluate import (NAC_MATCHING_ERROR, MatchingErrorModel, eq15_precision, fit_matching_error,
                               pair_precision, simulate_matching_errors)

ANGLES = np.arange(5.0, 65.0, 5.0)


def test_eq15_limits_and_turning_points():
    H, f = 50e3, 99946.0
    ds = eq15_precision([1e-3], H, f, 0.3)
    th = np.radians(0.5e-3)
    B = 2 * H * np.tan(th)
    # normal case: sigma_Z = sqrt(2) (H / B) (H / f) sigma
    assert float(ds.sigma_z[0]) == pytest.approx(np.sqrt(2) * H / B * H / f * 0.3, rel=1e-9)
    assert float(ds.sigma_x[0]) == pytest.approx(H / f * 0.3 / np.sqrt(2), rel=1e-9)
    fine = np.linspace(1.0, 120.0, 11901)
    # constant matching error, no along-track term: sigma_T^2 ~ 1 / (sin^2 cos^4) turns at tan(theta) = 1/sqrt(2)
    t = eq15_precision(fine, H, f, 0.3, sigma_along_px=0.0)
    assert fine[int(np.argmin(t.sigma_t.values))] == pytest.approx(2 * np.degrees(np.arctan(1 / np.sqrt(2))), abs=0.02)
    # height error falls as a power of the convergence: log-log slope -1 at small angles
    z = eq15_precision([5.0, 10.0], H, f, 0.3).sigma_z.values
    assert np.log(z[1] / z[0]) / np.log(2.0) == pytest.approx(-1.0, abs=0.01)
    # a matching error growing with the convergence moves the turn to smaller angles (the study's Fig. 9):
    # with the simulated NAC slope (0.00425 px/deg) on a 0.1-0.3 px floor it lies between 40 and 60 deg;
    # the synthetic images' own floor (0.026 px, identical texture in both images) puts it at 28 deg
    turns = {}
    for floor in (0.1, 0.3, NAC_MATCHING_ERROR.intercept):
        m = eq15_precision(fine, H, f, MatchingErrorModel(floor, NAC_MATCHING_ERROR.slope), along="linescan")
        turns[floor] = fine[int(np.argmin(m.sigma_t.values))]
    const = eq15_precision(fine, H, f, 0.3, along="linescan").sigma_t.values
    print(f"Eq. 15 turning point: constant error {fine[int(np.argmin(const))]:.1f} deg; with the matching error "
          + ", ".join(f"floor {k:.3f} px: {v:.1f} deg" for k, v in turns.items()))
    assert 40.0 <= turns[0.1] <= turns[0.3] <= 60.0
    assert turns[NAC_MATCHING_ERROR.intercept] < turns[0.1] < fine[int(np.argmin(const))]


@pytest.mark.parametrize("kind", ["frame", "linescan"])
def test_eq15_equals_propagated_precision_of_symmetric_pairs(kind):
    ds = pair_precision(ANGLES, kind, sigma_px=0.3)
    ratios = np.stack([ds[f"ratio_{c}"].values for c in "xyzt"])
    worst = float(np.max(np.abs(ratios - 1.0)))
    print(f"{kind}: adjustment / Eq. 15 within {worst:.2%} from 5 to 60 deg")
    for c in ANGLES[[0, 5, -1]]:
        r = ds.sel(convergence=c)
        print(f"  {c:4.0f} deg  Eq.15 x/y/z/T {float(r.eq15_x):.3f} {float(r.eq15_y):.3f} {float(r.eq15_z):.3f} "
              f"{float(r.eq15_t):.3f} m   adjustment {float(r.adjust_x):.3f} {float(r.adjust_y):.3f} "
              f"{float(r.adjust_z):.3f} {float(r.adjust_t):.3f} m")
    assert worst <= 0.01          # the issue asks for 10 %; the sphere's curvature costs 0.5 % at 60 deg


def test_matching_error_model_fit_and_bad_input():
    c = np.array([0.0, 10.0, 20.0, 40.0])
    m = fit_matching_error(c, 0.03 + 0.004 * c)
    assert m.intercept == pytest.approx(0.03) and m.slope == pytest.approx(0.004)
    assert m.per_image_emission(10.0) == pytest.approx(m.per_image(20.0))
    assert m.per_coordinate(20.0) == pytest.approx(m.rms(20.0) / np.sqrt(2))
    with pytest.raises(EvaluationInputError, match="two or more"):
        fit_matching_error([10.0, 10.0], [0.1, 0.2])
    with pytest.raises(EvaluationInputError, match="convergence"):
        eq15_precision([0.0], 50e3, 1e5)
    with pytest.raises(EvaluationInputError, match="along"):
        eq15_precision([10.0], 50e3, 1e5, along="pushbroom")
    assert isinstance(NAC_MATCHING_ERROR, MatchingErrorModel)


@pytest.mark.slow
def test_matching_error_grows_with_convergence_on_rendered_pairs():
    """Two small rendered NAC-like pairs (~5 s): the matcher's error against truth is larger at 30 than at 5 degrees.

    Rendered with 2 x 2 rays per pixel: point-sampled (aliased) pixels lose more to the matcher's Gaussian
    pre-smoothing (0.28 px instead of 0.14 at 5 deg) than area-integrated ones (3 x 3 rays: 0.072 px instead of 0.054).
    """
    ds = simulate_matching_errors([5.0, 30.0], "linescan", size=240, supersample=2)
    print(ds.to_dataframe())
    assert np.all(ds.matches.values > 40)
    assert float(ds.rms[1]) > float(ds.rms[0])
    assert float(ds.rms[0]) < 0.2
    model = fit_matching_error(ds.convergence, ds.rms)
    assert model.slope > 0
