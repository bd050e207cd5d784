"""usgscsm as an oracle: ``csm_eval`` (built by ``../shared/tools/usgscsm/build.sh``) driven from Python.

Tests that need it skip with the reason when it is not built; ``LUNARMAP_REQUIRE_USGSCSM=1`` turns the
skip into a failure (set it where the tool is part of the environment).
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

CSM_EVAL = Path(os.environ.get("LUNARMAP_CSM_EVAL", Path.home() / ".cache" / "usgscsm" / "bin" / "csm_eval"))


def require_csm_eval() -> Path:
    if not CSM_EVAL.is_file():
        why = (f"usgscsm's csm_eval is not built at {CSM_EVAL} (bash ../shared/tools/usgscsm/build.sh; "
               "or set LUNARMAP_CSM_EVAL)")
        if os.environ.get("LUNARMAP_REQUIRE_USGSCSM") == "1":
            pytest.fail(why)
        pytest.skip(why)
    return CSM_EVAL


def _run(isd: Path, commands: list[str]) -> list[str]:
    res = subprocess.run([str(require_csm_eval()), str(isd)], input="\n".join(commands) + "\n",
                         capture_output=True, text=True, timeout=120)
    lines = [ln for ln in res.stdout.splitlines() if not ln.startswith("#")]
    if res.returncode != 0 or (lines and lines[0].startswith("ERROR")):
        raise AssertionError(f"usgscsm could not build {isd}: {' '.join(lines[:1])}")
    return lines


def usgscsm_image_to_ground(isd: Path, line, sample, height: float) -> np.ndarray:
    """usgscsm's ``imageToGround`` of pixels (CSM convention), body-fixed metres; NaN rows where it errs."""
    out = _run(isd, [f"i2g {float(l)!r} {float(s)!r} {float(height)!r}" for l, s in zip(line, sample)])
    return np.array([[float(v) for v in r.split()[:3]] if not r.startswith("ERR") else [np.nan] * 3 for r in out])


def usgscsm_ground_to_image(isd: Path, xyz) -> np.ndarray:
    """usgscsm's ``groundToImage`` ``(line, sample)`` of body-fixed points; NaN rows where it errs."""
    out = _run(isd, [f"g2i {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in np.asarray(xyz)])
    return np.array([[float(v) for v in r.split()[:2]] if not r.startswith("ERR") else [np.nan] * 2 for r in out])
