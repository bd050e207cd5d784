"""Pickling round trips of every public model and result object (dask ships them between processes).

Each object is pickled with the highest protocol and loaded back; the copy must *behave* the same:
project the same points bit for bit, hold the same arrays, answer the same queries. Cameras also
drop their caches (and their lock) on the way and must rebuild them, from several threads at once.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import xarray as xr

from lunarmap.camera import FrameCamera, LineScanCamera, Shape
from lunarmap.simulate.orbits import NAC_LINE_TIME, frame_interior, nac_like_interior, polar_orbit_eo
from threadhelp import in_threads


def roundtrip(obj):
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    copy = pickle.loads(data)
    assert type(copy) is type(obj)
    return copy


def _pixels(n_lines, n_samples, n=200, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0, n_lines, n), rng.uniform(0, n_samples, n)


@pytest.fixture(scope="module")
def cameras():
    ls = LineScanCamera(nac_like_interior(n_lines=4000), polar_orbit_eo(lat_center=10.0, half_span=2.0),
                        Shape.moon(), line_times=(-2000 * NAC_LINE_TIME, NAC_LINE_TIME))
    fr = FrameCamera(frame_interior(), polar_orbit_eo(lat_center=10.0, half_span=0.0, step=1.0), Shape.moon())
    return {"linescan": ls, "frame": fr}


@pytest.mark.parametrize("kind", ["linescan", "frame"])
def test_cameras(cameras, kind):
    cam = cameras[kind]
    line, sample = _pixels(cam.n_lines, cam.n_samples)
    ground = cam.image_to_ground(line, sample, height=250.0)   # caches built before pickling
    copy = roundtrip(cam)
    assert getattr(copy, "_table", None) is None                # the cache stayed home ...
    got = in_threads(lambda i: (copy.image_to_ground(line, sample, height=250.0), copy.ground_to_image(ground)), 4)
    ref = cam.ground_to_image(ground)
    for g, (li, sa) in got:                                      # ... and is rebuilt, from threads, identically
        assert np.array_equal(g, ground) and np.array_equal(li, ref[0]) and np.array_equal(sa, ref[1])
    corr, corr_copy = cam.corrections(), roundtrip(cam.corrections())
    p = np.full(corr.n_params, 1e-6)
    assert np.array_equal(corr.project(p, ground), corr_copy.project(p, ground))
    assert np.array_equal(roundtrip(cam.eo).position_at(np.array([0.1, 0.2])), cam.eo.position_at(np.array([0.1, 0.2])))


def test_rfm_affine_sensor_and_fit(cameras):
    from lunarmap.rpc import fit_rpc

    fit = fit_rpc(cameras["frame"], (-2000.0, 2000.0))
    copy = roundtrip(fit)
    assert np.array_equal(copy.model.coefficients, fit.model.coefficients) and copy.check.rms == fit.check.rms
    rfm = fit.model
    line, sample = _pixels(rfm.n_lines, rfm.n_samples)
    ground = rfm.image_to_ground(line, sample, 100.0)
    assert np.array_equal(roundtrip(rfm).image_to_ground(line, sample, 100.0), ground)
    corr = rfm.corrections()
    params = np.array([0.3, 1e-4, -2e-4, -0.2, 3e-4, 1e-4])[: corr.n_params]
    affine = corr.apply(params)
    a, b = affine.ground_to_image(ground), roundtrip(affine).ground_to_image(ground)
    assert np.array_equal(a[0], b[0], equal_nan=True) and np.array_equal(a[1], b[1], equal_nan=True)
    assert np.isfinite(a[0]).sum() > 100
    assert np.array_equal(roundtrip(corr).project(params, ground), corr.project(params, ground))


def test_image_support_and_label(sim_mission):
    from lunarmap.errors import LabelKeywordError
    from lunarmap.labels import load_label
    from lunarmap.orientation.drivers import image_support

    lab_path = sorted(sim_mission.parent.glob("sim_frame_*.lbl"))[0]
    isd = image_support(lab_path, sim_mission)
    assert roundtrip(isd).to_ale_dict() == isd.to_ale_dict()
    label = load_label(lab_path)
    copy = roundtrip(label)
    assert copy == label and copy["isiscube"]["core"]["DIMENSIONS"]["lines"] == label["IsisCube"]["Core"]["Dimensions"]["Lines"]
    exposure = copy.find("ExposureDuration")   # a Quantity: its unit survives (it used to break unpickling)
    assert exposure == label.find("ExposureDuration") and exposure.unit == "ms"
    with pytest.raises(LabelKeywordError, match="lacks IsisCube/Core/Nothing"):
        copy["IsisCube"]["Core"]["Nothing"]


def test_kernel_set_network_bal_and_tiepoints(sim_mission, tmp_path):
    import sys

    from lunarmap.spice import KernelSet

    sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))
    from fuzz_targets import _bal_seed, _network_seed, _tiepoint_seed

    k = KernelSet.from_metakernel(sim_mission)
    assert roundtrip(k) == k
    net = _network_seed()
    c = roundtrip(net)
    for f in ("point_id", "point_type", "measure_point", "measure_image", "image_id"):
        assert np.array_equal(getattr(c, f), getattr(net, f))
    assert np.array_equal(c.xyz, net.xyz, equal_nan=True) and np.array_equal(c.xyz_cov, net.xyz_cov, equal_nan=True)
    bal = _bal_seed()
    assert all(np.array_equal(getattr(roundtrip(bal), f), getattr(bal, f)) for f in ("cameras", "points", "obs"))
    ties = _tiepoint_seed()
    xr.testing.assert_identical(roundtrip(ties), ties)


@pytest.fixture(scope="module")
def solved():
    import lunarmap
    from lunarmap.adjust import SolverOptions
    from lunarmap.simulate import frame_block
    from test_adjust_block import _networks, _spec

    sim = frame_block(orbits=2, per_orbit=4, points=120, n_control=4, n_check=8, seed=5)
    names, ties, ctl, chk = _networks(sim)
    from lunarmap.adjust import merge_networks, network_from_tiepoints

    block = lunarmap.build_block(dict(zip(names, sim.nav_cameras)), merge_networks(network_from_tiepoints(ties), ctl, chk),
                                 navigation=_spec(sim, names), times={n: float(t) for n, t in zip(names, sim.times)})
    return block, lunarmap.solve(block, SolverOptions(ftol=1e-10))


def test_block_and_results(solved):
    import lunarmap
    from lunarmap.adjust import SolverOptions

    block, res = solved
    b2 = roundtrip(block)
    again = lunarmap.solve(b2, SolverOptions(ftol=1e-10))
    assert again.sigma0 == res.sigma0
    xr.testing.assert_identical(again.points(), res.points())

    copy = roundtrip(res)                        # before the (lazy) precision exists
    assert copy.sigma0 == res.sigma0 and copy.converged == res.converged
    xr.testing.assert_identical(copy.points(), res.points())
    xr.testing.assert_identical(copy.corrections(), res.corrections())
    xr.testing.assert_identical(copy.check_points(), res.check_points())
    res.result.precision()
    copy2 = roundtrip(res)                       # and after
    assert copy2.result._precision is not None
    xr.testing.assert_identical(copy2.result.points_dataset(with_precision=True),
                                res.result.points_dataset(with_precision=True))
    ground = res.points()["xyz"].values[:20]
    for name, sensor in res.adjusted_sensors().items():
        a, b = sensor.ground_to_image(ground), copy.adjusted_sensors()[name].ground_to_image(ground)
        assert np.array_equal(a[0], b[0], equal_nan=True) and np.array_equal(a[1], b[1], equal_nan=True)


def test_samplers_intersections_and_parameter_objects(cameras):
    from lunarmap.adjust import NavigationSpec, SensorImageModel, SolverOptions, intersect_points
    from lunarmap.camera import DtmSampler
    from lunarmap.matching import TiePointParams
    from lunarmap.simulate import synthetic_dtm
    from lunarmap.simulate.sampling import RasterSampler

    dtm = synthetic_dtm(30.0, 10.0, 2000.0, 20.0, seed=1)
    lon, lat = np.linspace(29.99, 30.01, 7), np.linspace(9.99, 10.01, 7)
    for sampler in (DtmSampler(dtm), RasterSampler(dtm)):
        sampler(lon, lat)                                  # caches (a projection) built before pickling
        assert np.array_equal(roundtrip(sampler)(lon, lat), sampler(lon, lat), equal_nan=True)

    cam = cameras["frame"]
    other = FrameCamera(cam.interior, polar_orbit_eo(lat_center=10.0, lon=30.05, half_span=0.0, step=1.0), Shape.moon())
    model = SensorImageModel([cam, other])
    X = cam.image_to_ground(*_pixels(cam.n_lines, cam.n_samples, 30), height=0.0)
    seen = np.all(np.isfinite(np.column_stack(other.ground_to_image(X))), axis=1)
    X = X[seen]
    n = X.shape[0]
    xy = model.project(np.zeros((2, 6)), np.repeat([0, 1], n), np.concatenate([X, X]))
    res = intersect_points(model, np.zeros((2, 6)), np.repeat([0, 1], n), np.tile(np.arange(n), 2), xy, 0.3, n_pt=n)
    copy = roundtrip(res)
    assert np.array_equal(copy.xyz, res.xyz) and np.array_equal(copy.cov, res.cov, equal_nan=True)
    for obj in (cam.interior, cam.shape, SolverOptions(ftol=1e-9),
                NavigationSpec(orbit={"a": 0}, position_sigma=1.0, attitude_sigma=1e-6), TiePointParams()):
        assert roundtrip(obj) == obj
    times = cameras["linescan"].line_times          # no __eq__: compared by what it computes
    lines = np.linspace(-10.0, 4010.0, 50)
    assert np.array_equal(roundtrip(times).time(lines), times.time(lines))
