"""Distortion models: published formulas, exact inverses, registry."""

from __future__ import annotations

import numpy as np
import pytest

from lunarmap.camera import (
    DISTORTION_MODELS,
    KaguyaLismDistortion,
    LroNacDistortion,
    NoDistortion,
    RadialDistortion,
    distortion_from_interior,
    make_distortion,
)
from lunarmap.errors import InvalidInputError
from lunarmap.simulate.orbits import frame_interior, nac_like_interior

KAGUYA_BLOCK = {"x": [1e-3, 2e-3, -3e-4, 1e-5], "y": [-2e-3, 1e-3, 2e-4, -1e-5],
                "boresight_x": 0.01, "boresight_y": -0.02}

MODELS = {
    "none": make_distortion("none"),
    "lrolrocnac": make_distortion("lrolrocnac", {"coefficients": [1.81e-5]}),
    "radial": make_distortion("radial", {"coefficients": [0.0, -2.42e-5, 0.0]}),
    "radial-strong": make_distortion("radial", {"coefficients": [1e-3, 3e-4, -2e-7]}),
    "kaguyalism": make_distortion("kaguyalism", KAGUYA_BLOCK),
}


@pytest.fixture(scope="module")
def points() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(42)
    xy = rng.uniform(-20.0, 20.0, size=(2, 20_000))
    # include the origin and the axes, where radial Jacobians are special
    x = np.concatenate([xy[0], [0.0, 0.0, 5.0, 0.0]])
    y = np.concatenate([xy[1], [0.0, 5.0, 0.0, -17.7]])
    return x, y


@pytest.mark.parametrize("name", sorted(MODELS))
def test_round_trip_both_ways(name: str, points: tuple[np.ndarray, np.ndarray]) -> None:
    model = MODELS[name]
    x, y = points
    ux, uy = model.undistort(x, y)
    dx, dy = model.distort(ux, uy)
    assert np.max(np.hypot(dx - x, dy - y)) < 1e-9
    dx, dy = model.distort(x, y)
    ux, uy = model.undistort(dx, dy)
    assert np.max(np.hypot(ux - x, uy - y)) < 1e-9


def test_lroc_nac_known_value() -> None:
    # ISIS LroNarrowAngleDistortionMap::SetFocalPlane: uy = dy / (1 + k1 dy^2), ux = dx.
    # dy = 10 mm, k1 = 1.81e-5: uy = 10 / 1.00181 = 9.981932701809724 mm.
    model = LroNacDistortion(1.81e-5)
    ux, uy = model.undistort(1.0, 10.0)
    assert ux == 1.0
    assert uy == pytest.approx(9.981932701809724, abs=1e-12)
    dx, dy = model.distort(1.0, 9.981932701809724)
    assert dy == pytest.approx(10.0, abs=1e-12)


def test_lroc_nac_distorts_only_samples_and_has_no_root_far_off() -> None:
    model = LroNacDistortion(1.81e-5)
    dx, dy = model.distort([3.0, 0.0], [0.0, 200.0])
    assert dx[0] == 3.0 and dy[0] == 0.0
    assert np.isnan(dy[1])  # |uy| > 1 / (2 sqrt(k1)) = 117.5 mm


def test_radial_known_value() -> None:
    # ISIS CameraDistortionMap::SetFocalPlane: u = d (1 - (k0 + k1 r^2 + k2 r^4)).
    # d = (3, 4) mm, r^2 = 25, OD_K = (0, -2.42e-5, 0): factor 1 + 6.05e-4.
    model = RadialDistortion([0.0, -2.42e-5, 0.0])
    ux, uy = model.undistort(3.0, 4.0)
    assert ux == pytest.approx(3.001815, abs=1e-12)
    assert uy == pytest.approx(4.00242, abs=1e-12)


