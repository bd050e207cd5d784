"""Issue 27: a final status per observation, a budget per QC run, honest ends, build_block on dirty data."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr
from qchelp import dlr_problem

from lunarmap.adjust import ControlNetwork, SolverOptions, build_block, solve
from lunarmap.adjust.qc import STATUSES, Ledger, QCOptions, quality_control
from lunarmap.adjust.qc.ending import sigma0_bounds
from lunarmap.adjust.qc.ledger import ASIDE_BEHIND
from lunarmap.errors import AdjustmentInputError, QualityControlInputError, QualityControlWarning
from lunarmap.simulate import dlr_block, frame_block, inject_blunders

OPTS = SolverOptions(ftol=1e-8)


@pytest.fixture(scope="module")
def blunder_sim():
    return inject_blunders(dlr_block(seed=0, example="blunders"), seed=1000)


@pytest.fixture(scope="module")
def qc_run(blunder_sim):
    return quality_control(dlr_problem(blunder_sim), ("sequent", "baarda"), image_group=blunder_sim.block.camera,
                           options=QCOptions(solver=OPTS))


# -- item 5: the final status ----------------------------------------------------------------------------

def test_every_observation_has_one_final_status_and_the_injected_errors_are_out(qc_run, blunder_sim, tmp_path):
    st = qc_run.report.final_status()
    pb = qc_run.ledger.base
    img = st["kind"].values == "image"
    assert set(st["status"].values) <= set(STATUSES)
    # one row per image observation, per weighted control point, per navigation row
    assert np.array_equal(np.sort(st["index"].values[img]), np.arange(pb.obs.n))
    assert int(np.sum(st["kind"].values == "control")) == int(np.sum(~pb.priors.fixed))
    assert int(np.sum(st["kind"].values == "navigation")) == pb.terms[0].n_obs_scalar
    status = st["status"].values[img]
    # what is out of the final adjustment (the ledger's weights, the backward-compatible list) is what the table
    # says is not "in"
    assert np.array_equal(np.flatnonzero(status != "in"), np.flatnonzero(~qc_run.ledger.active))
    assert np.array_equal(np.flatnonzero(status != "in"), np.sort(qc_run.removed_image_observations))
    bl = blunder_sim.blunders
    # the large image errors (500-3000 px, the simulation's truth) are out, each by a step of its own or with its point
    large = bl.image_obs[bl.image_group == 1]
    assert set(status[large]) <= {"removed", "withdrawn"}
    steps = st["step"].values[img]
    assert set(steps[large]) <= {"sequent", "baarda"}
    w_removed = img & (st["status"].values == "removed") & (st["step"].values == "baarda")
    assert np.all(st["value"].values[w_removed] > 4.0)             # a w-test removal failed its limit
    assert np.all(st["round"].values[w_removed] >= 1)
    # the control error (truth: bl.control) is down-weighted, by a failing w-test
    ctl = (st["kind"].values == "control") & (st["index"].values == bl.control[0])
    assert st["status"].values[ctl][0] == "down-weighted" and st["value"].values[ctl][0] > 4.0
    # the position error's image has a down-weighted navigation row
    nav = st["kind"].values == "navigation"
    down = nav & (st["status"].values == "down-weighted")
    assert bl.position[0] in set(st["image"].values[down])
    # qc.nc carries the table
    path = qc_run.report.write(tmp_path / "qc.nc")
    with xr.open_dataset(path) as ds:
        assert list(ds["status_status"].values.astype(str)) == [str(x) for x in st["status"].values]
        assert int(ds.attrs["clean"]) == 1
    assert "final status:" in qc_run.report.table()


def test_a_clean_run_is_clean_and_silent(qc_run):
    assert qc_run.report.clean and qc_run.report.summary["flags"] == []


# -- item 3: budget and honest ends ----------------------------------------------------------------------

def test_sigma0_bounds_are_the_chi_square_quantiles_a_simulation_finds():
    rng = np.random.default_rng(5)
    r = 400
    s0 = np.sqrt(rng.chisquare(r, 200000) / r)
    lo, hi = sigma0_bounds(r, 0.01)
    assert np.mean(s0 < lo) == pytest.approx(0.005, abs=0.0015)
    assert np.mean(s0 > hi) == pytest.approx(0.005, abs=0.0015)


def test_a_budget_of_zero_rounds_is_the_plain_adjustment_flagged(blunder_sim):
    pb = dlr_problem(blunder_sim)
    plain = solve(dlr_problem(blunder_sim), OPTS)
    with pytest.warns(QualityControlWarning, match="budget of 0"):
        qc = quality_control(pb, ("sequent", "baarda"), options=QCOptions(solver=OPTS, max_rounds=0))
    assert not qc.report.clean
    assert qc.report.summary["steps_unfinished"] == ["sequent", "baarda"]
    assert qc.result.sigma0 == pytest.approx(plain.sigma0, rel=1e-6)
    assert set(qc.report.final_status()["status"].values) == {"in"}


def test_a_budget_of_rounds_stops_the_snooping_and_says_so(blunder_sim):
    with pytest.warns(QualityControlWarning, match="budget of 3"):
        qc = quality_control(dlr_problem(blunder_sim), ("baarda",), options=QCOptions(solver=OPTS, max_rounds=3))
    assert qc.report.summary["rounds"] <= 4          # checked after each round's adjustment
    assert not qc.report.clean
    # 23 errors cannot be found in 3 rounds: large |w| or a sigma0 beyond its bound is left, and flagged
    assert any("|w|" in f or "sigma0" in f for f in qc.report.summary["flags"])
    with pytest.warns(QualityControlWarning, match="budget of 0 s"):
        quality_control(dlr_problem(blunder_sim), ("baarda",), options=QCOptions(solver=OPTS, max_seconds=0.0))


@pytest.mark.parametrize("bad", [dict(max_rounds=-1), dict(max_rounds=1.5), dict(max_seconds=-2.0),
                                 dict(max_seconds=float("nan")), dict(sigma0_alpha=0.0)])
def test_bad_budgets_are_refused(blunder_sim, bad):
    with pytest.raises(QualityControlInputError):
        quality_control(dlr_problem(blunder_sim), ("baarda",), options=QCOptions(solver=OPTS, **bad))


def test_a_block_without_redundancy_is_flagged(qc_run):
    """A block with fewer observations than unknowns is refused when it is built (InsufficientObservationsError,
    tests/test_adjust_bad_input.py); one with none to spare is flagged: nothing in it can be tested."""
    from lunarmap.adjust.qc.ending import assess

    assert not any("redundancy" in f for f in assess(qc_run.result, {}, 4.0))
    no_redundancy = type("Result", (), {"redundancy": 0, "sigma0": float("nan")})()
    assert assess(no_redundancy, {}, 4.0) == ["no redundancy left (r = 0): nothing could be tested"]


@pytest.fixture(scope="module")
def resection_block():
    """A real block with no redundancy: one image and three fixed control points, 6 observations for the
    image's 6 unknowns (the space resection, exactly determined)."""
    from blockhelp import frame_case

    from lunarmap.adjust import BundleProblem, ImageObservations, PointPriors, SensorImageModel

    pb = frame_case(orbits=2, per_orbit=5, points=120, n_control=4, seed=4).problem
    o = pb.obs
    pts = o.pt_idx[o.cam_idx == 0][:3]
    m = (o.cam_idx == 0) & np.isin(o.pt_idx, pts)
    remap = np.zeros(pb.n_points, np.int64)
    remap[pts] = np.arange(3)
    X = pb.points[pts].copy()
    return BundleProblem(SensorImageModel(pb.model.sensors[:1]), pb.cam_params[:1].copy(), X,
                         ImageObservations(o.cam_idx[m], remap[o.pt_idx[m]], o.xy[m], 0.3),
                         priors=PointPriors(np.arange(3), X.copy(), np.zeros((3, 3))))


