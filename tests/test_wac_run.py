"""A WAC-like push-frame block through ``lunarmap run`` (issue 26): kernels, labels and images written by
the simulator (``lunarmap.simulate.wac_block``), ISDs from the generic driver's push-frame rule, matching,
adjustment with navigation observations, adjusted ISDs and kernels written back; the check points against
the simulation's truth."""

from __future__ import annotations

import numpy as np

from lunarmap.simulate.wac_block import write_wac_block
from lunarmap.workflows import run


def test_wac_block_goes_through_the_run(tmp_path):
    toml = write_wac_block(tmp_path / "wac")
    res = run(toml, scheduler="sync", report=False)
    s = res.summary
    assert s["converged"] and 0.7 < s["sigma0"] < 1.5
    before = float(np.sqrt(np.sum(np.square(s["check_rms_before_m"]))))
    after = float(np.sqrt(np.sum(np.square(s["check_rms_after_m"]))))
    assert after < 0.5 * before, (before, after)
    assert 0.4 < s["check_normalized_rms"] < 2.0
    adjusted = sorted((res.outputs["adjustment"]).glob("*.adjusted.json"))
    assert len(adjusted) == 4
    import json

    for p in adjusted:          # push-frame ISDs, as the cameras were
        assert json.loads(p.read_text())["name_model"] == "USGS_ASTRO_PUSH_FRAME_SENSOR_MODEL"
