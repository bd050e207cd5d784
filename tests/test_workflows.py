"""Workflows on a real two-process dask cluster."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lunarmap.orientation.drivers import image_support  # noqa: E402
from workflows import isd_batch  # noqa: E402


@pytest.mark.slow
def test_isd_batch_on_local_cluster_equals_serial(sim_mission, tmp_path):
    labels = [sim_mission.parent / f"{n}.lbl" for n in ("sim_frame_a", "sim_frame_b", "sim_nac_85n")]
    paths = isd_batch.run(labels, sim_mission, tmp_path / "isd", n_workers=2)
    assert [Path(p).name for p in paths] == ["sim_frame_a.isd.json", "sim_frame_b.isd.json", "sim_nac_85n.isd.json"]
    for lab, path in zip(labels, paths):
        serial = image_support(lab, sim_mission).to_ale_dict()
        parallel = json.loads(Path(path).read_text())
        assert parallel["instrument_position"] == json.loads(json.dumps(serial["instrument_position"]))
        assert parallel["instrument_pointing"]["quaternions"] == serial["instrument_pointing"]["quaternions"]
