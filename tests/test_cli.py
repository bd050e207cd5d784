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
    # the file is the ISD of the library call, through JSON (no key lost, no value rounded)
    from lunarmap.orientation.drivers import image_support

    assert isd == json.loads(json.dumps(image_support(sim_mission.parent / f"{name}.lbl", sim_mission).to_ale_dict()))
    assert sorted(p.name for p in tmp_path.iterdir()) == [out.name]    # no temporary file left beside it


def test_isd_command_reports_errors_and_writes_nothing(sim_mission, tmp_path, capsys):
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    out = out_dir / "x.json"
    missing = tmp_path / "missing.tm"
    status = main(["isd", str(sim_mission.parent / "sim_frame_a.lbl"), "--kernels", str(missing), "-o", str(out)])
    assert status == 2
    err = capsys.readouterr().err
    assert "MissingKernelError" in err and str(missing) in err and "Traceback" not in err
    assert list(out_dir.iterdir()) == []                    # no output, no temporary file


def test_isd_command_fails_during_sampling_and_writes_nothing(sim_mission, tmp_path, capsys):
    """A label one day after the kernels' coverage: SPICE fails after the label was read; nothing is written."""
    label = (sim_mission.parent / "sim_frame_a.lbl").read_text()
    start = label.split("StartTime")[1].split("=")[1].split()[0]
    # the clock count is read first when present: drop it, so the (late) StartTime is used
    late = "\n".join(ln for ln in label.replace(start, start.replace("2026-03-21", "2026-03-22")).splitlines()
                     if "SpacecraftClockStartCount" not in ln)
    assert "2026-03-22" in late
    lab = tmp_path / "late.lbl"
    lab.write_text(late)
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    status = main(["isd", str(lab), "--kernels", str(sim_mission), "-o", str(out_dir / "late.json")])
    assert status != 0
    assert "KernelCoverageError" in capsys.readouterr().err
    assert list(out_dir.iterdir()) == []


def test_isd_command_interrupted_while_writing_leaves_no_file(sim_mission, tmp_path, monkeypatch, capsys):
    """The write itself fails half-way (disk full): one named error line, exit status 2, neither a partial ISD nor a
    temporary file remains."""
    import lunarmap.orientation.isd as isd_module

    def half_then_fail(data, fh, **kw):
        fh.write(json.dumps(data)[:100])
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(isd_module.json, "dump", half_then_fail)
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    status = main(["isd", str(sim_mission.parent / "sim_frame_a.lbl"), "--kernels", str(sim_mission),
                   "-o", str(out_dir / "a.json")])
    err = capsys.readouterr().err
    assert status == 2
    assert "DiskFullError" in err and "a.json" in err and "no space left" in err.lower()
    assert list(out_dir.iterdir()) == []


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
    # one sigma0 line: first adjustment -> after quality control -> with the estimated tie-point sigma
    line = next(ln for ln in text.splitlines() if "sigma0 " in ln and "after QC" in ln)
    sigma0 = float(line.split(" with the tie-point sigma")[0].split()[-1])
    assert float(line.split("sigma0 ")[1].split()[0]) > sigma0
    # quality control against the simulator's true conjugates: precision and recall
    truth = next(ln for ln in text.splitlines() if "QC vs truth:" in ln)
    assert "precision" in truth and "recall" in truth and "true mismatches" in truth
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
    # every RPC file reproduces its camera reloaded independently from the unchanged label: outputs/rpc (fitted
    # before matching) the navigation camera through the navigation kernels, outputs/rpc_adjusted the adjusted
    # camera through the adjusted kernels the run wrote (not the in-memory cameras the RFMs were fitted to)
    import lunarmap
    from lunarmap.rpc import read_rpc_txt

    printed = {}
    for line in text.splitlines():     # "cubic RFMs of the ... cameras (...), check RMS: nac 1.6e-06 px, tc ..."
        if "cubic RFMs of the" in line:
            which = "rpc_adjusted" if "adjusted cameras" in line else "rpc"
            printed[which] = {kind: float(value) for kind, value in
                              (part.split()[:2] for part in line.split("check RMS:")[1].split(","))}
    assert set(printed) == {"rpc", "rpc_adjusted"}
    kernels = {"rpc": out / "mission" / "navigation.tm", "rpc_adjusted": outputs / "adjusted.tm"}
    for which, check_rms in printed.items():
        assert set(check_rms) == {"nac", "tc", "frame"}
        rpcs = sorted((outputs / which).glob("*_RPC.TXT"))
        assert len(rpcs) == 12
        worst: dict[str, float] = {}
        moved = 0.0
        for f in rpcs:
            name = f.name[: -len("_RPC.TXT")]
            kind = name.split("_")[1]
            cam = lunarmap.load_camera(out / "mission" / f"{name}.lbl", kernels[which])
            rfm = read_rpc_txt(f)
            assert (rfm.n_lines, rfm.n_samples) == (cam.n_lines, cam.n_samples)
            li, sa = np.meshgrid(np.linspace(1, cam.n_lines - 1, 7), np.linspace(1, cam.n_samples - 1, 7),
                                 indexing="ij")
            X = cam.image_to_ground(li.ravel(), sa.ravel(), height=100.0)
            rl, rs = rfm.ground_to_image(X)
            worst[kind] = max(worst.get(kind, 0.0), float(np.max(np.hypot(rl - li.ravel(), rs - sa.ravel()))))
            other = read_rpc_txt(outputs / ("rpc" if which == "rpc_adjusted" else "rpc_adjusted") / f.name)
            ol, os_ = other.ground_to_image(X)
            # NaN: the point lies outside the other RFM's ground domain, i.e. it moved all the more
            moved = max(moved, float(np.max(np.nan_to_num(np.hypot(ol - li.ravel(), os_ - sa.ravel()), nan=np.inf))))
        # measured (seed 0): worst / check RMS = 2.8 (nac, 4.5e-6 px), 2.2 (tc, 0.19 px: a cubic cannot follow the
        # TC's kaguyalism along-track distortion), 1.9 (frame, 4.1e-5 px); a file that did not reproduce its
        # camera would be off by pixels
        for kind, err in worst.items():
            assert err <= max(5.0 * check_rms[kind], 1e-5), (which, kind, err, check_rms[kind])
        assert moved > 1.0   # the other set is off by the adjustment (tens of metres): the check can fail
    # the second run computes nothing (counted by its own log line), writes nothing in the outputs, the store or
    # the report, and prints the figures of the first run's comparison with the truth
    import re

    run_dir = out / "run"
    files = sorted(p for sub in ("outputs", "store", "report") for p in (run_dir / sub).rglob("*"))
    written = {p: p.stat().st_mtime_ns for p in files}
    assert main(["run", "--example", "--output", str(out), "--quick", "--serial"]) == 0
    again = capsys.readouterr().out

    def figures(t: str) -> list[str]:        # this run's own timings and memory aside
        return [ln for ln in t.splitlines() if not ln.strip().startswith(("time (s)", "peak resident memory"))]

    assert figures(again) == figures(text)
    finished = [ln for ln in (run_dir / "run.log").read_text().splitlines() if "run finished:" in ln]
    assert len(finished) == 2
    counts = re.findall(r"(\w+) (\d+) computed / (\d+) reused", finished[-1])
    assert len(counts) >= 9 and all(int(c) == 0 and int(r) > 0 for _, c, r in counts), finished[-1]
    assert {p: p.stat().st_mtime_ns for p in written} == written
    assert sorted(p for sub in ("outputs", "store", "report") for p in (run_dir / sub).rglob("*")) == files
