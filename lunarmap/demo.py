"""The demo behind ``make demo`` / ``lunarmap demo``.

Writes the synthetic LUNARMAP-SIM mission (kernels, labels) into a folder,
builds each image's ISD and rigorous sensor model from the kernels, and prints
ground points of the image corners and centre, plus a round-trip check; fits
each image's cubic RFM (written as ``<image>_RPC.TXT``) and reports its check
against the rigorous model; finally adjusts a simulated Clementine-like block
with navigation observations and reports sigma0 and the normalised errors
against the simulation's truth.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from .camera.factory import camera_from_isd
from .camera.geodesy import xyz_to_lonlat_height
from .orientation.drivers import image_support
from .rpc import fit_rpc, write_rpc_txt
from .synthetic import IMAGE_NAMES, write_mission

__all__ = ["run_demo"]


def run_demo(output: str | os.PathLike[str] = "demo_output") -> dict[str, np.ndarray]:
    """Run the demo; returns the ground points (body-fixed metres) per image."""
    t0 = time.perf_counter()
    mk = write_mission(output)
    print(f"synthetic mission written to {Path(mk).parent} ({time.perf_counter() - t0:.1f} s)")
    results: dict[str, np.ndarray] = {}
    for name in IMAGE_NAMES:
        isd = image_support(Path(mk).parent / f"{name}.lbl", mk)
        isd.write_json(Path(mk).parent / f"{name}.isd.json")
        cam = camera_from_isd(isd)
        nl, ns = isd.image_lines, isd.image_samples
        lines = np.array([0.5, 0.5, nl - 0.5, nl - 0.5, nl / 2])
        samples = np.array([0.5, ns - 0.5, 0.5, ns - 0.5, ns / 2])
        xyz = cam.image_to_ground(lines, samples)
        lon, lat, h = xyz_to_lonlat_height(xyz)
        back_l, back_s = cam.ground_to_image(xyz)
        rt = float(np.max(np.hypot(back_l - lines, back_s - samples)))
        print(f"\n{name}: {isd.model} camera, {nl} x {ns} pixels, {isd.times.size} SPICE epochs")
        print(f"  {'line':>9} {'sample':>8} {'lat (deg)':>11} {'lon (deg)':>11}  {'X (m)':>13} {'Y (m)':>13} {'Z (m)':>13}")
        for i in range(lines.size):
            print(f"  {lines[i]:9.1f} {samples[i]:8.1f} {lat[i]:11.6f} {lon[i]:11.6f}  "
                  f"{xyz[i, 0]:13.3f} {xyz[i, 1]:13.3f} {xyz[i, 2]:13.3f}")
        print(f"  ground_to_image(image_to_ground(p)) - p: max {rt:.2e} px")
        fit = fit_rpc(cam, (-3000.0, 3000.0))
        write_rpc_txt(fit.model, Path(mk).parent / f"{name}_RPC.TXT")
        print(f"  cubic RFM vs rigorous model on an independent check grid ({fit.check.n_points} points): "
              f"RMS {fit.check.rms:.1e} px, max {fit.check.max:.1e} px -> {name}_RPC.TXT")
        results[name] = xyz
    print("\nISDs (ALE/CSM layout) written as <image>.isd.json, RPCs as <image>_RPC.TXT")
    _adjustment_demo()
    print(f"\ntotal {time.perf_counter() - t0:.1f} s")
    return results


def _adjustment_demo() -> None:
    """Adjust a simulated Clementine-like block and compare with its truth."""
    from .adjust.acceptance import navigation_block_figures

    t = time.perf_counter()
    f = navigation_block_figures(seed=1)
    b = f["_block"]
    print(f"\nblock adjustment: simulated Clementine-like block, {b['images']} images in 4 orbits, "
          f"{b['points']} points, {b['observations']} image observations, navigation with per-orbit offset and drift")
    print(f"  sigma0 {f['sigma0']:.3f}, image residual RMS {b['rms_px']:.3f} px, {b['iterations']} iterations")
    print(f"  point errors vs truth (datum: navigation data and {b['control_points']} control points): median "
          f"{b['point_error_median_m']:.1f} m; normalised by their posterior sigma: RMS {f['points_z_rms']:.2f} "
          f"(1 if the precision is right) ({time.perf_counter() - t:.1f} s)")
