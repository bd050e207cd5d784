"""Control-network netCDF: round trip, atomic write, conversion to a BundleProblem, bad files."""

from __future__ import annotations


import numpy as np
import pytest
import xarray as xr

from lunarmap.adjust import SolverOptions, solve
from lunarmap.adjust.network import (ControlNetwork, network_from_dataset, network_to_dataset, read_network,
                                     write_network)
from blockhelp import rfm_case
from lunarmap.errors import NetworkFormatError


@pytest.fixture(scope="module")
def block():
    return rfm_case(n_points=30, n_control=4, n_check=8, seed=2)


def _network(sb):
    pb = sb.problem
    n = pb.n_points
    ptype = np.array(["tie"] * n, dtype=object)
    ptype[sb.control] = "control"
    ptype[sb.check] = "check"
    xyz = np.full((n, 3), np.nan)
    xyz[sb.control] = pb.priors.xyz
    xyz[sb.check] = sb.true_points[sb.check]
    cov = np.full((n, 3, 3), np.nan)
    cov[sb.control] = pb.priors.sigma[:, :, None] ** 2 * np.eye(3)
    return ControlNetwork(point_id=[f"P{j:04d}" for j in range(n)], point_type=ptype, xyz=xyz,
                          measure_point=pb.obs.pt_idx, measure_image=pb.obs.cam_idx, line_sample=pb.obs.xy,
                          measure_sigma=pb.obs.sigma, image_id=[f"M{i}L" for i in range(pb.n_images)],
                          image_name=[f"M{i}L.cub" for i in range(pb.n_images)], xyz_cov=cov,
                          attrs={"site": "synthetic"})


def _same(a: ControlNetwork, b: ControlNetwork):
    assert a.point_id.tolist() == b.point_id.tolist()
    assert a.point_type.tolist() == b.point_type.tolist()
    assert np.array_equal(a.xyz, b.xyz, equal_nan=True)
    assert np.array_equal(a.xyz_cov, b.xyz_cov, equal_nan=True)
    assert np.array_equal(a.measure_point, b.measure_point) and np.array_equal(a.measure_image, b.measure_image)
    assert np.array_equal(a.line_sample, b.line_sample) and np.array_equal(a.measure_sigma, b.measure_sigma)
    assert a.image_id.tolist() == b.image_id.tolist() and a.image_name.tolist() == b.image_name.tolist()
    assert a.radius == b.radius and a.body == b.body


def test_round_trip(block, tmp_path):
    net = _network(block)
    path = write_network(net, tmp_path / "net.nc")
    back = read_network(path)
    _same(net, back)
    assert back.attrs["site"] == "synthetic"
    assert back.indices("check").tolist() == sorted(block.check.tolist())
    # derived lat/lon/height in the file agree with the xyz
    with xr.open_dataset(path) as ds:
        from lunarmap.camera.geodesy import lonlat_height_to_xyz

        c = block.control
        assert np.allclose(lonlat_height_to_xyz(ds.lon.values[c], ds.lat.values[c], ds.height.values[c]),
                           net.xyz[c], atol=1e-6)
        assert ds.point_type.attrs["flag_meanings"] == "tie control check"
    assert [p.name for p in tmp_path.iterdir()] == ["net.nc"]   # no temporary left behind


def test_failed_write_leaves_nothing(block, tmp_path, monkeypatch):
    net = _network(block)
    target = tmp_path / "net.nc"
    write_network(net, target)
    before = target.read_bytes()

    def broken(self, path, *a, **k):
        with open(path, "wb") as fh:
            fh.write(b"half")          # a partial file ...
        raise OSError("disk full")     # ... then the failure

    monkeypatch.setattr(xr.Dataset, "to_netcdf", broken)
    with pytest.raises(OSError, match="disk full"):
        write_network(net, target)
    with pytest.raises(OSError):
        write_network(net, tmp_path / "new.nc")
    assert target.read_bytes() == before          # the old file is untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["net.nc"]
    with pytest.raises(NetworkFormatError, match="does not exist"):
        write_network(net, tmp_path / "no" / "such" / "net.nc")


def test_conversion_to_problem_reproduces_the_adjustment(block):
    net = _network(block)
    pb = block.problem
    p2 = net.to_problem(pb.model, pb.cam_params, points=pb.points)
    assert np.array_equal(p2.obs.xy, pb.obs.xy) and np.array_equal(p2.obs.cam_idx, pb.obs.cam_idx)
    assert np.array_equal(p2.priors.idx, pb.priors.idx) and np.allclose(p2.priors.sigma, pb.priors.sigma)
    r1 = solve(pb, SolverOptions(ftol=1e-10))
    r2 = solve(p2, SolverOptions(ftol=1e-10))
    assert np.allclose(r1.points, r2.points, atol=1e-6)
    with pytest.raises(NetworkFormatError, match="initial points"):
        net.to_problem(pb.model, pb.cam_params)


def test_bad_networks(block, tmp_path):
    net = _network(block)
    ds = network_to_dataset(net)
    with pytest.raises(NetworkFormatError, match="missing variable"):
        network_from_dataset(ds.drop_vars("line"))
    with pytest.raises(NetworkFormatError, match="not a lunarmap control network"):
        network_from_dataset(ds.assign_attrs(Conventions="CF-1.8"))
    bad = ds.copy()
    bad["point_type"] = bad["point_type"].copy(data=np.full(bad.sizes["point"], 7, np.int8))
    with pytest.raises(NetworkFormatError, match="point_type"):
        network_from_dataset(bad)
    bad = ds.copy()
    bad["measure_image"] = bad["measure_image"] + 100
    with pytest.raises(NetworkFormatError, match="measure_image out of range"):
        network_from_dataset(bad)
    bad = ds.copy()
    bad["line"] = bad["line"].where(bad.measure < 1)
    with pytest.raises(NetworkFormatError, match="NaN"):
        network_from_dataset(bad)
    with pytest.raises(NetworkFormatError, match="ids repeat"):
        ControlNetwork(["a", "a"], ["tie", "tie"], np.zeros((2, 3)), [0, 1], [0, 0], np.zeros((2, 2)), 1.0, ["i"])
    with pytest.raises(NetworkFormatError, match="xyz_cov"):
        ControlNetwork(["a", "b"], ["control", "tie"], np.zeros((2, 3)), [0, 1], [0, 0], np.zeros((2, 2)), 1.0,
                       ["i"])
    with pytest.raises(FileNotFoundError):
        read_network(tmp_path / "absent.nc")
