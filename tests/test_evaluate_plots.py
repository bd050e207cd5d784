"""Figures of lunarmap.evaluate.plots written as files (Agg, no pyplot), and the missing-matplotlib error."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import xarray as xr

from lunarmap.errors import EvaluationInputError, MissingDependencyError
from lunarmap.evaluate import (NAC_MATCHING_ERROR, evaluate_combinations, pair_geometry, pair_precision,
                               plot_error_vs_convergence, plot_footprints, plot_matching_error, plot_pair_quantity,
                               plot_precision_vs_convergence, plot_precision_vs_images, power_law_fit,
                               progressive_selection, site_network)
from lunarmap.simulate import APOLLO11_LIKE, lroc_site

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def site():
    s = lroc_site(APOLLO11_LIKE[:4], n_tie=20, n_control=4, n_check=8, sigma_px=0.2, seed=5)
    return s, site_network(s)


def _png(path):
    data = path.read_bytes()
    assert data[:8] == PNG and len(data) > 5000
    return data


def test_all_figures_written(site, tmp_path):
    s, net = site
    table = evaluate_combinations(s.true_cameras, net, mode="intersect")
    pairs = pair_geometry(s.true_cameras)
    prog = progressive_selection(s.true_cameras, net, table=table, mode="intersect")
    errors = xr.Dataset({"rms": ("convergence", [0.05, 0.1, 0.2])}, coords={"convergence": [0.0, 20.0, 40.0]})
    figs = {
        "fig3.png": lambda p: plot_error_vs_convergence(table, pairs, path=p),
        "fig7.png": lambda p: plot_matching_error(errors, NAC_MATCHING_ERROR, path=p),
        "fig9.png": lambda p: plot_precision_vs_convergence(50e3, 99946.0, 0.3, NAC_MATCHING_ERROR,
                                                            adjusted=pair_precision([10.0, 30.0, 50.0], "linescan"),
                                                            path=p),
        "fig4.png": lambda p: plot_pair_quantity(pairs, np.linspace(0.9, 0.7, pairs.sizes["pair"]), path=p),
        "fig5.png": lambda p: plot_pair_quantity(pairs, pairs.convergence, "aspect_ratio_ratio", "convergence", path=p),
        "fig10.png": lambda p: plot_precision_vs_images(prog, path=p),
        "footprints.pdf": lambda p: plot_footprints(s.true_cameras, ["A1", "A3"], points=s.true_xyz, path=p),
    }
    for name, make in figs.items():
        fig = make(tmp_path / name)
        assert fig.axes, name
        if name.endswith(".png"):
            _png(tmp_path / name)
        else:
            assert (tmp_path / name).read_bytes()[:4] == b"%PDF"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(figs)      # no temporary files left


def test_power_law_and_bad_input(site):
    a, b = power_law_fit([1.0, 2.0, 4.0], [8.0, 4.0, 2.0])
    assert a == pytest.approx(8.0) and b == pytest.approx(-1.0)
    s, _ = site
    pairs = pair_geometry(s.true_cameras)
    with pytest.raises(EvaluationInputError, match="no 'phase_ratio'"):
        plot_pair_quantity(pairs, np.zeros(pairs.sizes["pair"]), "phase_ratio")
    with pytest.raises(EvaluationInputError, match="values for"):
        plot_pair_quantity(pairs, [1.0, 2.0])
    with pytest.raises(EvaluationInputError, match="no sensor model"):
        plot_footprints(s.true_cameras, ["A1", "Q"])


def test_missing_matplotlib_is_named(monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)
    with pytest.raises(MissingDependencyError, match="lunarmap\\[plot\\]"):
        plot_matching_error(xr.Dataset({"rms": ("convergence", [0.1])}, coords={"convergence": [1.0]}))
