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


def test_demo_prints_ground_points(tmp_path, capsys):
    assert main(["demo", "--output", str(tmp_path / "demo")]) == 0
    text = capsys.readouterr().out
    assert "sim_nac_85n" in text and "sim_frame_a" in text and "nan" not in text.lower()
    assert (tmp_path / "demo" / "sim_nac_equator.isd.json").is_file()
    # every image got an RPC that reads back; the adjustment line reports sigma0 near 1
    from lunarmap.rpc import read_rpc_txt

    for name in ("sim_nac_equator", "sim_frame_a"):
        assert read_rpc_txt(tmp_path / "demo" / f"{name}_RPC.TXT").to_dataset() is not None
    rms = [float(line.split("RMS ")[1].split(" px")[0]) for line in text.splitlines() if "cubic RFM" in line]
    assert len(rms) == 5 and max(rms) <= 0.01
    sigma0 = float(text.split("sigma0 ")[1].split(",")[0])
    assert abs(sigma0 - 1.0) < 0.05
