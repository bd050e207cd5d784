"""The demo behind ``make demo`` / ``lunarmap demo``: the whole chain on a synthetic mission with known truth.

1. **Mission**: :func:`lunarmap.synthetic.write_block_mission` writes a 12-image block over one site on
   3 orbits (NAC-like and Kaguya-TC-like pushbrooms, a Clementine-like frame camera, with
   ``lrolrocnac`` / ``kaguyalism`` / ``radial`` distortion) as SPICE kernels: a TRUTH set and a
   NAVIGATION set whose spacecraft trajectory and attitude carry per-orbit offsets and drifts.
2. **Images**: :func:`lunarmap.simulate.render_block` renders every image from a synthetic DTM and
   albedo through the TRUTH cameras.
3. **Cameras**: from the labels and the NAVIGATION kernels (:func:`lunarmap.image_support`,
   :func:`lunarmap.camera_from_isd`), as a user would load a mission.
4. **Tie points** with the matcher (:func:`lunarmap.find_tiepoints`, predictions through the navigation
   cameras), plus a few control points (coordinates from a reference with 0.5 m sigma) and check
   points measured in the images (0.3 px).
5. **Adjustment** on the rigorous cameras (:func:`lunarmap.build_block`, :func:`lunarmap.solve`) with
   navigation observations and per-orbit offsets and drifts, the tie points' variance factor estimated
   from the data (:mod:`lunarmap.adjust.variance`).
6. **Adjusted kernels**: :func:`lunarmap.write_adjusted` writes an SPK, a CK and a meta-kernel layered
   over the navigation set (and adjusted ISDs); the cameras are reloaded from the labels through that
   meta-kernel and compared with the adjusted cameras; each adjusted camera's cubic RFM is fitted
   (``<image>_RPC.TXT``).

The report gives check-point errors against truth before and after, the posterior sigma they should
match, and the camera position errors of the navigation and of the adjustment.
"""

from __future__ import annotations

import logging
import os
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

__all__ = ["DemoReport", "run_demo"]

_log = logging.getLogger(__name__)


@dataclass
class DemoReport:
    """Figures of one demo run (SI units: metres, pixels, seconds)."""

    folder: Path
    images: list[str]
    n_tie_points: int = 0
    n_observations: int = 0
    sigma0: float = float("nan")
    tie_sigma_scale: float = float("nan")
    check_rms_before: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    check_rms_after: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    check_sigma_after: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    check_normalized_rms: float = float("nan")
    camera_error_before: float = float("nan")
    camera_error_after: float = float("nan")
    camera_normalized_rms: float = float("nan")
    reload_position_mm: float = float("nan")
    reload_px: float = float("nan")
    rpc_check_rms_px: dict[str, float] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    files: dict[str, Path] = field(default_factory=dict)

    def text(self) -> str:
        """A printable summary."""
        b, a, s = self.check_rms_before, self.check_rms_after, self.check_sigma_after
        b3, a3, s3 = (float(np.sqrt(np.sum(v ** 2))) for v in (b, a, s))
        lines = [
            f"lunarmap demo in {self.folder}",
            f"  block: {len(self.images)} images ({', '.join(self.images[:4])}, ...) on 3 orbits, NAVIGATION "
            "kernels with per-orbit offsets and drifts",
            f"  tie points from the matcher: {self.n_tie_points} points, {self.n_observations} image observations",
            f"  adjustment on the rigorous cameras: sigma0 {self.sigma0:.3f} (tie-point sigma x "
            f"{self.tie_sigma_scale:.2f} from variance-component estimation)",
            "  check points vs truth, RMS east / north / up / 3-D (m):",
            f"    before (navigation): {b[0]:8.3f} {b[1]:8.3f} {b[2]:8.3f} {b3:8.3f}",
            f"    after (adjusted):    {a[0]:8.3f} {a[1]:8.3f} {a[2]:8.3f} {a3:8.3f}   ({b3 / a3:.0f}x smaller)",
            f"    posterior sigma:     {s[0]:8.3f} {s[1]:8.3f} {s[2]:8.3f} {s3:8.3f}   "
            f"(errors / sigma: RMS {self.check_normalized_rms:.2f}; 1 if the precision is right)",
            f"  camera positions (image centre) vs truth, RMS (m): navigation {self.camera_error_before:.2f}, "
            f"adjusted {self.camera_error_after:.2f} (errors / posterior sigma: RMS {self.camera_normalized_rms:.2f}; "
            "narrow fields of view trade position for attitude)",
            f"  adjusted kernels reloaded through {self.files.get('metakernel', Path('?')).name}: cameras agree "
            f"with the adjusted ones to {self.reload_position_mm:.2e} mm / {self.reload_px:.2e} px",
            "  cubic RFMs of the adjusted cameras (<image>_RPC.TXT), check RMS: " + ", ".join(
                f"{k} {v:.1e} px" for k, v in self.rpc_check_rms_px.items()),
            "  time (s): " + ", ".join(f"{k} {v:.1f}" for k, v in self.seconds.items()),
        ]
        return "\n".join(lines)


