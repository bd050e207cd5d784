"""Laser altimetry (LOLA-like tracks) as observations in the block adjustment (issue 30, item 2): the shot
table reader's named errors, the observation's partials against central differences, and a block without
control points whose navigation has per-orbit errors, adjusted with simulated tracks, against the
simulation's truth (tie points' radii, track offsets, posterior sigmas, the altimeter's variance component,
gross shots found by data snooping)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import xarray as xr

import lunarmap
from lunarmap.adjust import (
    ControlNetwork,
    LaserAltimetry,
    NavigationSpec,
    SolverOptions,
    altimetry_observations,
    merge_networks,
    network_from_tiepoints,
)
from lunarmap.camera.geodesy import lonlat_height_to_xyz, xyz_to_lonlat_height
from lunarmap.camera.shape import MOON_RADIUS
from lunarmap.errors import AltimetryCoverageError, AltimetryInputError
from lunarmap.io import AltimetryShots, read_altimetry, write_altimetry
from lunarmap.simulate import altimetry_tracks, frame_block, frame_block_height

#: relief of the synthetic terrain (m): its curvature with the tie points' ~8 km spacing bounds the
#: triangulated surface's error by kappa h^2 / 8 ~ 0.8 m (the interpolation sigma given below)
RELIEF = 50.0
INTERP_SIGMA = 1.0
SHOT_SIGMA = 0.5
OFFSET_SIGMA = 30.0
#: every 20th LOLA shot (1140 m instead of 57 m along track): the test's run time; 5 spots each
ALONG_M = 1140.0


def _block(seed: int, per_orbit: int = 8, points: int = 300, n_check: int = 15, relief: float = RELIEF,
           height=None):
    """Fore/aft frame block, no control points, check points, navigation with per-orbit errors (also the
    block of ``bench/altimetry_datum.py``, which varies its size and terrain ``height(lon, lat)``)."""
    sb = frame_block(orbits=2, per_orbit=per_orbit, points=points, n_control=0, n_check=n_check, seed=seed,
                     relief=relief, cameras=2, tilt_deg=(-15.0, 15.0), forward_overlap=0.3, height=height)
    m = sb.measurements
    names = [f"img{i:02d}" for i in range(len(sb.nav_cameras))]
    chk = np.zeros(sb.true_points.shape[0], bool)
    chk[sb.check] = True
    tie = ~chk[m.pt_idx]
    ties = xr.Dataset({"point_id": ("observation", m.pt_idx[tie]), "image_id": ("observation", m.cam_idx[tie]),
                       "line": ("observation", m.xy[tie, 0]), "sample": ("observation", m.xy[tie, 1]),
                       "sigma_line": ("observation", np.full(tie.sum(), m.sigma)),
                       "sigma_sample": ("observation", np.full(tie.sum(), m.sigma))}, coords={"image": names})
    sel = np.isin(m.pt_idx, sb.check)
    remap = {int(j): k for k, j in enumerate(sb.check)}
    cnet = ControlNetwork([f"C{j}" for j in sb.check], ["check"] * sb.check.size, sb.true_points[sb.check],
                          [remap[int(j)] for j in m.pt_idx[sel]], m.cam_idx[sel], m.xy[sel],
                          np.full((sel.sum(), 2), m.sigma), names)
    net = merge_networks(network_from_tiepoints(ties), cnet)
    spec = NavigationSpec(orbit=dict(zip(names, sb.orbit.tolist())), position_sigma=sb.nav_sigma[3],
                          attitude_sigma=sb.nav_sigma[0], offset="observed", drift="observed",
                          offset_sigma=sb.offset_sigma, drift_sigma=sb.drift_sigma)
    # truth of every network point, by its id ("tp<j>" tie, "C<j>" check)
    truth = sb.true_points[[int(str(p).replace("tp", "").replace("C", "")) for p in net.point_id]]
    return sb, net, dict(zip(names, sb.nav_cameras)), spec, {n: float(t) for n, t in zip(names, sb.times)}, truth


def _tracks(sb, seed: int, gross: float = 0.0):
    lon, lat, _ = xyz_to_lonlat_height(sb.true_points, MOON_RADIUS)
    return altimetry_tracks(lambda lo, la: frame_block_height(lo, la, RELIEF), (lon.min(), lon.max()),
                            (lat.min(), lat.max()), 24, along_track_m=ALONG_M, sigma=SHOT_SIGMA,
                            offset_sigma=OFFSET_SIGMA, heading_deg=20.0, gross_fraction=gross, seed=seed)


def _radial(X, truth):
    u = truth / np.linalg.norm(truth, axis=1)[:, None]
    return np.sum((X - truth) * u, axis=1)


def run_block(seed: int, sigma_factor: float = 1.0, gross: float = 0.0, vc: bool = True):
    """Navigation alone and with altimetry (variance components of images and altimeter estimated); the
    figures against the truth."""
    sb, net, sensors, spec, times, truth = _block(seed)
    out: dict = {}
    b0 = lunarmap.build_block(sensors, net, navigation=spec, times=times)
    r0 = lunarmap.solve(b0, SolverOptions(ftol=1e-10)).result
    sim = _tracks(sb, seed, gross)
    alt = LaserAltimetry(sim.shots, sigma_m=SHOT_SIGMA * sigma_factor, interpolation_sigma_m=INTERP_SIGMA * sigma_factor,
                         offset_sigma_m=OFFSET_SIGMA)
    b1 = lunarmap.build_block(sensors, net, navigation=spec, times=times, altimetry=[alt])
    term = b1.altimetry[0]
    if vc:
        from lunarmap.adjust import estimate_variance_components, observation_groups

        groups = observation_groups(b1.problem, navigation=False)
        comp = estimate_variance_components(b1.problem, groups, SolverOptions(ftol=1e-10))
        r1 = comp.result
        k = list(comp.names).index(term.name)
        out["vc_scale"], out["vc_scale_sigma"] = float(comp.scale[k]), float(comp.scale_sigma[k])
        out["vc_redundancy"] = float(comp.redundancy[k])
    else:
        r1 = lunarmap.solve(b1, SolverOptions(ftol=1e-10)).result
    tie = net.point_type == "tie"
    rad0, rad1 = _radial(r0.points[tie], truth[tie]), _radial(r1.points[tie], truth[tie])
    observed = np.zeros(net.n_points, bool)
    observed[term.shot_point_index.ravel()] = True
    obs_t = observed[tie]
    prec = r1.precision()
    err = r1.points - truth
    C = prec.pt_cov
    z2 = np.einsum("ki,kij,kj->k", err[tie], np.linalg.inv(C[tie]), err[tie])
    s = sum(t.n_extra for t in b1.problem.terms[:-1])
    off = r1.state.extra[s:s + term.n_tracks]
    sig = np.sqrt(np.diag(prec.extra_cov)[s:s + term.n_tracks])
    true_off = sim.offsets[np.searchsorted(sim.track_names, term.track_names)]
    chk = net.point_type == "check"
    out.update(
        tie_radial_rms_nav=float(np.sqrt(np.mean(rad0 ** 2))), tie_radial_rms_alt=float(np.sqrt(np.mean(rad1 ** 2))),
        observed_radial_rms_alt=float(np.sqrt(np.mean(rad1[obs_t] ** 2))),
        tie_3d_rms_nav=float(np.sqrt(np.mean(np.sum((r0.points - truth)[tie] ** 2, axis=1)))),
        tie_3d_rms_alt=float(np.sqrt(np.mean(np.sum(err[tie] ** 2, axis=1)))),
        check_3d_rms_nav=float(np.sqrt(np.mean(np.sum((r0.points - truth)[chk] ** 2, axis=1)))),
        check_3d_rms_alt=float(np.sqrt(np.mean(np.sum(err[chk] ** 2, axis=1)))),
        tie_normalized_rms=float(np.sqrt(np.mean(z2) / 3.0)),
        check_normalized_rms=float(np.sqrt(np.mean(np.einsum("ki,kij,kj->k", err[chk], np.linalg.inv(C[chk]),
                                                             err[chk])) / 3.0)),
        offsets_within_2sigma=float(np.mean(np.abs(off - true_off) <= 2.0 * sig)),
        offsets_normalized_rms=float(np.sqrt(np.mean(((off - true_off) / sig) ** 2))),
        offset_mean_error=float(np.mean(off - true_off)), offset_sigma_median=float(np.median(sig)),
        sigma0=float(r1.sigma0), shots=int(term.n_shots), skipped=int(term.skipped), tracks=int(term.n_tracks),
        # sum of all redundancy numbers against n - u (the trace of the redundancy matrix: a closed form)
        redundancy_total=float(np.sum(prec.redundancy_numbers[r1.state.obs_weight > 0])
                               + sum(float(np.sum(t)) for t in prec.term_redundancy)),
        redundancy_expected=float(b1.problem.n_observations() - 2 * int(np.sum(r1.state.obs_weight == 0))
                                  - b1.problem.n_unknowns()))
    return out, (b1, r1, sim, term)


@pytest.fixture(scope="module")
def adjusted():
    return run_block(3)


# --- the reader -----------------------------------------------------------------------------------

def _table(n=6):
    return AltimetryShots(np.array(["a"] * 3 + ["b"] * (n - 3)), np.arange(n, dtype=float), np.linspace(10, 10.1, n),
                          np.linspace(5, 5.1, n), np.full(n, 1737.4e3), np.full(n, 0.5))


@pytest.mark.parametrize("ext", [".csv", ".nc"])
def test_shot_tables_round_trip(tmp_path, ext):
    shots = _table()
    p = write_altimetry(tmp_path / f"shots{ext}", shots)
    back = read_altimetry(p)
    assert list(back.track) == list(shots.track)
    for c in ("time", "lon", "lat", "radius", "sigma"):
        np.testing.assert_allclose(getattr(back, c), getattr(shots, c), rtol=1e-9)


def test_bad_shot_tables_are_named(tmp_path):
    p = tmp_path / "s.csv"
    p.write_text("track,time,lon,lat\na,0,10,5\n")
    with pytest.raises(AltimetryInputError, match="missing column.*radius"):
        read_altimetry(p)
    p.write_text("track,time,lon,lat,radius\na,0,10,5,1737400\na,1,nan,5,1737400\nb,0,10,5,1737400\nb,2,10,5,1737401\n")
    with pytest.raises(AltimetryInputError, match="'lon'.*NaN.*row 1"):
        read_altimetry(p)
    p.write_text("track,time,lon,lat,radius\na,0,10,5,1737400\na,1,10,5,1737400\nb,0,10,5,1737400\n")
    with pytest.raises(AltimetryInputError, match="one shot.*'b'"):
        read_altimetry(p)
    p.write_text("track,time,lon,lat,radius\na,0,10,5,1737.4\na,1,10,5,1737.4\n")
    with pytest.raises(AltimetryInputError, match="kilometres"):
        read_altimetry(p)
    with pytest.raises(AltimetryInputError, match="does not exist"):
        read_altimetry(tmp_path / "none.csv")
    with pytest.raises(AltimetryInputError, match="sigma_m"):
        LaserAltimetry(_table(), sigma_m=0.0)


def test_shots_outside_the_tie_points_are_counted_and_none_inside_is_named():
    rng = np.random.default_rng(1)
    X = lonlat_height_to_xyz(rng.uniform(10, 10.1, 30), rng.uniform(5, 5.1, 30), np.zeros(30))
    shots = AltimetryShots(np.repeat(["a", "b"], 4), np.arange(8.0), [10.05, 10.06, 10.07, 30.0] * 2,
                           [5.05, 5.04, 5.06, 5.05] * 2, np.full(8, MOON_RADIUS))
    term = altimetry_observations(LaserAltimetry(shots, 1.0), X, 0, 1)
    assert term.n_shots == 6 and term.skipped == 2 and term.n_tracks == 2
    far = AltimetryShots(["a", "a"], [0.0, 1.0], [40.0, 40.1], [5.0, 5.0], [MOON_RADIUS] * 2)
    with pytest.raises(AltimetryCoverageError, match="none of the 2 shots"):
        altimetry_observations(LaserAltimetry(far, 1.0), X, 0, 1)


# --- the observation's partials --------------------------------------------------------------------

@pytest.mark.parametrize("slopes", [False, True])
def test_partials_match_central_differences(slopes):
    rng = np.random.default_rng(0)
    n = 40
    lon, lat = rng.uniform(9.9, 10.1, n), rng.uniform(4.9, 5.1, n)
    X = lonlat_height_to_xyz(lon, lat, 300 * np.sin(lon * 30) + 200 * np.cos(lat * 20))
    ns = 120
    shots = AltimetryShots(np.array(["A", "B"])[rng.integers(0, 2, ns)], rng.uniform(0, 100, ns),
                           rng.uniform(9.95, 10.05, ns), rng.uniform(4.95, 5.05, ns), MOON_RADIUS + rng.normal(0, 100, ns))
    term = altimetry_observations(LaserAltimetry(shots, 1.0, drift=True, offset_sigma_m=5.0, slopes=slopes), X, 0, 1)
    Xp = X + rng.normal(0, 30, X.shape)           # away from the start: the recomputed weights move
    ex = np.array([3.0, -2.0, 0.1, 0.05])
    r, J, Jp = term.linearize(np.zeros(0), ex, Xp)
    e = 0.05
    for row in range(0, term.n_shots, 5):
        for k in range(3):
            j = term.point_index[row, k]
            for a in range(3):
                Y = Xp.copy()
                Y[j, a] += e
                rp = term.linearize(np.zeros(0), ex, Y)[0][row]
                Y[j, a] -= 2 * e
                rm = term.linearize(np.zeros(0), ex, Y)[0][row]
                assert abs((rp - rm) / (2 * e) - Jp[row, k, a]) < 1e-6 * max(1.0, abs(Jp[row, k, a]))
    Jd = J.toarray()
    for c in range(ex.size):
        d = np.zeros(ex.size)
        d[c] = 1e-3
        num = (term.linearize(np.zeros(0), ex + d, Xp)[0] - term.linearize(np.zeros(0), ex - d, Xp)[0]) / 2e-3
        np.testing.assert_allclose(num, Jd[:, c], atol=1e-7)


# --- the block against the truth -------------------------------------------------------------------

def test_altimetry_pins_the_radii_and_recovers_the_track_offsets(adjusted):
    f, _ = adjusted
    print({k: round(v, 3) if isinstance(v, float) else v for k, v in f.items()})
    assert f["skipped"] > 0 and f["shots"] > 1000
    # radial: navigation alone leaves the block's radius to its per-orbit offsets and the weak heights
    assert f["tie_radial_rms_alt"] * 10.0 <= f["tie_radial_rms_nav"]
    # the tracks' offsets: every track alike (their mean is the block's radius, OFFSET_SIGMA / sqrt(24))
    assert f["offsets_within_2sigma"] >= 0.9
    # their common part (the block's radius) is set by the offsets' prior: OFFSET_SIGMA / sqrt(tracks)
    assert abs(f["offset_mean_error"]) < 3.0 * OFFSET_SIGMA / np.sqrt(f["tracks"])
    # the precision of the coupled problem: its redundancy numbers add up to n - u
    assert f["redundancy_total"] == pytest.approx(f["redundancy_expected"], rel=1e-6)
    # the altimeter's variance component is estimated with a large redundancy
    assert f["vc_redundancy"] > 0.8 * f["shots"] and 0.3 < f["vc_scale"] < 1.5


@pytest.mark.slow
def test_altimeter_variance_component_from_far_off_starts(adjusted):
    """Started 10 x too large and 10 x too small, the altimeter's sigma converges to the same value."""
    est = {}
    for factor in (10.0, 0.1):
        f, _ = run_block(3, sigma_factor=factor)
        est[factor] = (f["vc_scale"] * factor, f["vc_scale_sigma"] * factor)
    print(est, adjusted[0]["vc_scale"], adjusted[0]["vc_scale_sigma"])
    (a, sa), (b, sb) = est[10.0], est[0.1]
    assert abs(a - b) < 2.0 * max(sa, sb)
    assert abs(a - adjusted[0]["vc_scale"]) < 2.0 * max(sa, adjusted[0]["vc_scale_sigma"])


