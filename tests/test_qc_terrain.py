"""Quality control of reference-DTM heights (issue 30 item 1, issue 27 item 5) on a simulated frame block with a
reference DTM of known error (the simulator's true terrain plus 3 m white node noise), against the simulation's
truth: a DTM height 50 m off at one tie point (a fake fresh crater) is found and named as a terrain observation of
its DTM's group, a DTM row whose point is out of the adjustment goes out with it, and the chain variance ->
baarda recovers the DTM's variance component."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from blockhelp import frame_problem

from lunarmap.adjust import ReferenceDtm, SolverOptions, dtm_heights
from lunarmap.adjust.normal import term_residuals
from lunarmap.adjust.qc import Ledger, QCOptions, final_status, quality_control, w_tests
from lunarmap.adjust.terrain import point_height
from lunarmap.simulate import frame_block, frame_block_height, reference_dtm

R_MOON = 1737400.0
NOISE = 3.0             # white noise per DTM node, metres (interpolated: 2/3 of it, SimulatedDtm.sigma_m)
SPACING = 20.0          # DTM node spacing, metres
CRATER_M = 50.0         # the fake crater: the DTM 50 m below the terrain within CRATER_RADIUS of one tie point
CRATER_RADIUS = 60.0    # metres: every node of the point's cell is in it
START = 1.0             # the DTM's a-priori sigma is START x the truth
LIMIT = 4.0
DTM_NAME = "lola"
OPTS = SolverOptions(ftol=1e-8)


@pytest.fixture(scope="module")
def block():
    """Two tilted frame cameras (+-20 deg) on 3 orbits at 20 km (5 m pixels): tie heights to ~2 m, like the DTM's."""
    sb = frame_block(orbits=3, per_orbit=6, points=300, n_control=8, n_check=0, altitude=20e3, cameras=2,
                     tilt_deg=(-20, 20), seed=1)
    pb, _ = frame_problem(sb)
    tie = np.ones(pb.n_points, bool)
    tie[sb.control] = False
    return sb, pb, tie


def _dtm_problem(block, path, crater: int | None):
    """The block with a reference DTM term (name DTM_NAME) written to ``path``; ``crater``: the point whose DTM
    height is CRATER_M too low."""
    sb, pb, tie = block
    lon, lat, _, _ = point_height(sb.true_points, R_MOON)

    def height(lo, la):
        h = frame_block_height(lo, la)
        if crater is None:
            return h
        d = np.hypot(np.radians(lo - lon[crater]) * R_MOON * np.cos(np.radians(lat[crater])),
                     np.radians(la - lat[crater]) * R_MOON)
        return h - CRATER_M * (d < CRATER_RADIUS)

    m = 0.01
    sim = reference_dtm(path, height, (lon.min() - m, lon.max() + m), (lat.min() - m, lat.max() + m), SPACING,
                        noise_sigma=NOISE, seed=5)
    ref = ReferenceDtm(str(path), START * sim.sigma_m, name=DTM_NAME, slope_baseline_m=5 * SPACING)
    term = dtm_heights(ref, pb.points, pb.model.n_images * pb.model.n_params, pb.model.n_images, tie)
    return dataclasses.replace(pb, terms=list(pb.terms) + [term]), term, sim


def _chain(pb):
    return quality_control(pb, ["variance", "baarda"], image_group=None,
                           options=QCOptions(solver=OPTS, baarda=dict(limit=LIMIT), variance=dict(on_weak="keep")))


@pytest.fixture(scope="module")
def crater_run(block, tmp_path_factory):
    _, _, tie = block
    j = int(np.flatnonzero(tie)[10])
    pb, term, sim = _dtm_problem(block, tmp_path_factory.mktemp("crater") / "crater.tif", j)
    row = int(np.flatnonzero(term.point_index == j)[0])
    return {"qc": _chain(pb), "point": j, "row": row, "term": len(pb.terms) - 1, "dtm": term, "sim": sim}