def _network_of(points: xr.Dataset, kind: str, prefix: str, sigma_m: float = 0.0,
                rng: np.random.Generator | None = None) -> Any:
    """Control or check points measured in the images (:func:`lunarmap.simulate.block_check_points`) as a network."""
    from .adjust import ControlNetwork

    ids, inverse = np.unique(points["point_id"].values, return_inverse=True)
    xyz = points["xyz"].values[ids]
    cov = None
    if kind == "control":
        assert rng is not None
        xyz = xyz + rng.normal(0.0, sigma_m, xyz.shape)       # a reference DTM/altimetry with sigma_m
        cov = np.repeat((sigma_m ** 2 * np.eye(3))[None], ids.size, axis=0)
    return ControlNetwork([f"{prefix}{i}" for i in ids], [kind] * ids.size, xyz, inverse,
                          points["image_id"].values, np.column_stack([points["line"].values, points["sample"].values]),
                          np.column_stack([points["sigma_line"].values, points["sigma_sample"].values]),
                          np.asarray(points["image"].values).astype(str), xyz_cov=cov)


def _grid(cam: Any, n: int = 9) -> tuple[np.ndarray, np.ndarray]:
    lines = np.linspace(0.5, cam.n_lines - 0.5, n)
    samples = np.linspace(0.5, cam.n_samples - 0.5, n)
    L, S = np.meshgrid(lines, samples, indexing="ij")
    return L.ravel(), S.ravel()