@pytest.mark.slow
def test_data_snooping_finds_the_gross_shots():
    """2 % of the shots 50 m off (fewer, sparser tracks: every QC round is an adjustment): variance components,
    then data snooping; the down-weighted shots are the gross ones."""
    from lunarmap.adjust import QCOptions, quality_control

    sb, net, sensors, spec, times, _ = _block(3)
    lon, lat, _ = xyz_to_lonlat_height(sb.true_points, MOON_RADIUS)
    sim = altimetry_tracks(lambda lo, la: frame_block_height(lo, la, RELIEF), (lon.min(), lon.max()),
                           (lat.min(), lat.max()), 8, along_track_m=4 * ALONG_M, sigma=SHOT_SIGMA,
                           offset_sigma=OFFSET_SIGMA, heading_deg=20.0, gross_fraction=0.02, gross_m=50.0, seed=4)
    alt = LaserAltimetry(sim.shots, sigma_m=SHOT_SIGMA, interpolation_sigma_m=INTERP_SIGMA, offset_sigma_m=OFFSET_SIGMA)
    b = lunarmap.build_block(sensors, net, navigation=spec, times=times, altimetry=[alt])
    term = b.altimetry[0]
    gross = sim.gross[term.shot_index]
    assert gross.sum() >= 5
    with warnings.catch_warnings():     # the sparse block's sigma0 test may fail; the decisions are tested
        warnings.simplefilter("ignore")
        qc = quality_control(b.problem, ("variance", "baarda"),
                             options=QCOptions(solver=SolverOptions(ftol=1e-10), variance={"on_weak": "keep"}))
    flagged = np.zeros(term.n_obs_scalar, bool)
    for d in qc.ledger.decisions:
        if d.kind == "terrain" and d.action == "downweighted":
            flagged[d.index] = True
    print(f"shots {term.n_shots}, gross {int(gross.sum())}, down-weighted gross {int(np.sum(flagged[:term.n_shots] & gross))}, "
          f"down-weighted good {int(np.sum(flagged[:term.n_shots] & ~gross))}, rounds {qc.report.summary.get('rounds')}")
    assert np.all(flagged[:term.n_shots][gross])
    assert np.sum(flagged[:term.n_shots] & ~gross) <= 0.1 * gross.sum()