@pytest.mark.parametrize("steps", [("baarda",), ("sequent", "baarda"), ("robust", "baarda"), ("robust",)])
def test_quality_control_of_a_real_block_without_redundancy_is_flagged(resection_block, steps):
    """Issue 27's bad input "a block with no redundancy", end to end: the block is accepted (as many
    observations as unknowns), every QC step sequence ends with a QualityControlWarning and the flag, nothing
    removed (nothing can be tested), no exception."""
    assert solve(resection_block, OPTS).redundancy == 0          # the oracle: 6 observations, 6 unknowns
    with pytest.warns(QualityControlWarning, match="no redundancy"):
        qc = quality_control(resection_block, steps, options=QCOptions(solver=OPTS))
    assert not qc.report.clean
    assert "no redundancy left (r = 0): nothing could be tested" in qc.report.summary["flags"]
    assert qc.removed_image_observations.size == 0


def test_variance_components_of_a_block_without_redundancy_are_a_named_error(resection_block):
    from lunarmap.errors import VarianceComponentError

    with pytest.raises(VarianceComponentError, match="redundancy"):
        quality_control(resection_block, ("variance",), options=QCOptions(solver=OPTS))


def test_variance_components_without_redundancy_raise_at_the_first_adjustment(resection_block, monkeypatch):
    """r = 0 at the first adjustment is r = 0 at any weights (every redundancy number of an exactly determined
    block is 0): the error comes from that adjustment, not after the round budget (it came after 60)."""
    from lunarmap.adjust import variance
    from lunarmap.errors import VarianceComponentError

    calls = []
    real = variance.solve
    monkeypatch.setattr(variance, "solve", lambda *a, **k: calls.append(1) or real(*a, **k))
    assert solve(resection_block, OPTS).redundancy == 0          # the oracle: 6 observations, 6 unknowns
    with pytest.raises(VarianceComponentError, match="redundancy 0.00"):
        variance.estimate_variance_components(resection_block, variance.observation_groups(resection_block), OPTS)
    assert len(calls) == 1


