"""Measured agreement of ``lunarmap isd`` with USGS ALE's ISD for LRO NAC M103595705LE.

Usage: ``python bench/compare_ale.py [SHARED_KERNELS_FOLDER]`` (default ../shared/data/kernels).
Prints three JSON lines of maximum differences over all epochs: the ISIS-label ISD
against ALE's, the PDS3-EDR-label ISD against ALE's, and the PDS3-label ISD
against the ISIS-label ISD (``"reference"`` says which).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from lunarmap.orientation.drivers import image_support

ARCSEC = np.pi / 180 / 3600


def qangle(a, b):
    a, b = np.asarray(a), np.asarray(b)
    d = np.minimum(np.linalg.norm(a - b, axis=-1), np.linalg.norm(a + b, axis=-1))
    return 4 * np.arcsin(np.clip(d / 2, 0, 1))


def compare(ours: dict, ref: dict) -> dict:
    """Largest differences of ``ours`` from the reference ISD ``ref``."""
    return {
        "start_et_diff_s": abs(ours["starting_ephemeris_time"] - ref["starting_ephemeris_time"]),
        "center_et_diff_s": abs(ours["center_ephemeris_time"] - ref["center_ephemeris_time"]),
        "epochs_max_diff_s": max(float(np.abs(np.subtract(ours[b]["ephemeris_times"], ref[b]["ephemeris_times"])).max())
                                 for b in ("instrument_position", "instrument_pointing", "body_rotation", "sun_position")),
        "position_max_diff_mm": float(np.abs(np.subtract(ours["instrument_position"]["positions"],
                                                         ref["instrument_position"]["positions"])).max() * 1e6),
        "velocity_max_diff_mm_s": float(np.abs(np.subtract(ours["instrument_position"]["velocities"],
                                                           ref["instrument_position"]["velocities"])).max() * 1e6),
        "sun_position_max_diff_mm": float(np.abs(np.subtract(ours["sun_position"]["positions"],
                                                             ref["sun_position"]["positions"])).max() * 1e6),
        "pointing_max_diff_arcsec": float(qangle(ours["instrument_pointing"]["quaternions"],
                                                 ref["instrument_pointing"]["quaternions"]).max() / ARCSEC),
        "body_rotation_max_diff_arcsec": float(qangle(ours["body_rotation"]["quaternions"],
                                                      ref["body_rotation"]["quaternions"]).max() / ARCSEC),
        "interior_identical": all(ours[k] == ref[k] for k in (
            "focal2pixel_lines", "focal2pixel_samples", "detector_center", "optical_distortion",
            "starting_detector_line", "starting_detector_sample", "focal_length_model")),
        "naif_keywords_identical": ours["naif_keywords"] == ref["naif_keywords"],
        "epochs": len(ours["instrument_position"]["ephemeris_times"]),
    }


def main() -> None:
    root = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parents[1].parent / "shared/data/kernels")
    s = root / "lro_nac_M103595705LE"
    isis = image_support(s / "M103595705LE_isis3.lbl", s / "lro_nac_M103595705LE.tm").to_ale_dict()
    pds3 = image_support(s / "M103595705LE_pds3.lbl", s / "lro_nac_M103595705LE.tm").to_ale_dict()
    ale = json.loads((s / "ale_isd.json").read_text())
    for label, ours, ref, name in (("isis3", isis, ale, "ale"), ("pds3", pds3, ale, "ale"),
                                   ("pds3", pds3, isis, "lunarmap isis3")):
        print(json.dumps({"label": label, "reference": name, **compare(ours, ref)}))


if __name__ == "__main__":
    main()
