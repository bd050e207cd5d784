"""The adjustment's frame models against oracles that share none of their code.

* ``FrameModel`` (the BAL collinearity, compiled and numpy paths) against ``FrameCamera`` over a grid
  of pixels at three heights, both directions: pixel -> ground by the camera -> pixel by the model,
  and ground -> pixel by both; cameras converted to BAL the textbook way (``R_bal = diag(1, -1, -1)
  R_body->sensor``, ``t = -R C``, ``f`` in pixels);
* ``FrameModel`` with non-zero corrections against a collinearity written here, with its own
  Rodrigues rotation (no lunarmap rotation code);
* ``SensorImageModel`` (the rigorous frame path of the adjustment: ``FrameStack``, compiled, with
  radial distortion) against ``FrameCorrections.apply`` -> ``FrameCamera.ground_to_image``, the
  camera's own projection, over the same grid, with non-zero corrections.

Measured figures are printed (``pytest -s``); all are asserted at <= 1e-9 px.
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import require
from lunarmap.adjust import FrameModel, SensorImageModel
from lunarmap.simulate import frame_block
from lunarmap.simulate.blocks import clementine_interior

TOL_PX = 1e-9
HEIGHTS = (-2000.0, 0.0, 2000.0)


def _rodrigues(w: np.ndarray) -> np.ndarray:
    """Rotation matrices of angle-axis vectors ``(n, 3)``, written out (R = I + sin K + (1 - cos) K^2)."""
    out = np.empty((len(w), 3, 3))
    for i, v in enumerate(w):
        th = float(np.sqrt(v @ v))
        if th == 0.0:
            out[i] = np.eye(3)
            continue
        kx, ky, kz = v / th
        K = np.array([[0.0, -kz, ky], [kz, 0.0, -kx], [-ky, kx, 0.0]])
        out[i] = np.eye(3) + np.sin(th) * K + (1.0 - np.cos(th)) * (K @ K)
    return out


def _collinearity(R: np.ndarray, C: np.ndarray, f: float, X: np.ndarray) -> np.ndarray:
    """BAL pixels of points ``X`` for cameras ``R`` (body -> BAL camera) at centres ``C``."""
    P = np.einsum("nij,nj->ni", R, X - C)
    return -f * P[:, :2] / P[:, 2:3]


def _grid(cam, n_l=9, n_s=11):
    li, sa = np.meshgrid(np.linspace(0.0, cam.n_lines, n_l), np.linspace(0.0, cam.n_samples, n_s), indexing="ij")
    return li.ravel(), sa.ravel()


@pytest.fixture(scope="module")
def block():
    return frame_block(orbits=2, per_orbit=3, points=40, seed=11, interior=clementine_interior(odk=None))


def _bal_setup(cameras):
    """BAL reference rotations (body -> BAL camera), centres and focal length of FrameCameras."""
    R0 = np.array([np.diag([1.0, -1.0, -1.0]) @ c.eo.rotation_at(c.time).T for c in cameras])
    C = np.array([c.eo.position_at(c.time) for c in cameras])
    io = cameras[0].interior
    return R0, C, io.focal_length / io.pixel_pitch, io


@pytest.mark.parametrize("path", ["compiled", "numpy"])
def test_frame_model_equals_frame_camera_on_a_grid_both_ways(block, path, monkeypatch):
    import lunarmap.adjust.collinearity as collinearity

    if path == "numpy":
        monkeypatch.setattr(collinearity, "_frame_kernel", None)
    else:
        require(collinearity._frame_kernel is not None, "numba (the compiled frame kernel)")
    cams = block.nav_cameras
    R0, C, f, io = _bal_setup(cams)
    model = FrameModel(R0, f)
    params = np.column_stack([np.zeros((len(cams), 3)), C])
    worst = {"pixel->ground->pixel": 0.0, "ground->pixel": 0.0}
    rng = np.random.default_rng(4)
    for i, cam in enumerate(cams):
        li, sa = _grid(cam)
        for h in HEIGHTS:
            X = cam.image_to_ground(li, sa, height=h)                        # the camera: pixel -> ground
            xy = model.project(params, np.full(li.size, i), X)               # the model: ground -> pixel
            back_l, back_s = io.detector_center_line - xy[:, 1], xy[:, 0] + io.detector_center_sample
            worst["pixel->ground->pixel"] = max(worst["pixel->ground->pixel"],
                                                np.max(np.abs(back_l - li)), np.max(np.abs(back_s - sa)))
            # ground -> pixel by both, at points off the grid
            Y = cam.image_to_ground(rng.uniform(0, cam.n_lines, 50), rng.uniform(0, cam.n_samples, 50), height=h)
            cl, cs = cam.ground_to_image(Y, within_image=False)
            xy = model.project(params, np.full(50, i), Y)
            worst["ground->pixel"] = max(worst["ground->pixel"], np.max(np.abs(io.detector_center_line - xy[:, 1] - cl)),
                                         np.max(np.abs(xy[:, 0] + io.detector_center_sample - cs)))
    print(f"FrameModel ({path}) vs FrameCamera, {len(cams)} images x {li.size} pixels x {len(HEIGHTS)} heights:",
          {k: f"{v:.1e} px" for k, v in worst.items()})
    assert max(worst.values()) <= TOL_PX, worst


@pytest.mark.parametrize("path", ["compiled", "numpy"])
def test_frame_model_with_corrections_equals_handwritten_collinearity(block, path, monkeypatch):
    import lunarmap.adjust.collinearity as collinearity

    if path == "numpy":
        monkeypatch.setattr(collinearity, "_frame_kernel", None)
    cams = block.nav_cameras
    R0, C, f, _ = _bal_setup(cams)
    rng = np.random.default_rng(8)
    w = rng.normal(0.0, 2e-3, (len(cams), 3))                  # ~0.1 degree attitude corrections
    dC = rng.normal(0.0, 200.0, (len(cams), 3))                # ~200 m position corrections
    params = np.column_stack([w, C + dC])
    idx = np.repeat(np.arange(len(cams)), 99)
    X = np.concatenate([cam.image_to_ground(*_grid(cam), height=h)
                        for cam, h in zip(cams, np.resize(HEIGHTS, len(cams)))])
    got = FrameModel(R0, f).project(params, idx, X)
    want = _collinearity((_rodrigues(w) @ R0)[idx], (C + dC)[idx], f, X)
    err = float(np.max(np.abs(got - want)))
    print(f"FrameModel ({path}) with corrections vs hand-written collinearity: {err:.1e} px over {idx.size} points")
    assert err <= TOL_PX


def test_rigorous_frame_path_equals_applied_corrections_on_a_grid():
    """The adjustment's own frame path (SensorImageModel -> FrameStack, radial distortion) vs FrameCamera."""
    sb = frame_block(orbits=2, per_orbit=3, points=40, seed=12)          # clementine_interior: radial OD_K
    cams = sb.nav_cameras
    model = SensorImageModel(cams)
    rng = np.random.default_rng(9)
    params = np.column_stack([rng.normal(0.0, 1e-4, (len(cams), 3)), rng.normal(0.0, 50.0, (len(cams), 3))])
    worst = {"pixel->ground->pixel": 0.0, "ground->pixel": 0.0}
    for i, cam in enumerate(cams):
        moved = cam.corrections().apply(params[i])                      # the camera with the corrections applied
        li, sa = _grid(moved)
        for h in HEIGHTS:
            X = moved.image_to_ground(li, sa, height=h)
            pix = model.project(params, np.full(li.size, i), X)
            worst["pixel->ground->pixel"] = max(worst["pixel->ground->pixel"],
                                                np.max(np.abs(pix - np.column_stack([li, sa]))))
            Y = X + rng.normal(0.0, 300.0, X.shape)
            cl, cs = moved.ground_to_image(Y, within_image=False)
            pix = model.project(params, np.full(li.size, i), Y)
            worst["ground->pixel"] = max(worst["ground->pixel"], np.max(np.abs(pix - np.column_stack([cl, cs]))))
    print(f"SensorImageModel vs FrameCamera with applied corrections: {({k: f'{v:.1e} px' for k, v in worst.items()})}")
    assert max(worst.values()) <= TOL_PX, worst