# --- the run configuration and the adjust step's summary ---------------------------------------------

def test_run_config_altimetry_tables(tmp_path):
    from lunarmap.errors import ConfigError
    from lunarmap.workflows.config import _altimetry_config, _terrain_config

    write_altimetry(tmp_path / "lola.csv", _table())
    t = {"altimetry": [{"path": "lola.csv", "sigma": 0.5, "interpolation_sigma": 1.0, "offset_sigma": 30.0}]}
    assert _terrain_config(t, tmp_path, "cfg") == ()          # no DTM: altimetry alone is a terrain section
    (a,) = _altimetry_config(t, tmp_path, "cfg")
    assert (a.name, a.group, a.sigma, a.interpolation_sigma, a.offset_sigma, a.drift) == \
        ("lola", "altimetry lola", 0.5, 1.0, 30.0, False)
    with pytest.raises(ConfigError, match="interpolation_sigma must be >= 0"):
        _altimetry_config({"altimetry": [{"path": "lola.csv", "sigma": 0.5, "interpolation_sigma": -1}]}, tmp_path, "c")
    with pytest.raises(ConfigError, match="at least one"):
        _terrain_config({}, tmp_path, "cfg")
    with pytest.raises(ConfigError, match="repeats"):
        _altimetry_config({"altimetry": [{"path": "lola.csv", "sigma": 0.5}] * 2}, tmp_path, "cfg")


