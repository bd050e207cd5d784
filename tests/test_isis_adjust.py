"""ISIS control networks driving a block adjustment and carrying its results back; ASP .adjust files."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import lunarmap
from lunarmap.adjust import merge_networks, network_from_tiepoints
from lunarmap.adjust.asp import asp_adjustment, read_asp_adjust, write_asp_adjust, write_asp_outputs
from lunarmap.adjust.isis import isis_dataset, read_isis_network, write_isis_network
from lunarmap.errors import NetworkFormatError, UnknownImageError
from lunarmap.io.isis_network import read_isis_network as read_isis_dataset
from lunarmap.simulate import frame_block
from test_adjust_block import _networks, _spec


@pytest.fixture(scope="module")
def solved():
    sim = frame_block(orbits=2, per_orbit=6, points=300, n_control=4, n_check=15, seed=21)
    names, ties, ctl, chk = _networks(sim)
    net = merge_networks(network_from_tiepoints(ties), ctl, chk)
    sensors = dict(zip(names, sim.nav_cameras))
    block = lunarmap.build_block(sensors, net, navigation=_spec(sim, names),
                                 times={n: float(t) for n, t in zip(names, sim.times)})
    return sim, names, net, sensors, lunarmap.solve(block)


def test_network_through_isis_file_is_the_same_network(solved, tmp_path):
    sim, names, net, sensors, result = solved
    path = write_isis_network(net, tmp_path / "block.net")
    back = read_isis_network(path, images=names)
    assert list(back.point_id) == list(net.point_id) and list(back.point_type) == list(net.point_type)
    np.testing.assert_array_equal(back.xyz, net.xyz)
    control = net.point_type == "control"
    np.testing.assert_array_equal(back.xyz_cov[control], net.xyz_cov[control])
    order = np.argsort(net.measure_point, kind="stable")          # ISIS keeps measures inside their points
    np.testing.assert_array_equal(back.measure_point, net.measure_point[order])
    np.testing.assert_array_equal(back.measure_image, net.measure_image[order])
    np.testing.assert_allclose(back.line_sample, net.line_sample[order], rtol=0, atol=1e-10)
    np.testing.assert_array_equal(back.measure_sigma, net.measure_sigma[order])
    # the block built from the ISIS file solves to the same result
    block = lunarmap.build_block(sensors, back, navigation=_spec(sim, names),
                                 times={n: float(t) for n, t in zip(names, sim.times)})
    again = lunarmap.solve(block)
    assert again.sigma0 == pytest.approx(result.sigma0, rel=1e-6)
    np.testing.assert_allclose(again.result.points, result.result.points, rtol=0, atol=1e-4)
    with pytest.raises(UnknownImageError, match="not in the image list"):
        read_isis_network(path, images=names[:-1])


def test_adjustment_results_in_the_isis_network(solved, tmp_path):
    _, names, net, _, result = solved
    block_net = result.block.network
    path = write_isis_network(block_net, tmp_path / "adjusted.net", result=result)
    ds = read_isis_dataset(path, images=list(block_net.image_id))
    order = np.argsort(block_net.measure_point, kind="stable")
    np.testing.assert_array_equal(ds["adjusted_xyz"].values, result.result.points)
    cov = result.result.precision().pt_cov                       # ISIS stores the upper triangle
    upper = np.triu(cov) + np.swapaxes(np.triu(cov, 1), 1, 2)
    np.testing.assert_array_equal(ds["adjusted_cov"].values, upper)
    residual = result.result.image_residuals()[order]
    np.testing.assert_array_equal(ds["line_residual"].values, residual[:, 0])
    np.testing.assert_array_equal(ds["sample_residual"].values, residual[:, 1])
    isis_types = ds["isis_point_type"].values
    assert set(isis_types[ds["point_type"].values == 1]) == {3} and set(isis_types[ds["point_type"].values == 0]) == {2}
    check = ds["point_type"].values == 2
    assert check.sum() == 15 and ds["ignore"].values[check].all()       # jigsaw leaves check points out
    with pytest.raises(NetworkFormatError, match="not a solution of this network"):
        isis_dataset(net.__class__(point_id=net.point_id[:5], point_type=net.point_type[:5], xyz=net.xyz[:5],
                                   measure_point=np.zeros(0, int), measure_image=np.zeros(0, int),
                                   line_sample=np.zeros((0, 2)), measure_sigma=np.zeros((0, 2)),
                                   image_id=net.image_id, xyz_cov=net.xyz_cov[:5]), result=result)


def _asp_formula(original, translation, quaternion, xyz):
    """ASP's AdjustedCameraModel::point_to_pixel, written from its definition with scipy."""
    c0, _ = original.rays(np.array([0.5]), np.array([0.5]))
    c0 = c0.reshape(3)
    r = Rotation.from_quat([quaternion[1], quaternion[2], quaternion[3], quaternion[0]])
    return original.ground_to_image(r.inv().apply(xyz - c0 - translation) + c0, within_image=False)