def test_a_point_behind_its_cameras_from_every_start_is_set_aside_not_fatal():
    sim = dlr_block(seed=1, example="blunders")
    pb = dlr_problem(sim)
    pb.points = 3.0 * pb.points                    # every point out beyond the orbit: behind every camera
    led = Ledger(pb)
    j = int(np.flatnonzero(~np.isin(np.arange(pb.n_points), sim.block.control))[0])
    rays = led.rays_of(j)
    led.weights.image_weight[rays] = 0.0            # no active rays to intersect it from
    fixed = led._finite(led.problem())
    x = pb.model.project(fixed.cam_params, pb.obs.cam_idx[rays], fixed.points[pb.obs.pt_idx[rays]])
    assert np.all(np.isfinite(x))                   # its start is seen by all its images
    assert led.weights.dropped_points[j]
    d = [d for d in led.decisions if d.kind == "point" and d.index == j]
    assert d and d[-1].action == "dropped" and d[-1].group == ASIDE_BEHIND


# -- item 4: build_block on dirty data -----------------------------------------------------------------------

@pytest.fixture(scope="module")
def frame_sim():
    return frame_block(orbits=2, per_orbit=5, points=120, n_control=0, seed=4)


def _network(sb, xy):
    m = sb.measurements
    names = [f"img{i:02d}" for i in range(len(sb.nav_cameras))]
    return names, ControlNetwork([f"P{j}" for j in range(sb.true_points.shape[0])],
                                 ["tie"] * sb.true_points.shape[0], np.full((sb.true_points.shape[0], 3), np.nan),
                                 m.pt_idx, m.cam_idx, xy, np.full((m.pt_idx.size, 2), m.sigma), names)


def _two_ray_point(sb):
    rays = np.bincount(sb.measurements.pt_idx)
    return int(np.flatnonzero(rays == 2)[0]) if np.any(rays == 2) else int(np.argmin(rays))


@pytest.mark.parametrize("parallax_px, reason", [(120.0, "not finite"), (20.0, "too far"),
                                                 (0.0, "impossible height")])