def run_demo(output: str | os.PathLike[str] = "demo_output", seed: int = 0, quick: bool = False) -> DemoReport:
    """Run the chain (module docstring) in ``output``; returns its figures.

    Parameters
    ----------
    output : path-like
        Folder for everything the demo writes (created).
    seed : int
        Seed of the mission, scene and measurements.
    quick : bool
        Fewer interest points and check points (for tests): same chain, about half the time.
    """
    import lunarmap

    from .adjust import NavigationSpec, SolverOptions, merge_networks, network_from_tiepoints, write_network
    from .adjust.block import BlockResult
    from .adjust.variance import estimate_image_variances
    from .matching import DetectParams, MatchParams, TiePointParams, write_tiepoints
    from .rpc import fit_rpc, write_rpc_txt
    from .simulate import block_cameras, block_check_points, render_block
    from .synthetic import write_block_mission

    out = Path(output)
    out.mkdir(parents=True, exist_ok=True)
    seconds: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(name: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        seconds[name] = now - clock
        clock = now
        _log.info("%s done (%.1f s)", name, seconds[name])

    bm = write_block_mission(out / "mission", seed=seed)
    names = list(bm.image_names)
    man = bm.manifest
    lap("mission")
    rendered = render_block(bm, supersample=2)
    lap("render")

    isds = {n: lunarmap.image_support(bm.label(n), bm.navigation_metakernel) for n in names}
    cams = {n: lunarmap.camera_from_isd(isds[n]) for n in names}
    for n, isd in isds.items():
        isd.write_json(bm.folder / f"{n}.navigation.json")
    lap("cameras")

    # the navigation predictions of images of different orbits are tens of metres apart: a wide NCC search
    params = TiePointParams(detect=DetectParams(cell=64 if quick else 48),
                            match=MatchParams(search=128.0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")      # blank/edge tiles are expected on rolled images
        ties = lunarmap.find_tiepoints(rendered.images, cams, params=params, scheduler="threads")
    write_tiepoints(ties, out / "tiepoints.nc")
    lap("tie points")

    truth = block_cameras(bm, "truth")
    rng = np.random.default_rng(seed + 1)
    control = block_check_points(bm, 6, sigma_px=0.3, seed=seed + 11, cameras=truth)
    check = block_check_points(bm, 12 if quick else 20, sigma_px=0.3, seed=seed + 12, cameras=truth)
    net = merge_networks(network_from_tiepoints(ties), _network_of(control, "control", "C", 0.5, rng),
                         _network_of(check, "check", "K"))
    write_network(net, out / "control_network.nc")
    # navigation: per image 0.5 m / 1 urad (the random part); per orbit and camera (attitude corrections are
    # in each sensor's frame) an offset and a drift observed with the magnitudes the navigation is known to have
    orbit = {n: f"{man['images'][n]['orbit']}-{man['images'][n]['kind']}" for n in names}
    spec = NavigationSpec(orbit=orbit, position_sigma=0.5, attitude_sigma=1e-6, position_rate_sigma=1.0,
                          attitude_rate_sigma=1e-6, offset="observed", drift="observed",
                          offset_sigma=[50e-6] * 3 + [50.0] * 3, drift_sigma=[1e-6] * 3 + [1.0] * 3)
    block = lunarmap.build_block(cams, net, degree=1, navigation=spec)
    x0 = block.problem.points.copy()
    groups = np.where(block.network.point_type[block.problem.obs.pt_idx] == "tie", 0, 1)
    est = estimate_image_variances(block.problem, groups, np.array([True, False]), SolverOptions(ftol=1e-10))
    result = BlockResult(block, est.result)
    lap("adjustment")

    before, after = result.check_points(x0), result.check_points()
    adjusted = result.adjusted_sensors()
    written = lunarmap.write_adjusted(result, isds, out, bm.navigation_metakernel, name="adjusted")
    lap("adjusted kernels")

    # reload from the unchanged labels through the layered meta-kernel
    d_pos, d_px = 0.0, 0.0
    for n in names:
        again = lunarmap.load_camera(bm.label(n), written.metakernel)
        L, S = _grid(again)
        X = adjusted[n].image_to_ground(L, S, height=0.0)
        la, sa = again.ground_to_image(X, within_image=False)
        d_px = max(d_px, float(np.max(np.hypot(la - L, sa - S))))
        d_pos = max(d_pos, float(np.max(np.linalg.norm(again.rays(L, S)[0] - adjusted[n].rays(L, S)[0], axis=1))))
    lap("reload")

    def centre_positions(sensors: dict[str, Any]) -> np.ndarray:
        return np.array([sensors[n].rays(0.5 * sensors[n].n_lines, 0.5 * sensors[n].n_samples)[0] for n in names])

    p_true, p_nav, p_adj = centre_positions(truth), centre_positions(cams), centre_positions(adjusted)
    # posterior sigma of the position correction at the image centre (c_x, c_y, c_z; tau = 0 for line scans)
    sig = result.corrections()["sigma"].values[:, 3:6]      # columns 3-5: c (frame) / c_0 (line scan)
    z = (p_adj - p_true) / sig
    rpc_rms: dict[str, float] = {}
    for n in names:
        fit = fit_rpc(adjusted[n], (-300.0, 300.0))
        write_rpc_txt(fit.model, out / f"{n}_RPC.TXT")
        kind = str(man["images"][n]["kind"]).split("_")[0]
        rpc_rms[kind] = max(rpc_rms.get(kind, 0.0), float(fit.check.rms))
    lap("RPCs")
    return DemoReport(
        folder=out, images=names, n_tie_points=int(np.unique(ties["point_id"].values).size),
        n_observations=int(ties.sizes["observation"]), sigma0=result.sigma0, tie_sigma_scale=float(est.scale[0]),
        check_rms_before=np.asarray(before.attrs["rms_m"]), check_rms_after=np.asarray(after.attrs["rms_m"]),
        check_sigma_after=np.sqrt(np.mean(after["sigma"].values ** 2, axis=0)),
        check_normalized_rms=float(after.attrs["normalized_rms"]),
        camera_error_before=float(np.sqrt(np.mean(np.sum((p_nav - p_true) ** 2, axis=1)))),
        camera_error_after=float(np.sqrt(np.mean(np.sum((p_adj - p_true) ** 2, axis=1)))),
        camera_normalized_rms=float(np.sqrt(np.mean(z ** 2))), reload_position_mm=1e3 * d_pos, reload_px=d_px,
        rpc_check_rms_px=rpc_rms, seconds=seconds,
        files={"metakernel": written.metakernel, "tiepoints": out / "tiepoints.nc",
               "network": out / "control_network.nc", "navigation": bm.navigation_metakernel,
               "truth": bm.truth_metakernel})