@pytest.fixture(scope="module")
def clean_run(block, tmp_path_factory):
    pb, term, sim = _dtm_problem(block, tmp_path_factory.mktemp("clean") / "clean.tif", None)
    return {"qc": _chain(pb), "term": len(pb.terms) - 1, "dtm": term, "sim": sim}


def _terrain_rows(st, t):
    return st["term"].values == t


def test_the_crater_row_is_a_terrain_observation_of_its_dtm_and_down_weighted(block, crater_run):
    sb = block[0]
    qc, t, row, j = crater_run["qc"], crater_run["term"], crater_run["row"], crater_run["point"]
    # the simulation's truth: the DTM is CRATER_M below the true point there, within its noise elsewhere
    r_true = crater_run["dtm"].residuals_m(sb.true_points)
    assert abs(r_true[row] - CRATER_M) < 4 * crater_run["sim"].sigma_m
    st = qc.report.final_status()
    terr = _terrain_rows(st, t)
    # every row of the DTM term is a terrain row named by its point, none a navigation row
    assert set(st["kind"].values[terr]) == {"terrain"}
    assert np.array_equal(st["point"].values[terr], crater_run["dtm"].point_index)
    assert np.array_equal(st["index"].values[terr], np.arange(crater_run["dtm"].n_obs_scalar))
    assert int(np.sum(st["kind"].values == "navigation")) == qc.ledger.terms[0].n_obs_scalar
    k = np.flatnonzero(terr & (st["index"].values == row))[0]
    assert st["status"].values[k] == "down-weighted" and st["step"].values[k] == "baarda"
    assert DTM_NAME in st["reason"].values[k] and st["round"].values[k] >= 1
    # found by a failing w-test of its own: the first decision on it
    first = next(d for d in qc.report.decisions if d.term == t and d.index == row)
    assert first.kind == "terrain" and first.point == j and abs(first.value) > LIMIT
    # and the point kept its images' height, not the DTM's (truth: the crater is in the DTM only)
    _, _, h_adj, _ = point_height(qc.result.points[j], R_MOON)
    _, _, h_true, _ = point_height(sb.true_points[j], R_MOON)
    assert abs(float(h_adj[0] - h_true[0])) < 0.2 * CRATER_M
    print("crater row: first |w|", abs(first.value), "round", first.round, "final status", st["status"].values[k],
          st["reason"].values[k], "; point height error", float(h_adj[0] - h_true[0]), "m")


def test_a_dtm_row_of_a_point_out_of_the_adjustment_is_out_with_it(block, crater_run):
    """The crater point's rays all removed but one (it is dropped), another point withdrawn: their DTM rows are
    not tested and end set-aside / withdrawn with the deciding step, not flagged."""
    sb, pb0, tie = block
    pb = dataclasses.replace(pb0, terms=list(pb0.terms) + [crater_run["dtm"]])
    t, row, j = crater_run["term"], crater_run["row"], crater_run["point"]
    led = Ledger(pb)
    led.adjust(OPTS)
    before = w_tests(led)["terms"][t]
    assert abs(before[row]) > LIMIT                  # in the adjustment, the crater fails its test
    rays = led.rays_of(j)
    led.remove_image(rays[1:], "sequent", 0)         # one ray left: the point is dropped with it
    assert led.weights.dropped_points[j]
    j2 = int(crater_run["dtm"].point_index[row + 1])
    row2 = row + 1
    led.withdraw_point(j2, "baarda", 3, value=1.0, why="test")
    led.adjust(OPTS)
    tests = w_tests(led, limit=LIMIT)
    assert np.isnan(tests["terms"][t][row]) and np.isnan(tests["terms"][t][row2])
    # the other DTM rows are still tested
    assert np.isfinite(tests["terms"][t]).sum() >= crater_run["dtm"].n_obs_scalar - 2 - 10
    st = final_status(led)
    terr = _terrain_rows(st, t)
    k = np.flatnonzero(terr & (st["index"].values == row))[0]
    k2 = np.flatnonzero(terr & (st["index"].values == row2))[0]
    assert (st["status"].values[k], st["step"].values[k], st["point"].values[k]) == ("set-aside", "sequent", j)
    assert (st["status"].values[k2], st["step"].values[k2], st["round"].values[k2]) == ("withdrawn", "baarda", 3)
    # it weighs nothing: its whitened residual in the final adjustment is ~0, though the point (held where the first
    # adjustment left it, halfway to the crater's floor) is still LIMIT DTM sigmas and more above the DTM there
    res = led.result
    rx = term_residuals(res.problem.terms[t], res.cam_params, res._term_extra(t), res.points)
    assert abs(crater_run["dtm"].residuals_m(res.points)[row]) > LIMIT * crater_run["sim"].sigma_m
    assert abs(rx[row]) < 1e-3 and abs(rx[row2]) < 1e-3


