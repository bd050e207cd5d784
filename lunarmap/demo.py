"""The demo behind ``make demo`` / ``lunarmap run --example``: the whole chain on a synthetic mission with known truth.

:func:`lunarmap.workflows.write_example` writes the data and ``run.toml``; :func:`lunarmap.workflows.run`
runs the chain as one dask graph; :func:`run_demo` then compares the results with the simulation's truth.

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

import json
import logging
import os
import time
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
    orbits: int = 3
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
    rpc_adjusted_check_rms_px: dict[str, float] = field(default_factory=dict)
    quality_control: str = ""
    seconds: dict[str, float] = field(default_factory=dict)
    files: dict[str, Path] = field(default_factory=dict)

    def text(self) -> str:
        """A printable summary."""
        b, a, s = self.check_rms_before, self.check_rms_after, self.check_sigma_after
        b3, a3, s3 = (float(np.sqrt(np.sum(v ** 2))) for v in (b, a, s))
        lines = [
            f"lunarmap demo in {self.folder}",
            f"  block: {len(self.images)} images ({', '.join(self.images[:4])}, ...) on {self.orbits} orbits, NAVIGATION "
            "kernels with per-orbit offsets and drifts",
            f"  tie points from the matcher: {self.n_tie_points} points, {self.n_observations} image observations",
            f"  adjustment on the rigorous cameras: sigma0 {self.sigma0:.3f} (tie-point sigma x "
            f"{self.tie_sigma_scale:.2f} from variance-component estimation)",
            *([f"  {self.quality_control}"] if self.quality_control else []),
            "  check points vs truth, RMS along-track / cross-track / height / 3-D (m):",
            f"    before (navigation): {b[0]:8.3f} {b[1]:8.3f} {b[2]:8.3f} {b3:8.3f}",
            f"    after (adjusted):    {a[0]:8.3f} {a[1]:8.3f} {a[2]:8.3f} {a3:8.3f}   ({b3 / a3:.0f}x smaller)",
            f"    posterior sigma:     {s[0]:8.3f} {s[1]:8.3f} {s[2]:8.3f} {s3:8.3f}   "
            f"(errors / sigma: RMS {self.check_normalized_rms:.2f}; 1 if the precision is right)",
            f"  camera positions (image centre) vs truth, RMS (m): navigation {self.camera_error_before:.2f}, "
            f"adjusted {self.camera_error_after:.2f} (errors / posterior sigma: RMS {self.camera_normalized_rms:.2f}; "
            "narrow fields of view trade position for attitude)",
            f"  adjusted kernels reloaded through {self.files.get('metakernel', Path('?'))}: cameras agree "
            f"with the adjusted ones to {self.reload_position_mm:.2e} mm / {self.reload_px:.2e} px",
            "  cubic RFMs of the navigation cameras (outputs/rpc/<image>_RPC.TXT, used for matching), check RMS: "
            + ", ".join(f"{k} {v:.1e} px" for k, v in self.rpc_check_rms_px.items()),
            "  cubic RFMs of the adjusted cameras (outputs/rpc_adjusted/<image>_RPC.TXT), check RMS: "
            + ", ".join(f"{k} {v:.1e} px" for k, v in self.rpc_adjusted_check_rms_px.items()),
            "  time (s): " + ", ".join(f"{k} {v:.1f}" for k, v in self.seconds.items()),
            f"  report: {self.files.get('report', '')}; configuration: {self.files.get('config', '')}",
        ]
        return "\n".join(lines)


def _grid(cam: Any, n: int = 9) -> tuple[np.ndarray, np.ndarray]:
    lines = np.linspace(0.5, cam.n_lines - 0.5, n)
    samples = np.linspace(0.5, cam.n_samples - 0.5, n)
    L, S = np.meshgrid(lines, samples, indexing="ij")
    return L.ravel(), S.ravel()


def run_demo(output: str | os.PathLike[str] = "demo_output", seed: int = 0, quick: bool = False,
             scheduler: Any = None, workers: int = 2, full_size: bool = False) -> DemoReport:
    """Run the chain (module docstring) in ``output``; returns its figures.

    Parameters
    ----------
    output : path-like
        Folder for everything the demo writes (created).
    seed : int
        Seed of the mission, scene and measurements.
    quick : bool
        Fewer interest points and check points (for tests): same chain, about half the time.
    scheduler, workers
        As for :func:`lunarmap.workflows.run` (default: a local cluster of ``workers`` processes).
    full_size : bool
        The full-size example (8 LRO-NAC-like images of 52,224 x 5,064 pixels as ISIS cubes; see
        :func:`lunarmap.workflows.write_example`).
    """
    import lunarmap

    from .camera.factory import camera_from_isd_file
    from .rpc import read_netcdf
    from .simulate import block_cameras
    from .synthetic import open_block_mission
    from .workflows import run, write_example
    from .workflows.report import qc_text

    out = Path(output)
    t = time.perf_counter()
    config = write_example(out, seed=seed, quick=quick, full_size=full_size)
    t_example = time.perf_counter() - t
    _log.info("example written (mission, rendered images, control and check points, run.toml): %.1f s", t_example)
    result = run(config, scheduler=scheduler, workers=workers)
    bm = open_block_mission(out / "mission")
    names = list(bm.image_names)
    s = result.summary
    nav = {n: camera_from_isd_file(result.outputs["isd"] / f"{n}.json") for n in names}
    adjusted = {n: camera_from_isd_file(result.outputs["adjustment"] / f"{n}.adjusted.json") for n in names}
    truth = block_cameras(bm, "truth")

    # the adjusted kernels, reloaded from the unchanged labels through the layered meta-kernel
    kernels_of = json.loads(result.outputs["kernels"].read_text())
    d_pos, d_px = 0.0, 0.0
    for n in names:
        again = lunarmap.load_camera(bm.label(n), result.outputs["kernels"].parent / kernels_of[n])
        L, S = _grid(again)
        X = adjusted[n].image_to_ground(L, S, height=0.0)
        la, sa = again.ground_to_image(X, within_image=False)
        d_px = max(d_px, float(np.max(np.hypot(la - L, sa - S))))
        d_pos = max(d_pos, float(np.max(np.linalg.norm(again.rays(L, S)[0] - adjusted[n].rays(L, S)[0], axis=1))))

    def centre_positions(sensors: dict[str, Any]) -> np.ndarray:
        return np.array([sensors[n].rays(0.5 * sensors[n].n_lines, 0.5 * sensors[n].n_samples)[0] for n in names])

    p_true, p_nav, p_adj = centre_positions(truth), centre_positions(nav), centre_positions(adjusted)
    with xr.open_dataset(result.outputs["adjustment"] / "corrections.nc") as corr:
        sig = corr["sigma"].values[:, 3:6]       # columns 3-5: c (frame) / c_0 (line scan), metres
    z = (p_adj - p_true) / sig
    rpc_rms: dict[str, float] = {}
    rpc_adj_rms: dict[str, float] = {}
    man = bm.manifest
    for n in names:
        kind = str(man["images"][n]["kind"]).split("_")[0]
        for folder, worst in (("rpc", rpc_rms), ("rpc_adjusted", rpc_adj_rms)):
            rms = float(read_netcdf(result.outputs[folder] / f"{n}.nc").attrs.get("check_rms", np.nan))
            worst[kind] = max(worst.get(kind, 0.0), rms)
    seconds = {"example": t_example, **{k: v for k, v in _stage_durations(result.stage_seconds).items()}}
    return DemoReport(
        folder=out, images=names, orbits=bm.model.orbits, n_tie_points=int(s["n_points"]), n_observations=int(s["n_observations"]),
        sigma0=float(s["sigma0"]), tie_sigma_scale=float(s["tie_sigma_scale"]),
        check_rms_before=np.asarray(s["check_rms_before_m"]), check_rms_after=np.asarray(s["check_rms_after_m"]),
        check_sigma_after=np.asarray(s["check_sigma_after_m"]), check_normalized_rms=float(s["check_normalized_rms"]),
        camera_error_before=float(np.sqrt(np.mean(np.sum((p_nav - p_true) ** 2, axis=1)))),
        camera_error_after=float(np.sqrt(np.mean(np.sum((p_adj - p_true) ** 2, axis=1)))),
        camera_normalized_rms=float(np.sqrt(np.mean(z ** 2))), reload_position_mm=1e3 * d_pos, reload_px=d_px,
        rpc_check_rms_px=rpc_rms, rpc_adjusted_check_rms_px=rpc_adj_rms, quality_control=qc_text(s), seconds=seconds,
        files={"metakernel": result.outputs.get("metakernel", result.outputs["kernels"]),
               "tiepoints": result.outputs["tiepoints"],
               "report": result.report or Path(), "config": config, "navigation": bm.navigation_metakernel,
               "truth": bm.truth_metakernel})


def _stage_durations(ends: dict[str, float]) -> dict[str, float]:
    """Durations from the stages' end times (a stage starts when the previous one ended)."""
    out, prev = {}, 0.0
    for k, v in ends.items():
        out[k] = max(v - prev, 0.0)
        prev = max(prev, v)
    return out