def test_adjust_step_summary_reports_the_track_offsets(adjusted):
    from lunarmap.adjust.block import BlockResult
    from lunarmap.workflows.steps import _altimetry_outputs

    _, (b1, r1, sim, term) = adjusted
    sec = _altimetry_outputs(b1, BlockResult(b1, r1), None, [{"name": "lola", "sigma": SHOT_SIGMA}])["lola"]
    assert sec["shots"] == term.n_shots and len(sec["tracks"]) == term.n_tracks
    s = sum(t.n_extra for t in b1.problem.terms[:-1])
    k = 3
    tr = sec["tracks"][str(term.track_names[k])]
    assert tr["offset_m"] == pytest.approx(r1.state.extra[s + k])
    assert tr["offset_sigma_m"] == pytest.approx(np.sqrt(r1.precision().extra_cov[s + k, s + k]))
    # the group's residual RMS: between the shots' noise and the noise with the surface's interpolation error
    assert 0.8 * SHOT_SIGMA < sec["rms_residual_m"] < np.hypot(SHOT_SIGMA, INTERP_SIGMA)
    # the offsets reported are the simulated ones within their sigma (most tracks)
    z = [(sec["tracks"][str(n)]["offset_m"] - sim.offsets[list(sim.track_names).index(n)])
         / sec["tracks"][str(n)]["offset_sigma_m"] for n in term.track_names]
    assert np.mean(np.abs(z) < 2.0) >= 0.9


