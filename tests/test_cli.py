"""The ``lunarmap`` command line on the synthetic mission."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lunarmap.cli import main


@pytest.mark.parametrize("name, model", [("sim_nac_85n", "USGS_ASTRO_LINE_SCANNER_SENSOR_MODEL"),
                                         ("sim_frame_b", "USGS_ASTRO_FRAME_SENSOR_MODEL")])
def test_isd_command_writes_csm_isd(sim_mission, tmp_path, name, model):
    out = tmp_path / f"{name}.json"
    assert main(["isd", str(sim_mission.parent / f"{name}.lbl"), "--kernels", str(sim_mission), "-o", str(out)]) == 0
    isd = json.loads(out.read_text())
    assert isd["name_model"] == model
    pos = np.array(isd["instrument_position"]["positions"])
    alt = np.linalg.norm(pos, axis=1) - isd["radii"]["semimajor"]
    assert np.all((alt > 30) & (alt < 80))  # km: the ~50 km orbit, in ALE's units
    q = np.array(isd["instrument_pointing"]["quaternions"])
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0)
    if "LINE" in model:
        assert len(isd["instrument_position"]["ephemeris_times"]) == isd["image_lines"] // 10 + 1
        assert isd["line_scan_rate"][0][0] == 0.5


def test_isd_command_reports_errors_and_writes_nothing(sim_mission, tmp_path, capsys):
    out = tmp_path / "x.json"
    status = main(["isd", str(sim_mission.parent / "sim_frame_a.lbl"), "--kernels", str(tmp_path / "missing.tm"),
                   "-o", str(out)])
    assert status == 2
    assert "MissingKernelError" in capsys.readouterr().err and "missing.tm" not in [p.name for p in tmp_path.iterdir()]
    assert not out.exists()


def test_demo_runs_the_whole_chain(tmp_path, capsys):
    """``lunarmap run --example --quick``: rendered images, tie points from the matcher, adjustment on the rigorous
    cameras with navigation observations, adjusted kernels reloaded; accuracy against the simulation's truth."""
    out = tmp_path / "demo"
    assert main(["run", "--example", "--output", str(out), "--quick", "--serial"]) == 0
    text = capsys.readouterr().out
    assert "nan" not in text.lower()
    before = np.array(text.split("before (navigation):")[1].split("\n")[0].split(), float)
    after = np.array(text.split("after (adjusted):")[1].split("(")[0].split(), float)
    sigma = np.array(text.split("posterior sigma:")[1].split("(")[0].split(), float)
    z = float(text.split("errors / sigma: RMS ")[1].split(";")[0])
    sigma0 = float(text.split("sigma0 ")[1].split(" ")[0])
    assert before[3] > 10.0                         # metres: the navigation errors of tens of metres
    assert after[3] * 10 < before[3]                # at least 10x better (3-D RMS; 115x with seed 0)
    assert np.all(after < 3 * sigma) and 0.7 < z < 1.3
    assert abs(sigma0 - 1.0) < 0.1
    mm, px = (float(v) for v in text.split("agree with the adjusted ones to ")[1].split(" px")[0].split(" mm / "))
    assert mm <= 1.0 and px <= 1e-4
    outputs = out / "run" / "outputs"
    for f in ("adjusted.tm", "tiepoints.nc", "rpc/orbit1_nac_RPC.TXT", "adjustment/orbit2_frame_a.adjusted.json",
              "adjustment/points.nc", "isd/orbit3_tc.json"):
        assert (outputs / f).is_file(), f
    assert (out / "run" / "report" / "index.html").is_file() and (out / "run.toml").is_file()
    from lunarmap.adjust import read_network
    from lunarmap.matching import read_tiepoints

    assert read_tiepoints(outputs / "tiepoints.nc").sizes["observation"] > 1000
    assert set(read_network(out / "points.nc").point_type) == {"control", "check"}
