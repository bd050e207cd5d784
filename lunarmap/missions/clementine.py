"""Clementine multi-orbit block through the real UVVIS camera, adjusted with navigation observations.

The DLR paper (``seeds/004``) adjusts Clementine UVVIS blocks of several orbits whose navigation
carries an offset and a drift per orbit. Here the same simulated set-up
(:func:`lunarmap.simulate.frame_block`: parallel north-bound strips, 60 % forward and 30 % side
overlap, navigation = truth + per-orbit offsets and drifts + white noise, measurements projected by
the true cameras) runs through the **real** UVVIS interior orientation: the camera that
:func:`lunarmap.image_support` builds from the shared Clementine kernel set's IK and label
(89.874444 mm, 23 um pixels, 384 x 288, ``OD_K`` radial distortion of ISIS's
``CameraDistortionMap``; :func:`uvvis_interior`). :func:`adjust_multi_orbit` adjusts it through
the public block API (:func:`lunarmap.build_block` with a :class:`~lunarmap.adjust.NavigationSpec`,
:func:`lunarmap.solve`) and measures it against the truth: check points before and after, and the
errors of points, image corrections and per-orbit offsets and drifts divided by their posterior sigma.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

import numpy as np

from ..adjust import ControlNetwork, NavigationSpec, build_block
from ..adjust.block import BlockResult, solve_block
from ..adjust.solver import SolverOptions
from ..camera import InteriorOrientation
from ..camera.factory import interior_from_isd
from ..orientation.drivers import image_support
from ..simulate import SimulatedBlock, frame_block

__all__ = ["uvvis_interior", "clementine_multi_orbit", "block_inputs", "adjust_multi_orbit"]


def uvvis_interior(label: str | os.PathLike[str], metakernel: str | os.PathLike[str],
                   distortion: bool = True) -> InteriorOrientation:
    """The Clementine UVVIS interior orientation of a real image (label + kernels, through the driver)."""
    io = interior_from_isd(image_support(label, metakernel), distortion=distortion)
    return dataclasses.replace(io, name=f"{io.name} (real IK)")


def clementine_multi_orbit(interior: InteriorOrientation, orbits: int = 4, per_orbit: int = 12, points: int = 1500,
                           n_control: int = 4, n_check: int = 40, seed: int = 0, **kwargs: Any) -> SimulatedBlock:
    """A Clementine-like block of ``orbits`` strips through ``interior`` (see :func:`lunarmap.simulate.frame_block`).

    Keyword arguments go to :func:`~lunarmap.simulate.frame_block` (navigation error sigmas, altitude, ...).
    """
    return frame_block(orbits=orbits, per_orbit=per_orbit, points=points, n_control=n_control, n_check=n_check,
                       interior=interior, seed=seed, **kwargs)


def _names(sb: SimulatedBlock) -> list[str]:
    return [f"orbit{int(o)}_img{i:02d}" for i, o in enumerate(sb.orbit)]


def block_inputs(sb: SimulatedBlock, offset: str = "observed",
                 drift: str = "observed") -> tuple[dict, ControlNetwork, NavigationSpec]:
    """The navigation cameras by name, a control network (tie, control, check points) and the navigation
    spec of a simulated block, as a user would hand them to :func:`lunarmap.build_block`."""
    names = _names(sb)
    m = sb.measurements
    n = sb.true_points.shape[0]
    kind = np.array(["tie"] * n, dtype=object)
    kind[sb.control], kind[sb.check] = "control", "check"
    xyz = np.full((n, 3), np.nan)
    xyz[sb.control] = sb.control_xyz
    xyz[sb.check] = sb.true_points[sb.check]
    cov = np.full((n, 3, 3), np.nan)
    cov[sb.control] = np.eye(3) * sb.control_sigma ** 2
    net = ControlNetwork(point_id=np.array([f"P{i}" for i in range(n)]), point_type=kind, xyz=xyz, measure_point=m.pt_idx,
                         measure_image=m.cam_idx, line_sample=m.xy, measure_sigma=np.full(m.pt_idx.size, m.sigma),
                         image_id=np.asarray(names), xyz_cov=cov)
    spec = NavigationSpec(orbit={nm: int(o) for nm, o in zip(names, sb.orbit)},
                          position_sigma=float(sb.nav_sigma[3]), attitude_sigma=float(sb.nav_sigma[0]),
                          offset=offset, drift=drift, offset_sigma=list(sb.offset_sigma), drift_sigma=list(sb.drift_sigma))
    return dict(zip(names, sb.nav_cameras)), net, spec


def adjust_multi_orbit(sb: SimulatedBlock, offset: str = "observed",
                       drift: str = "observed") -> tuple[BlockResult, dict[str, Any]]:
    """Adjust a simulated block with navigation observations; return the result and its figures against truth.

    Figures: ``sigma0``; check points' RMS east/north/up before (navigation, forward intersection) and
    after, metres, and errors/sigma RMS; normalised-error RMS (error / posterior sigma) of all points,
    of the image corrections (6 per image) and of the per-orbit offsets and drifts that are estimated.
    """
    cams, net, spec = block_inputs(sb, offset, drift)
    block = build_block(cams, net, navigation=spec)
    res = solve_block(block, SolverOptions(ftol=1e-9))
    r = res.result
    prec = r.precision()
    before = res.check_points(block.problem.points)
    after = res.check_points()
    e_p = r.points - sb.true_points
    z_p = e_p / np.sqrt(np.diagonal(prec.pt_cov, axis1=1, axis2=2))
    e_c = r.cam_params - sb.true_params
    z_c = e_c / np.sqrt(np.diagonal(prec.cam_cov, axis1=1, axis2=2))
    nav = block.navigation
    assert nav is not None          # the Clementine block has navigation observations
    truth_x = np.concatenate([sb.true_offsets.ravel(), sb.true_drifts.ravel()])
    free = nav.extra_free()
    z_x = (r.extra - truth_x)[free] / np.sqrt(np.diag(prec.extra_cov))[free]
    figures = {
        "images": block.problem.n_images, "points": block.problem.n_points, "observations": block.problem.obs.n,
        "sigma0": float(res.sigma0), "iterations": int(r.iterations),
        "check_rms_before_m": np.asarray(before.attrs["rms_m"]), "check_rms_after_m": np.asarray(after.attrs["rms_m"]),
        "check_z_rms": float(after.attrs["normalized_rms"]),
        "points_z_rms": float(np.sqrt(np.mean(z_p ** 2))), "images_z_rms": float(np.sqrt(np.mean(z_c ** 2))),
        "offsets_drifts_z_rms": float(np.sqrt(np.mean(z_x ** 2))), "offsets_drifts_estimated": int(free.sum()),
        "offsets_drifts_within_2_sigma": float(np.mean(np.abs(z_x) < 2.0)),
    }
    return res, figures
