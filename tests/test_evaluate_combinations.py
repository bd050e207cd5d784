"""Image combinations of a simulated site: exhaustive table, progressive selection, dask, skips."""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.errors import EvaluationInputError
from lunarmap.evaluate import (NAC_MATCHING_ERROR, best_combinations, compare_with_exhaustive, evaluate_combination,
                               evaluate_combinations, pair_geometry, progressive_selection, site_network,
                               subset_network)
from lunarmap.rpc import fit_rpc
from lunarmap.simulate import APOLLO11_LIKE, lroc_site


@pytest.fixture(scope="module")
def case():
    """Five images of the Apollo-11-like site, RFMs of the navigation cameras (the study's RFM + affine block)."""
    site = lroc_site(APOLLO11_LIKE[:5], n_tie=40, n_control=5, n_check=12,
                     sigma_px=NAC_MATCHING_ERROR.per_image_emission, seed=2)
    rfms = {n: fit_rpc(c, (-300.0, 300.0), check=False).model for n, c in site.nav_cameras.items()}
    return site, site_network(site), rfms


@pytest.fixture(scope="module")
def table(case):
    site, net, rfms = case
    return evaluate_combinations(rfms, net)


def test_exhaustive_table(case, table):
    site, net, _ = case
    assert table.sizes["combination"] == 26            # C(5,2) + C(5,3) + C(5,4) + C(5,5)
    assert np.all(table.status.values == "ok")
    assert set(np.unique(table.k.values)) == {2, 3, 4, 5}
    assert np.all(table.n_check.values == 12) and np.all(np.isfinite(table.overall.values))
    np.testing.assert_allclose(table.overall.values, np.sqrt(table.along ** 2 + table.cross ** 2 + table.height ** 2))
    # the pairs' height error against their convergence: the best pair is not a small-angle one
    pairs = table.where(table.k == 2, drop=True)
    geo = pair_geometry(site.true_cameras)
    conv = geo.convergence.sel(pair=[c.replace("+", "/") for c in pairs.combination.values]).values
    best = int(np.argmin(pairs.overall.values))
    print(best_combinations(table, 1)[["along", "cross", "height", "overall"]].to_dataframe().round(3))
    assert conv[best] > 10.0
    assert pairs.height.values[np.argmin(conv)] > np.median(pairs.height.values)


def test_progressive_selection_equals_table_lookup_and_is_near_the_optimum(case, table):
    site, net, rfms = case
    prog = progressive_selection(rfms, net)                    # evaluates its own candidates
    looked = progressive_selection(rfms, net, table=table)    # looks them up
    assert list(prog.combination.values) == list(looked.combination.values)
    np.testing.assert_allclose(prog.overall.values, looked.overall.values)
    assert prog.attrs["candidates"] == 10 + 3 + 2 + 1 and looked.attrs["candidates"] == 0
    cmp = compare_with_exhaustive(prog, table)
    print(cmp.to_dataframe())
    assert cmp.excess.values[0] == 0.0                          # the best pair is the exhaustive best pair
    assert np.all(cmp.excess.values <= 0.05)
    assert prog.attrs["stop_k"] in prog.step.values and prog.attrs["best_k"] in prog.step.values


def test_dask_threads_equal_serial(case, table):
    site, net, rfms = case
    par = evaluate_combinations(rfms, net, k=[2, 5], scheduler="threads")
    sel = table.sel(combination=par.combination.values)
    np.testing.assert_allclose(par.overall.values, sel.overall.values, rtol=1e-9)


def test_intersect_mode_through_true_cameras(case):
    site, net, _ = case
    t = evaluate_combinations(site.true_cameras, net, k=[2, 3], mode="intersect")
    assert np.all(t.status.values == "ok")
    assert 0.4 < float(np.sqrt(np.mean(t.normalized_rms.values ** 2))) < 1.6


def test_bad_input_and_skips(case):
    site, net, rfms = case
    with pytest.raises(EvaluationInputError, match="two or more"):
        evaluate_combination(["A1"], rfms, net)
    with pytest.raises(EvaluationInputError, match="no sensor model"):
        evaluate_combination(["A1", "Z9"], rfms, net)
    with pytest.raises(EvaluationInputError, match="between 2 and 5"):
        evaluate_combinations(rfms, net, k=[1])
    with pytest.raises(EvaluationInputError, match="at least two images"):
        evaluate_combinations({"A1": rfms["A1"]}, net)
    # a network whose check points are measured only in A1 (moved out of the other images): skipped, not raised
    bad = subset_network(net, site.names)[0]
    chk = np.isin(bad.measure_point, np.flatnonzero(bad.point_type == "check")) & (bad.measure_image > 0)
    keep = ~chk
    from lunarmap.adjust import ControlNetwork
    thin = ControlNetwork(point_id=bad.point_id, point_type=bad.point_type, xyz=bad.xyz,
                          measure_point=bad.measure_point[keep], measure_image=bad.measure_image[keep],
                          line_sample=bad.line_sample[keep], measure_sigma=bad.measure_sigma[keep],
                          image_id=bad.image_id, xyz_cov=bad.xyz_cov)
    row = evaluate_combination(["A1", "A2"], rfms, thin)
    assert row["status"].startswith("skipped: CheckPointError") and np.isnan(row["overall"])
    sub, dropped = subset_network(thin, ["A1", "A2"])
    assert len(dropped) == 12 and "1 ray(s)" in dropped[0]