def test_asp_adjust_reproduces_adjusted_frame_cameras(solved, tmp_path):
    _, names, _, sensors, result = solved
    adjusted = result.adjusted_sensors()
    worst = 0.0
    for name in names[:4]:
        adj = asp_adjustment(sensors[name], adjusted[name])
        path = write_asp_adjust(tmp_path / f"run-{name}.adjust", adj)
        back = read_asp_adjust(path, original=sensors[name])
        np.testing.assert_array_equal(back.translation, adj.translation)
        np.testing.assert_array_equal(back.quaternion, adj.quaternion)
        cam = adjusted[name]
        line, sample = np.meshgrid(np.linspace(1, cam.n_lines - 1, 9), np.linspace(1, cam.n_samples - 1, 9))
        xyz = cam.image_to_ground(line.ravel(), sample.ravel(), height=500.0)
        l2, s2 = _asp_formula(sensors[name], back.translation, back.quaternion, xyz)
        worst = max(worst, float(np.hypot(l2 - line.ravel(), s2 - sample.ravel()).max()))
        assert adj.max_px < 1e-6
    print(f"\nASP .adjust of adjusted frame cameras: max {worst:.2e} px")
    assert worst < 1e-6


@pytest.mark.shared
def test_asp_outputs_for_a_line_scan_camera(lro_set, tmp_path):
    from lunarmap.camera.cube import camera_from_cube
    from lunarmap.camera.factory import camera_from_isd_file
    from lunarmap.orientation.cube import image_support_from_cube

    cube = lro_set / "M103595705LE.cub"
    isd = image_support_from_cube(cube, image_size=(400, 5064))
    original = camera_from_cube(cube, image_size=(400, 5064))
    corr = original.corrections(degree=0)
    adjusted = corr.apply([2e-5, -1e-5, 3e-5, 30.0, -20.0, 10.0])
    out = write_asp_outputs({"nac": adjusted}, {"nac": original}, {"nac": isd}, tmp_path, prefix="run")["nac"]
    from_isd = camera_from_isd_file(out["isd"])                        # ASP's exact route: the adjusted ISD
    line, sample = np.meshgrid(np.linspace(0, 400, 9), np.linspace(0, 5064, 9))
    xyz = adjusted.image_to_ground(line.ravel(), sample.ravel())
    l1, s1 = from_isd.ground_to_image(xyz, within_image=False)
    assert np.hypot(l1 - line.ravel(), s1 - sample.ravel()).max() < 1e-6
    adj = read_asp_adjust(out["adjust"], original=original)
    l2, s2 = _asp_formula(original, adj.translation, adj.quaternion, xyz)
    rigid = float(np.hypot(l2 - line.ravel(), s2 - sample.ravel()).max())
    print(f"\nASP .adjust of a degree-0 corrected NAC camera (0.4 s): rigid-motion fit max {rigid:.2e} px "
          f"(fit report {out['max_px']:.2e} px)")
    assert rigid < 0.01 and out["max_px"] < 0.01
