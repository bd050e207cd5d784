"""The block API: named images on their sensor models, a control network (tie, control, check points),
navigation observations; adjusted sensors and check points against the simulation's truth; named errors."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

import lunarmap
from lunarmap.adjust import (ControlNetwork, NavigationSpec, SolverOptions, build_block, merge_networks,
                             network_from_tiepoints, solve_block, write_adjusted)
from lunarmap.errors import AdjustmentInputError, UnobservedParameterError
from lunarmap.simulate import frame_block


@pytest.fixture(scope="module")
def sim():
    return frame_block(orbits=2, per_orbit=6, points=300, n_control=4, n_check=15, seed=21)


def _networks(sb):
    """Tie points as a matcher table, control and check points as their own networks."""
    m = sb.measurements
    names = [f"img{i:02d}" for i in range(len(sb.nav_cameras))]
    special = np.zeros(sb.true_points.shape[0], bool)
    special[sb.control] = special[sb.check] = True
    tie = ~special[m.pt_idx]
    ties = xr.Dataset({"point_id": ("observation", m.pt_idx[tie]), "image_id": ("observation", m.cam_idx[tie]),
                       "line": ("observation", m.xy[tie, 0]), "sample": ("observation", m.xy[tie, 1]),
                       "sigma_line": ("observation", np.full(tie.sum(), m.sigma)),
                       "sigma_sample": ("observation", np.full(tie.sum(), m.sigma))},
                      coords={"image": names})

    def net(idx, kind, xyz, cov):
        sel = np.isin(m.pt_idx, idx)
        remap = {int(j): k for k, j in enumerate(idx)}
        return ControlNetwork([f"{kind[0].upper()}{j}" for j in idx], [kind] * idx.size, xyz,
                              [remap[int(j)] for j in m.pt_idx[sel]], m.cam_idx[sel], m.xy[sel],
                              np.full((sel.sum(), 2), m.sigma), names, xyz_cov=cov)

    ctl = net(sb.control, "control", sb.control_xyz,
              np.repeat((sb.control_sigma ** 2 * np.eye(3))[None], sb.control.size, 0))
    chk = net(sb.check, "check", sb.true_points[sb.check], None)
    return names, ties, ctl, chk


def _spec(sb, names):
    return NavigationSpec(orbit=dict(zip(names, sb.orbit.tolist())), position_sigma=sb.nav_sigma[3],
                          attitude_sigma=sb.nav_sigma[0], offset="observed", drift="observed",
                          offset_sigma=sb.offset_sigma, drift_sigma=sb.drift_sigma)


def test_tiepoint_table_to_adjusted_sensors(sim, tmp_path):
    names, ties, ctl, chk = _networks(sim)
    net = merge_networks(network_from_tiepoints(ties), ctl, chk)
    assert net.n_images == len(names) and set(net.point_type) == {"tie", "control", "check"}
    sensors = dict(zip(names, sim.nav_cameras))
    block = lunarmap.build_block(sensors, net, navigation=_spec(sim, names),
                                 times={n: float(t) for n, t in zip(names, sim.times)})
    assert block.problem.n_images == len(names) and block.navigation is not None
    x0 = block.problem.points.copy()
    res = lunarmap.solve(block, SolverOptions(ftol=1e-10))
    assert res.converged and abs(res.sigma0 - 1.0) < 0.15
    before, after = res.check_points(x0), res.check_points()
    # 100 m navigation offsets removed horizontally; heights of this 400-km-altitude block (B/H ~0.03) are
    # limited by the 0.3-px measurement noise before and after (posterior sigma ~1 km)
    assert np.all(before.attrs["rms_m"][:2] > 3 * after.attrs["rms_m"][:2])
    assert 0.6 < after.attrs["normalized_rms"] < 1.4
    # the corrections equal the simulated navigation errors within their posterior sigma
    corr = res.corrections()
    z = (corr["value"].values - sim.true_params) / corr["sigma"].values
    assert np.sqrt(np.mean(z ** 2)) < 1.5
    # adjusted sensors: new cameras equal to the truth where the truth is determined, originals untouched
    adj = res.adjusted_sensors()
    X = sim.true_points[sim.check]
    for i, n in enumerate(names):
        assert adj[n] is not sensors[n] and sensors[n] is sim.nav_cameras[i]
        la, sa = adj[n].ground_to_image(X, within_image=False)
        lt, st = sim.true_cameras[i].ground_to_image(X, within_image=False)
        assert np.max(np.hypot(la - lt, sa - st)) < 1.0
    pts = res.points()
    assert pts["point_type"].values.tolist().count("check") == sim.check.size
    # cameras without SPICE provenance cannot be written back as kernels: a named error, nothing written
    with pytest.raises(AdjustmentInputError, match="no image support data"):
        write_adjusted(res, {}, tmp_path, tmp_path / "none.tm")
    assert list(tmp_path.iterdir()) == []


def test_bad_inputs_are_named(sim):
    names, ties, ctl, chk = _networks(sim)
    sensors = dict(zip(names, sim.nav_cameras))
    unknown = ties.assign_coords(image=[n.replace("img00", "M0001") for n in names])
    with pytest.raises(AdjustmentInputError, match="without a sensor model: M0001"):
        build_block(sensors, merge_networks(network_from_tiepoints(unknown), ctl))
    extra = dict(sensors, lonely=sim.nav_cameras[0])
    with pytest.raises(UnobservedParameterError, match="no measurements: lonely"):
        build_block(extra, merge_networks(network_from_tiepoints(ties), ctl))
    with pytest.raises(AdjustmentInputError, match="ControlNetwork or a tie-point Dataset"):
        build_block(sensors, [1, 2, 3])  # type: ignore[arg-type]
    with pytest.raises(AdjustmentInputError, match="not a lunarmap SensorModel"):
        build_block(dict(sensors, img00="camera"), merge_networks(network_from_tiepoints(ties), ctl))
    spec = NavigationSpec(orbit={"nobody": 0}, position_sigma=1.0, attitude_sigma=1e-6)
    with pytest.raises(AdjustmentInputError, match="no image of the block"):
        build_block(sensors, merge_networks(network_from_tiepoints(ties), ctl), navigation=spec)
    from lunarmap.errors import NetworkFormatError

    with pytest.raises(NetworkFormatError, match="missing sigma_line"):
        network_from_tiepoints(ties.drop_vars("sigma_line"))


def test_matching_refuses_objects_that_are_not_sensor_models(sim):
    img = np.zeros((32, 32))
    with pytest.raises(lunarmap.errors.InvalidInputError, match="not lunarmap SensorModels"):
        lunarmap.find_tiepoints({"a": img, "b": img}, {"a": sim.nav_cameras[0], "b": object()})