def test_whole_normal_equations_agree_with_the_schur_path(monkeypatch):
    """The path of point-coupling terms (the whole normal equations, the dense inverse) on a block without
    them, against the Schur-complement solver and its precision: the same solution, covariances and
    redundancy numbers."""
    from lunarmap.adjust import normal

    sb, net, sensors, spec, times, _ = _block(3)
    block = lunarmap.build_block(sensors, net, navigation=spec, times=times)
    ref = lunarmap.solve(block, SolverOptions(ftol=1e-12)).result
    p_ref = ref.precision()
    init = normal.Terms.__init__

    def coupled_init(self, problem):
        init(self, problem)
        self.coupled = True

    monkeypatch.setattr(normal.Terms, "__init__", coupled_init)
    res = lunarmap.solve(block, SolverOptions(ftol=1e-12)).result
    prec = res.precision()
    assert prec.method == "dense-coupled" and p_ref.method != "dense-coupled"
    np.testing.assert_allclose(res.points, ref.points, rtol=0, atol=1e-3)               # metres
    np.testing.assert_allclose(prec.pt_cov, p_ref.pt_cov, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(prec.cam_cov, p_ref.cam_cov, rtol=1e-5, atol=1e-16)
    np.testing.assert_allclose(prec.redundancy_numbers, p_ref.redundancy_numbers, atol=1e-7)
    np.testing.assert_allclose(prec.term_redundancy[0], p_ref.term_redundancy[0], atol=1e-7)


def test_simulated_tracks_have_the_lola_pattern_and_the_stated_errors():
    """Centre spots 57 m apart along track, the other four 25 m from their centre; radius minus terrain minus the
    track's offset is the noise (sigma), the gross shots 50 m off."""
    sim = altimetry_tracks(lambda lo, la: np.zeros_like(lo), (10.0, 10.2), (5.0, 5.4), 3, sigma=0.7, offset_sigma=20.0,
                           gross_fraction=0.02, seed=2)
    s = sim.shots
    X = lonlat_height_to_xyz(s.lon, s.lat, np.zeros(s.n))
    first = s.track == sim.track_names[0]
    c = X[first][0::5]                                   # centre spots of the first track
    np.testing.assert_allclose(np.linalg.norm(np.diff(c, axis=0), axis=1), 57.0, rtol=1e-3)
    others = X[first].reshape(-1, 5, 3)
    np.testing.assert_allclose(np.linalg.norm(others[:, 1:] - others[:, :1], axis=2), 25.0, rtol=1e-3)
    k = np.searchsorted(sim.track_names, s.track)
    e = s.radius - sim.terrain_radius - sim.offsets[k]
    assert np.std(e[~sim.gross]) == pytest.approx(0.7, rel=0.05)
    np.testing.assert_allclose(np.abs(e[sim.gross]), 50.0, atol=5 * 0.7)
    assert 0.01 < sim.gross.mean() < 0.03


def test_free_track_offsets_without_navigation_are_a_datum_defect():
    """Without navigation and control points nothing fixes the block's radius and orientation: free track offsets
    (no offset_sigma) leave the datum undefined, named before any iteration."""
    from lunarmap.errors import DatumDefectError

    sb, net, sensors, _, _, _ = _block(3)
    sim = _tracks(sb, 3)
    block = lunarmap.build_block(sensors, net, altimetry=[LaserAltimetry(sim.shots, sigma_m=SHOT_SIGMA)])
    with pytest.raises(DatumDefectError):
        lunarmap.solve(block, SolverOptions(ftol=1e-10))


def test_frame_block_takes_a_terrain_of_its_own():
    """frame_block(height=...) puts the true points on that terrain (bench/altimetry_datum.py's cratered runs)."""
    def h(lon, lat):
        return 300.0 * np.sin(np.radians(lon) * 400.0) * np.cos(np.radians(lat) * 300.0)

    sb = frame_block(orbits=2, per_orbit=4, points=60, n_control=0, seed=1, height=h)
    lon, lat, hh = xyz_to_lonlat_height(sb.true_points, MOON_RADIUS)
    np.testing.assert_allclose(hh, h(lon, lat), atol=1e-6)
    assert np.ptp(hh) > 100.0