def test_kaguya_known_value() -> None:
    # usgscsm removeDistortion KAGUYALISM: u = d + poly(r) + boresight, r = |d| = 5 mm.
    # x: 1e-3 + 2e-3*5 - 3e-4*25 + 1e-5*125 = 0.00475; +0.01 boresight -> 3.01475
    # y: -2e-3 + 1e-3*5 + 2e-4*25 - 1e-5*125 = 0.00675; -0.02 boresight -> 3.98675
    model = KaguyaLismDistortion(**KAGUYA_BLOCK)
    ux, uy = model.undistort(3.0, 4.0)
    assert ux == pytest.approx(3.01475, abs=1e-12)
    assert uy == pytest.approx(3.98675, abs=1e-12)


def test_none_is_identity_and_copies() -> None:
    x = np.array([1.0, 2.0])
    ux, uy = NoDistortion().undistort(x, 3.0)
    assert np.array_equal(ux, x) and np.array_equal(uy, [3.0, 3.0])
    ux[0] = 99.0
    assert x[0] == 1.0


def test_registry_and_errors() -> None:
    from lunarmap.orientation.distortion_schema import DISTORTION_SCHEMAS

    assert set(DISTORTION_MODELS) == {"none", "lrolrocnac", "radial", "kaguyalism",
                                      "lunarorbiter", "apollometric",   # film cameras, issue 13
                                      "transverse", "radtan", "dawnfc", "kplo_shadowcam"}   # usgscsm's, issue 26
    # the ISD reader validates blocks against the orientation-level schema: the same names
    assert set(DISTORTION_SCHEMAS) == set(DISTORTION_MODELS)
    assert isinstance(make_distortion("LROLROCNAC", {"coefficients": [1e-5]}), LroNacDistortion)
    assert isinstance(make_distortion("radial", {"coefficients": [0.0, 1e-5]}), RadialDistortion)
    with pytest.raises(InvalidInputError, match="unknown distortion model"):
        make_distortion("brown-conrady", {})
    with pytest.raises(InvalidInputError, match="exactly 1"):
        make_distortion("lrolrocnac", {"coefficients": [1.0, 2.0]})
    with pytest.raises(InvalidInputError, match="coefficients"):
        make_distortion("radial", {})
    with pytest.raises(InvalidInputError, match="boresight|'x'|'y'"):
        make_distortion("kaguyalism", {"x": [0.0]})


def test_from_interior() -> None:
    assert isinstance(distortion_from_interior(nac_like_interior()), LroNacDistortion)
    assert isinstance(distortion_from_interior(frame_interior()), RadialDistortion)
    assert isinstance(distortion_from_interior(frame_interior(None)), NoDistortion)


@pytest.mark.parametrize("name", sorted(MODELS))
def test_broadcast_arrays_equal_point_by_point_values(name: str) -> None:
    """Inputs of different shapes broadcast, and every element equals the model at that one point."""
    model = MODELS[name]
    x = np.array([[-12.0, 0.0, 3.5], [7.25, -0.5, 15.0]])          # (2, 3)
    y = np.array([4.0, -9.0, 0.25])                                   # (3,): broadcasts along the rows
    for fn in (model.distort, model.undistort):
        ux, uy = fn(x, y)
        assert ux.shape == uy.shape == (2, 3)
        for i in range(2):
            for j in range(3):
                px, py = fn(float(x[i, j]), float(y[j]))
                assert np.shape(px) == () and (ux[i, j], uy[i, j]) == (px, py)
    jac = model.undistort_jacobian(x, y)
    assert jac.shape == (2, 3, 2, 2)
    np.testing.assert_array_equal(jac[1, 2], model.undistort_jacobian(15.0, 0.25))
    # a scalar against an array broadcasts too, and the arrays passed in are not modified
    x0 = x.copy()
    ux, uy = model.distort(x, 1.0)
    np.testing.assert_array_equal(x, x0)
    np.testing.assert_array_equal(ux[0], model.distort(x[0], np.ones(3))[0])