def test_variance_then_baarda_recovers_the_dtm_component_and_finds_the_crater(block, clean_run, crater_run):
    clean, qc = clean_run["qc"], crater_run["qc"]
    truth = clean_run["sim"].sigma_m                       # 2/3 of the node noise
    vc = clean.variance
    g = vc.names.index(DTM_NAME)
    assert vc.estimated[g]
    # the estimated sigma of one DTM height within 2 sigma of the truth (from a start START x off)
    est, sd = START * truth * vc.scale[g], START * truth * vc.scale_sigma[g]
    assert abs(est - truth) < 2.0 * sd and sd < 0.1 * truth
    for run, t in ((clean, clean_run["term"]), (qc, crater_run["term"])):
        w = run.ledger.weights
        k = run.variance.names.index(DTM_NAME)
        # the variance step's fix: every row of the group carries the group's component, and a row given back by
        # the snooping returns to it (not to its a-priori sigma); only rows still down-weighted are above it
        np.testing.assert_allclose(w.term_vc[t], run.variance.scale[k], rtol=1e-6)
        down = w.term_downweighted(t)
        np.testing.assert_allclose(w.term_sigma[t][~down], w.term_vc[t][~down], rtol=1e-12)
    assert any(d.kind == "terrain" and d.action == "reinstated" for d in qc.report.decisions)
    st_c, st = clean.report.final_status(), qc.report.final_status()
    for run, s, t in ((clean, st_c, clean_run["term"]), (qc, st, crater_run["term"])):
        # a DTM row is out only with its point (a type-I withdrawal of the snooping takes the point's row along)
        terr = _terrain_rows(s, t)
        with_point = run.ledger.weights.dropped_points[s["point"].values[terr]]
        assert set(s["status"].values[terr][with_point]) <= {"withdrawn", "set-aside"}
        assert set(s["status"].values[terr][~with_point]) <= {"in", "down-weighted"}
    # the clean block: no DTM row down-weighted; the crater block: the crater's row only
    terr_c, terr = _terrain_rows(st_c, clean_run["term"]), _terrain_rows(st, crater_run["term"])
    assert not np.any(st_c["status"].values[terr_c] == "down-weighted")
    assert list(st["index"].values[terr & (st["status"].values == "down-weighted")]) == [crater_run["row"]]
    # no good image observation out beyond the clean block's (its type-I share: the same images and noise)
    img_c, img = st_c["kind"].values == "image", st["kind"].values == "image"
    out_c = int(np.sum(st_c["status"].values[img_c] != "in"))
    out = int(np.sum(st["status"].values[img] != "in"))
    assert out <= out_c
    print("clean: DTM sigma", est, "+-", sd, "truth", truth, "images out", out_c, "; crater: images out", out,
          "DTM scale", qc.variance.scale[qc.variance.names.index(DTM_NAME)])