def test_build_block_refuses_or_best_guesses_a_point_its_rays_cannot_place(frame_sim, parallax_px, reason):
    sb = frame_sim
    m = sb.measurements
    j = _two_ray_point(sb)
    k = np.flatnonzero(m.pt_idx == j)
    xy = m.xy.copy()
    # the parallax of a 2-ray point reversed (the rays diverge) or removed (parallel rays): a line error
    xy[k[0], 0] = xy[k[1], 0] + parallax_px
    names, net = _network(sb, xy)
    sensors = dict(zip(names, sb.nav_cameras))
    with pytest.raises(AdjustmentInputError, match=f"could not be intersected.*{reason}.*best_guess"):
        build_block(sensors, net)
    blk = build_block(sensors, net, unintersectable="best_guess")
    assert list(blk.starts["point_id"].values) == [f"P{j}"]
    assert blk.starts["reason"].values[0] == reason
    X, true = blk.problem.points[j], sb.true_points[j]
    # the start is at a possible height and within a few image widths' ground distance of the truth (the
    # simulation's), not thousands of km off: 1 px is ~ 0.1 km here, the error ~ 120 px
    assert abs(np.linalg.norm(X) - net.radius) <= blk.starts.attrs["height_bound"]
    assert np.linalg.norm(X - true) < 50e3
    with pytest.raises(AdjustmentInputError, match="unintersectable"):
        build_block(sensors, net, unintersectable="ignore")


def test_build_block_best_guess_when_every_ray_of_a_point_is_wrong(frame_sim):
    sb = frame_sim
    m = sb.measurements
    rng = np.random.default_rng(3)
    j = int(np.argmax(np.bincount(m.pt_idx)))
    k = np.flatnonzero(m.pt_idx == j)
    xy = m.xy.copy()
    xy[k] = rng.uniform(50, 900, (k.size, 2))       # every ray of the point at a random pixel
    names, net = _network(sb, xy)
    sensors = dict(zip(names, sb.nav_cameras))
    blk = build_block(sensors, net, unintersectable="best_guess")
    X = blk.problem.points
    assert np.all(np.isfinite(X))
    # the clean points' starts are untouched by the option: the same as a block built from the clean rays
    clean = build_block(sensors, _network(sb, m.xy)[1])
    others = np.arange(X.shape[0]) != j
    assert np.allclose(X[others], clean.problem.points[others], rtol=0, atol=1e-6)


def test_quality_control_of_a_point_whose_rays_are_all_wrong_takes_them_out_or_says_so(frame_sim):
    """Every ray of one point at a random pixel: the block is built from its best guess, and quality control
    ends with none of those rays in, or with a flag (never a silent success, never an exception)."""
    import warnings

    from lunarmap.adjust import NavigationSpec

    sb = frame_sim
    m = sb.measurements
    rng = np.random.default_rng(7)
    j = int(np.argmax(np.bincount(m.pt_idx)))
    k = np.flatnonzero(m.pt_idx == j)
    xy = m.xy.copy()
    xy[k] = rng.uniform(20, 280, (k.size, 2))
    names, net = _network(sb, xy)
    spec = NavigationSpec(orbit=dict(zip(names, sb.orbit.tolist())), position_sigma=sb.nav_sigma[3],
                          attitude_sigma=sb.nav_sigma[0])
    blk = build_block(dict(zip(names, sb.nav_cameras)), net, navigation=spec, unintersectable="best_guess")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", QualityControlWarning)
        qc = quality_control(blk.problem, ("sequent", "baarda"), options=QCOptions(solver=OPTS))
    st = qc.report.final_status()
    img = st["kind"].values == "image"
    rays = st["status"].values[img][k]
    print("rays of the wrong point:", list(rays), "flags:", qc.report.summary["flags"])
    assert set(rays) <= {"removed", "withdrawn", "set-aside"} or (caught and not qc.report.clean)
    # the good rays are not taken with it beyond the type-I rate of the tests (truth: all other rays are good)
    others = np.setdiff1d(np.arange(m.pt_idx.size), k)
    assert np.mean(st["status"].values[img][others] != "in") < 0.05


