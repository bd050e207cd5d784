"""Exterior orientation: interpolation against SPICE at off-sample epochs, rotations, xarray I/O."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import spiceypy
import xarray as xr

from lunarmap.errors import InvalidInputError
from lunarmap.orientation import ExteriorOrientation, matrix_to_quat, quat_to_matrix
from lunarmap.orientation.drivers import image_support
from lunarmap.spice import KernelSet, kernels


def test_quaternion_helpers_match_spice():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(200, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    ours = quat_to_matrix(q)
    for i in range(200):
        assert np.abs(ours[i] - np.asarray(spiceypy.q2m(q[i]))).max() < 1e-15
        back = matrix_to_quat(ours[i])
        spice_q = np.asarray(spiceypy.m2q(ours[i]))
        assert min(np.abs(back - spice_q).max(), np.abs(back + spice_q).max()) < 1e-14
    # near 180-degree rotations (small w) stay accurate
    m = quat_to_matrix(np.array([1e-9, 0.0, 0.6, 0.8]))
    assert np.abs(quat_to_matrix(matrix_to_quat(m)) - m).max() < 1e-14


@pytest.fixture(scope="module")
def nac_eo(sim_mission):
    isd = image_support(sim_mission.parent / "sim_nac_85n.lbl", sim_mission)
    return isd, isd.exterior_orientation()


def test_interpolated_eo_equals_spice_between_samples(nac_eo, sim_mission):
    """Sampled every 10 lines (3 ms), interpolated: millimetres and nanoradians against SPICE."""
    isd, eo = nac_eo
    rng = np.random.default_rng(5)
    t = rng.uniform(eo.times[0], eo.times[-1], 300)
    pos, rot = eo.position_at(t), eo.rotation_at(t)
    vel = eo.velocity_at(t)
    with kernels(KernelSet.from_metakernel(sim_mission)):
        truth = np.array([spiceypy.spkez(-990, eo.epoch + ti, "IAU_MOON", "NONE", 301)[0] for ti in t]) * 1000
        truth_rot = np.array([spiceypy.pxform("SIM_NAC", "IAU_MOON", eo.epoch + ti) for ti in t])
    assert np.linalg.norm(pos - truth[:, :3], axis=1).max() < 1e-3  # 1 mm
    assert np.linalg.norm(vel - truth[:, 3:], axis=1).max() < 1e-3  # 1 mm/s
    # |R1 - R2| (Frobenius) / sqrt(2) is the rotation angle for small angles; arccos(trace) is too coarse
    ang = np.linalg.norm(rot - truth_rot, axis=(1, 2)) / np.sqrt(2)
    assert ang.max() < 2e-9  # rad: 0.1 mm at 50 km range


def test_eo_to_dataset_round_trip_netcdf_and_pickle(nac_eo, tmp_path):
    _, eo = nac_eo
    ds = eo.to_dataset()
    assert ds["position"].attrs["units"] == "m" and ds.sizes["time"] == eo.times.size
    path = tmp_path / "eo.nc"
    ds.to_netcdf(path)
    with xr.open_dataset(path) as loaded:
        eo2 = ExteriorOrientation.from_dataset(loaded.load())
    t = np.linspace(*eo.time_range, 50)
    assert np.abs(eo2.position_at(t) - eo.position_at(t)).max() == 0.0
    eo3 = pickle.loads(pickle.dumps(eo))
    assert np.abs(eo3.rotation_at(t) - eo.rotation_at(t)).max() == 0.0
    for _ in range(3):  # repeated round trips are bit-identical (no re-normalisation drift)
        eo3 = pickle.loads(pickle.dumps(eo3))
    assert np.array_equal(eo3.quaternions, eo.quaternions) and np.array_equal(eo3.positions, eo.positions)


def test_eo_rejects_bad_samples():
    good = dict(epoch=0.0, times=[0.0, 1.0], positions=np.ones((2, 3)), velocities=np.zeros((2, 3)),
                quaternions=[[1, 0, 0, 0]] * 2, sun_times=[0.0], sun_positions=[[1.0, 0, 0]])
    ExteriorOrientation(**good)
    with pytest.raises(InvalidInputError, match="positions"):
        ExteriorOrientation(**{**good, "positions": [[np.nan, 0, 0], [1, 1, 1]]})
    with pytest.raises(InvalidInputError, match="increasing"):
        ExteriorOrientation(**{**good, "times": [1.0, 0.0]})
    eo = ExteriorOrientation(**good)
    with pytest.raises(InvalidInputError):
        eo.position_at([np.nan])
