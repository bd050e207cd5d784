"""BAL ("Bundle Adjustment in the Large") text problems: read, write, convert.

BAL camera: 9 numbers ``[w (3, angle-axis, radians), t (3), f (pixels), k1, k2]``;
a world point ``X`` projects as ``P = R(w) X + t``, ``p = -P[:2] / P[2]``,
``x = f (1 + k1 |p|^2 + k2 |p|^4) p`` (pixels from the principal point, y up).
File layout (whitespace separated): ``n_cam n_pt n_obs``, then ``n_obs`` lines
``cam pt x y``, then ``9 n_cam`` camera numbers and ``3 n_pt`` point numbers.

:func:`bal_to_problem` converts to the collinearity parametrisation of
:class:`~lunarmap.adjust.collinearity.FrameModel` (``R0 = R(w)``, ``C = -R^T t``,
corrections ``[w, C]`` start at zero), which projects identically.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..atomic import atomic_write
from ..errors import AdjustmentInputError
from .collinearity import FrameModel
from .problem import BundleProblem, ImageObservations, PointPriors
from .rotation import matrix_to_rotvec, rotate, rotvec_to_matrix

__all__ = ["BALData", "read_bal", "write_bal", "bal_to_problem", "problem_to_bal_cameras"]


@dataclass
class BALData:
    """Arrays of a BAL file (and its ``.meta.json`` sidecar, if any)."""

    cameras: NDArray[np.float64]   # (n_cam, 9)
    points: NDArray[np.float64]    # (n_pt, 3)
    cam_idx: NDArray[np.int64]
    pt_idx: NDArray[np.int64]
    obs: NDArray[np.float64]       # (n_obs, 2) pixels
    meta: dict = field(default_factory=dict)


def _stem(p: str) -> str:
    for suf in (".bal.txt", ".txt", ".bal"):
        if p.endswith(suf):
            return p[: -len(suf)]
    return p


def read_bal(path: str | os.PathLike, with_meta: bool = True) -> BALData:
    """Read a BAL text problem; a ``<stem>.meta.json`` next to it is read into ``meta``.

    Raises
    ------
    AdjustmentInputError
        Truncated file, non-numeric tokens, indices out of range or NaN values, a sidecar that is not a
        JSON object (the message names the file).
    """
    path = str(path)
    with open(path, "rb") as fh:
        tok = fh.read().split()
    try:
        n_cam, n_pt, n_obs = int(tok[0]), int(tok[1]), int(tok[2])
        if min(n_cam, n_pt, n_obs) < 0:
            raise AdjustmentInputError(f"{path}: negative count in the BAL header ({n_cam} {n_pt} {n_obs})")
        need = 3 + 4 * n_obs + 9 * n_cam + 3 * n_pt
        if len(tok) < need:
            raise AdjustmentInputError(f"{path}: truncated BAL file ({len(tok)} numbers, header implies {need})")
        o = np.array(tok[3:3 + 4 * n_obs], dtype=np.float64).reshape(n_obs, 4)
        s = 3 + 4 * n_obs
        cams = np.array(tok[s:s + 9 * n_cam], dtype=np.float64).reshape(n_cam, 9)
        s += 9 * n_cam
        pts = np.array(tok[s:s + 3 * n_pt], dtype=np.float64).reshape(n_pt, 3)
    except (ValueError, IndexError) as exc:
        raise AdjustmentInputError(f"{path}: not a BAL problem ({exc})") from exc
    for name, a in (("observations", o), ("cameras", cams), ("points", pts)):
        if not np.all(np.isfinite(a)):
            raise AdjustmentInputError(f"{path}: non-finite values among the {name}")
    if not np.all(o[:, :2] == np.round(o[:, :2])):
        raise AdjustmentInputError(f"{path}: camera or point index is not an integer")
    ci, pi = o[:, 0].astype(np.int64), o[:, 1].astype(np.int64)
    if n_obs and (ci.min() < 0 or ci.max() >= n_cam or pi.min() < 0 or pi.max() >= n_pt):
        raise AdjustmentInputError(f"{path}: camera or point index out of range")
    meta = {}
    mp = _stem(path) + ".meta.json"
    if with_meta and os.path.exists(mp):
        try:
            with open(mp, encoding="utf-8") as fh:
                meta = json.load(fh)
        except ValueError as exc:  # JSONDecodeError and UnicodeDecodeError both are
            raise AdjustmentInputError(f"{mp}: the BAL sidecar is not JSON ({exc})") from exc
        if not isinstance(meta, dict):
            raise AdjustmentInputError(f"{mp}: the BAL sidecar must hold a JSON object, got {type(meta).__name__}")
    return BALData(cams, pts, ci, pi, o[:, 2:4].copy(), meta)


def write_bal(path: str | os.PathLike, data: BALData) -> None:
    """Write a BAL text problem atomically (temporary file in the same folder, then rename)."""
    def write(tmp: Path) -> None:
        with open(tmp, "w") as fh:
            fh.write(f"{data.cameras.shape[0]} {data.points.shape[0]} {data.obs.shape[0]}\n")
            rows = np.empty(data.obs.shape[0], dtype=[("c", "i8"), ("p", "i8"), ("x", "f8"), ("y", "f8")])
            rows["c"], rows["p"], rows["x"], rows["y"] = data.cam_idx, data.pt_idx, data.obs[:, 0], data.obs[:, 1]
            np.savetxt(fh, rows, fmt=["%d", "%d", "%.6f", "%.6f"])
            np.savetxt(fh, data.cameras.reshape(-1, 1), fmt="%.17g")
            np.savetxt(fh, data.points.reshape(-1, 1), fmt="%.17g")

    atomic_write(path, write)


def bal_to_problem(data: BALData, control: NDArray | None = None, control_sigma: float = 0.0,
                   sigma_px: float = 1.0) -> BundleProblem:
    """A :class:`BundleProblem` equivalent to the BAL problem.

    Parameters
    ----------
    control : int array, optional
        Control-point indices (default: ``meta["control_points"]``), held fixed when
        ``control_sigma == 0`` else observed with that sigma (length unit of the file).
    sigma_px : float
        Sigma of the image coordinates, pixels (1 reproduces BAL's unweighted cost).
    """
    if control is None:
        control = data.meta.get("control_points", [])
    try:
        control = np.asarray(control, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise AdjustmentInputError(f"control points must be a list of point indices, got {control!r:.80}") from None
    if not np.all(control == np.round(control)) or (control.size and (control.min() < 0
                                                                      or control.max() >= len(data.points))):
        raise AdjustmentInputError(f"control point indices must be integers in [0, {len(data.points)})")
    control = control.astype(np.int64)
    R0 = rotvec_to_matrix(data.cameras[:, 0:3])
    C = -rotate(-data.cameras[:, 0:3], data.cameras[:, 3:6])
    model = FrameModel(R0, data.cameras[:, 6], data.cameras[:, 7], data.cameras[:, 8])
    params = np.column_stack([np.zeros((len(C), 3)), C])
    priors = None
    if control.size:
        priors = PointPriors(control, data.points[control], np.full((control.size, 3), control_sigma))
    return BundleProblem(model, params, data.points,
                         ImageObservations(data.cam_idx, data.pt_idx, data.obs, sigma_px), priors)


def problem_to_bal_cameras(model: FrameModel, params: NDArray) -> NDArray:
    """BAL 9-vectors ``(n, 9)`` of adjusted frame cameras."""
    R = model.rotation(params)
    w = matrix_to_rotvec(R)
    t = -np.einsum("nij,nj->ni", R, params[:, 3:6])
    return np.column_stack([w, t, model.f, model.k1, model.k2])