def test_a_step_that_fails_on_the_data_ends_the_run_flagged_not_raised(blunder_sim, monkeypatch):
    """An exception of the adjustment raised inside a step (data the block accepted) ends the run on what it
    has, with the step's error in the flags and a "failed" decision; a bad setting still raises."""
    import lunarmap.adjust.qc as qcmod

    def broken(ledger, **kw):
        ledger.remove_image(0, "baarda", 1, value=9.0)
        raise AdjustmentInputError("point 14 is behind a camera from every start value tried")

    monkeypatch.setattr(qcmod, "snooping_step", broken)
    with pytest.warns(QualityControlWarning, match="a step failed on the data: baarda: AdjustmentInputError"):
        qc = quality_control(dlr_problem(blunder_sim), ("sequent", "baarda"), options=QCOptions(solver=OPTS))
    assert qc.report.summary["steps_unfinished"] == ["baarda"]
    assert any(d.kind == "step" and d.action == "failed" for d in qc.report.decisions)
    # the removal made before the failure is in the final adjustment and in the status table
    st = qc.report.final_status()
    assert st["status"].values[0] == "removed" and qc.result.state.obs_weight[0] == 0.0

    def bad_setting(ledger, **kw):
        raise QualityControlInputError("the Baarda limit must be > 0")

    monkeypatch.setattr(qcmod, "snooping_step", bad_setting)
    with pytest.raises(QualityControlInputError):
        quality_control(dlr_problem(blunder_sim), ("baarda",), options=QCOptions(solver=OPTS))


def test_auto_robust_prepass_stays_off_on_a_clean_block_and_its_removals_are_in_the_status_table():
    """A clean block fails no w-test: the auto rule does not start a robust pre-pass (its figure recorded). Forced
    on, on the blunder block, the pre-pass removals that nothing gave back are rows of the final status table with
    step "robust" and status "removed", and they are observations the simulation made wrong or are counted."""
    clean = dlr_block(seed=2, example="blunders")
    qc = quality_control(dlr_problem(clean), ("baarda",), options=QCOptions(solver=OPTS))
    d = qc.report.summary["auto_robust_start"]
    assert d["mode"] == "auto" and d["run"] is False and d["failing"] <= 2 and "steps_run" not in qc.report.summary
    assert not any(x.step == "robust" for x in qc.report.decisions)


def test_forced_robust_prepass_figures_reach_the_qc_file(blunder_sim, tmp_path):
    """The pre-pass decision (a nested summary entry) is written as flat netCDF attributes, read back equal."""
    qc = quality_control(dlr_problem(blunder_sim), ("baarda",), options=QCOptions(solver=OPTS, robust_prepass=True))
    d = qc.report.summary["auto_robust_start"]
    with xr.open_dataset(qc.report.write(tmp_path / "qc.nc")) as ds:
        assert ds.attrs["auto_robust_start_mode"] == "forced"
        assert int(ds.attrs["auto_robust_start_run"]) == 1
        assert int(ds.attrs["auto_robust_start_removed"]) == d["removed"]
        assert ds.attrs["steps_run"] == "robust, baarda"


def test_forced_robust_prepass_removals_carry_step_robust(blunder_sim):
    qc = quality_control(dlr_problem(blunder_sim), ("baarda",), options=QCOptions(solver=OPTS, robust_prepass=True))
    s = qc.report.summary
    assert s["steps_run"] == ["robust", "baarda"] and s["auto_robust_start"]["mode"] == "forced"
    st = qc.image_status()
    tab = qc.report.status
    img = tab["kind"].values == "image"
    rob = img & (tab["step"].values == "robust")
    assert s["auto_robust_start"]["removed"] == int(np.sum(rob & (tab["status"].values != "in")))
    assert rob.any() and set(tab["status"].values[rob]) <= {"removed", "set-aside"}
    assert np.all(st[tab["index"].values[rob].astype(int)] != "in")
    # the removals are the simulation's errors (large ones first): most of them wrong observations
    bad = set(blunder_sim.blunders.image_obs.tolist())
    hit = [int(i) for i in tab["index"].values[rob & (tab["status"].values == "removed")]]
    assert sum(i in bad for i in hit) >= 0.5 * len(hit)


def test_robust_prepass_setting_is_checked(blunder_sim):
    with pytest.raises(QualityControlInputError):
        quality_control(dlr_problem(blunder_sim), ("baarda",), options=QCOptions(solver=OPTS, robust_prepass="yes"))
