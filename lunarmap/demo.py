"""The demo behind ``make demo`` / ``lunarmap demo``.

Writes the synthetic LUNARMAP-SIM mission (kernels, labels) into a folder,
builds each image's ISD and rigorous sensor model from the kernels, and prints
ground points of the image corners and centre, plus a round-trip check.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from .camera.factory import camera_from_isd
from .camera.geodesy import xyz_to_lonlat_height
from .orientation.drivers import image_support
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
        results[name] = xyz
    print(f"\nISDs (ALE/CSM layout) written as <image>.isd.json; total {time.perf_counter() - t0:.1f} s")
    return results
