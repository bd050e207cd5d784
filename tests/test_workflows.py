"""Workflows: ISD batches on a real two-process dask cluster and in process.

A batch attempts every image: failures are collected by name (issue 16), good
images' ISDs are complete files equal to the serial computation, and the exit
status of the command line says whether any image failed.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lunarmap.orientation.drivers import image_support  # noqa: E402
from lunarmap.spice import loaded_kernel_set  # noqa: E402
from workflows import isd_batch  # noqa: E402

UNSUPPORTED_PDS3 = """PDS_VERSION_ID = PDS3
MISSION_NAME = "CHANDRAYAAN-1"
INSTRUMENT_HOST_ID = CH1
INSTRUMENT_ID = TMC
OBJECT = IMAGE
  LINES = 10
  LINE_SAMPLES = 10
END_OBJECT = IMAGE
END
"""


def _late_copy(src: Path, dst: Path) -> Path:
    """The label with its clock count moved ~1 year later, past every kernel's coverage."""
    text = src.read_text()
    old = next(line for line in text.splitlines() if "SpacecraftClockStartCount" in line)
    count = old.split("=")[1].strip()
    part, ticks = count.split("/")[0], count.split("/")[1].split(":")
    dst.write_text(text.replace(old, f"    SpacecraftClockStartCount = {part}/{int(ticks[0]) + 31_557_600:010d}:{ticks[1]}"))
    return dst


def _same_isd(path: str | Path, label: Path, metakernel: Path) -> None:
    written = json.loads(Path(path).read_text())
    serial = json.loads(json.dumps(image_support(label, metakernel).to_ale_dict()))
    for block in ("instrument_position", "instrument_pointing", "body_rotation", "sun_position"):
        assert written[block] == serial[block], (label.name, block)
    assert {k: v for k, v in written.items() if k != "lunarmap"} == \
        {k: v for k, v in serial.items() if k != "lunarmap"}


@pytest.mark.slow
def test_isd_batch_on_local_cluster_equals_serial(sim_mission, tmp_path):
    labels = [sim_mission.parent / f"{n}.lbl" for n in ("sim_frame_a", "sim_frame_b", "sim_nac_85n")]
    report = isd_batch.run(labels, sim_mission, tmp_path / "isd", n_workers=2)
    assert report.ok and not report.failures
    assert [Path(p).name for p in report.written] == ["sim_frame_a.isd.json", "sim_frame_b.isd.json",
                                                      "sim_nac_85n.isd.json"]
    for lab, path in zip(labels, report.written):
        _same_isd(path, lab, sim_mission)


def test_batch_collects_failures_by_name_and_writes_only_complete_files(sim_mission, tmp_path):
    sim = sim_mission.parent
    (tmp_path / "tmc_pds3.lbl").write_text(UNSUPPORTED_PDS3)
    late = _late_copy(sim / "sim_frame_b.lbl", tmp_path / "late_frame.lbl")
    labels = [sim / "sim_frame_a.lbl", tmp_path / "tmc_pds3.lbl", late, tmp_path / "absent.lbl",
              sim / "sim_nac_85n.lbl"]
    out = tmp_path / "out"
    previous = loaded_kernel_set()
    report = isd_batch.run(labels, sim_mission, out, scheduler="synchronous")
    assert loaded_kernel_set() == previous  # the caller's pool is left as it was
    assert not report.ok
    assert [Path(p).name for p in report.written] == ["sim_frame_a.isd.json", "sim_nac_85n.isd.json"]
    failed = {Path(r.label).name: r for r in report.failures}
    assert failed["tmc_pds3.lbl"].error == "UnknownInstrumentError" and "'TMC'" in failed["tmc_pds3.lbl"].message
    assert failed["late_frame.lbl"].error == "KernelCoverageError"
    assert failed["absent.lbl"].error == "LabelError" and "not found" in failed["absent.lbl"].message
    assert all(r.traceback is None for r in report.failures)  # lunarmap errors: no traceback
    # the folder holds the complete good ISDs and the report, nothing else (no partial or temporary file)
    assert sorted(p.name for p in out.iterdir()) == ["isd_batch_report.json", "sim_frame_a.isd.json",
                                                     "sim_nac_85n.isd.json"]
    for lab, path in zip((labels[0], labels[-1]), report.written):
        _same_isd(path, lab, sim_mission)
    doc = json.loads((out / isd_batch.REPORT_NAME).read_text())
    assert (doc["images"], doc["written"], doc["failed"]) == (5, 2, 3)
    assert [r["status"] for r in doc["results"]] == ["written", "failed", "failed", "failed", "written"]
    assert doc["results"][2] == {"label": str(late), "kernels": str(sim_mission), "status": "failed",
                                 "error": "KernelCoverageError", "message": failed["late_frame.lbl"].message}


def test_batch_fails_images_that_cannot_start(sim_mission, tmp_path):
    """A missing meta-kernel fails its images only; a second label with the same stem is refused."""
    sim = sim_mission.parent
    other = tmp_path / "other"
    other.mkdir()
    (other / "sim_frame_a.lbl").write_text((sim / "sim_frame_a.lbl").read_text())
    images = [(sim / "sim_frame_a.lbl", sim_mission), (other / "sim_frame_a.lbl", sim_mission),
              (sim / "sim_frame_b.lbl", tmp_path / "missing.tm")]
    report = isd_batch.run(images, None, tmp_path / "out", scheduler="synchronous")
    assert [r.error for r in report.results] == [None, "InvalidInputError", "MissingKernelError"]
    assert "already the ISD of label" in report.results[1].message and "missing.tm" in report.results[2].message
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["isd_batch_report.json", "sim_frame_a.isd.json"]


def test_a_bug_in_one_image_keeps_its_traceback_and_the_batch_goes_on(sim_mission, tmp_path, monkeypatch):
    """An exception that is not lunarmap's, raised while the ISD file is being written."""
    from lunarmap.orientation.isd import ImageSupport

    real = ImageSupport.to_ale_dict

    def broken(self):
        doc = real(self)
        if "sim_frame_b" in self.provenance["label"]:
            doc["instrument_position"]["positions"].append(object())  # json.dump fails half-way through the file
        return doc

    monkeypatch.setattr(ImageSupport, "to_ale_dict", broken)
    labels = [sim_mission.parent / f"{n}.lbl" for n in ("sim_frame_a", "sim_frame_b")]
    report = isd_batch.run(labels, sim_mission, tmp_path / "out", scheduler="synchronous")
    bug = report.results[1]
    assert (report.results[0].ok, bug.ok, bug.error) == (True, False, "TypeError")
    assert "Traceback" in bug.traceback and "json" in bug.traceback
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["isd_batch_report.json", "sim_frame_a.isd.json"]


def test_image_list_and_command_line(sim_mission, tmp_path, capsys):
    sim = sim_mission.parent
    listing = tmp_path / "images.txt"
    rel = os.path.relpath(sim, tmp_path)
    listing.write_text(f"# label  meta-kernel\n{rel}/sim_frame_a.lbl {rel}/{sim_mission.name}\n\n"
                       f"'{sim / 'sim_frame_b.lbl'}' {sim_mission}  # absolute, quoted\n")
    assert isd_batch.read_image_list(listing) == [(str(tmp_path / rel / "sim_frame_a.lbl"),
                                                   str(tmp_path / rel / sim_mission.name)),
                                                  (str(sim / "sim_frame_b.lbl"), str(sim_mission))]
    status = isd_batch.main(["--list", str(listing), str(tmp_path / "out"), "--scheduler", "synchronous"])
    cap = capsys.readouterr()
    assert status == 0, cap.err
    assert cap.out.split() == [str(tmp_path / "out" / "sim_frame_a.isd.json"),
                               str(tmp_path / "out" / "sim_frame_b.isd.json")]
    assert "2 of 2 ISDs written, 0 failed" in cap.err
    # one failure -> status 1; a batch that cannot run -> status 2, no traceback
    status = isd_batch.main([str(sim_mission), str(tmp_path / "out2"), str(sim / "sim_frame_a.lbl"),
                             str(tmp_path / "nope.lbl"), "--scheduler", "synchronous"])
    cap = capsys.readouterr()
    assert status == 1 and f"FAILED {tmp_path / 'nope.lbl'}: LabelError" in cap.err
    bad = tmp_path / "bad.txt"
    bad.write_text("a.lbl\n")
    assert isd_batch.main(["--list", str(bad), str(tmp_path / "out3")]) == 2
    err = capsys.readouterr().err
    assert f"{bad}:1: expected 'LABEL META_KERNEL'" in err and "Traceback" not in err
    assert not (tmp_path / "out3").exists()
    assert isd_batch.main(["--list", str(tmp_path / "none.txt"), str(tmp_path / "out3")]) == 2
    assert "cannot read image list" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.shared
def test_issue16_batch_of_the_real_sets_on_a_two_process_cluster(tmp_path):
    """Acceptance: the 7 labels of the 5 real kernel sets plus 2 broken ones, as a user runs it."""
    from conftest import shared_set

    sets = {name: shared_set(name) for name in ("lro_nac_M103595705LE", "clementine_uvvis_LUA3107H161",
                                                "kaguya_tc_TC1S2B0", "lunar_orbiter_3133_high_res_1",
                                                "apollo15_metric_AS15-M-1450")}
    mk = {name: folder / f"{name}.tm" for name, folder in sets.items()}
    lro = sets["lro_nac_M103595705LE"]
    good = [(lro / "M103595705LE_isis3.lbl", mk["lro_nac_M103595705LE"]),
            (lro / "M103595705LE_pds3.lbl", mk["lro_nac_M103595705LE"]),
            (sets["clementine_uvvis_LUA3107H161"] / "LUA3107H.161_isis3.lbl", mk["clementine_uvvis_LUA3107H161"]),
            (sets["kaguya_tc_TC1S2B0"] / "TC1S2B0_01_06691S820E0465_pds3.lbl", mk["kaguya_tc_TC1S2B0"]),
            # Lunar Orbiter and Apollo metric have drivers since issue 13
            (sets["lunar_orbiter_3133_high_res_1"] / "3133_high_res_1_isis.lbl", mk["lunar_orbiter_3133_high_res_1"]),
            (sets["apollo15_metric_AS15-M-1450"] / "AS15-M-1450_isis3.lbl", mk["apollo15_metric_AS15-M-1450"])]
    pds3 = (lro / "M103595705LE_pds3.lbl").read_text()
    wac = tmp_path / "W0000000000_pds3.lbl"  # an LROC PDS3 label that is not a NAC
    wac.write_text(pds3.replace("FRAME_ID                           = LEFT\n", ""))
    late = tmp_path / "M103595705LE_late_pds3.lbl"  # one hour after the kernels end
    late.write_text(pds3.replace("1/270649237:07208", "1/270652837:07208"))
    expected_failures = {
        "TC1S2B0_01_06691S820E0465_isis3.lbl": ("UnknownInstrumentError", "PDS3 level-2B0 label only"),
        wac.name: ("UnknownInstrumentError", "no FRAME_ID"),
        late.name: ("KernelCoverageError", "SPKINSUFFDATA"),
    }
    images = good + [(sets["kaguya_tc_TC1S2B0"] / "TC1S2B0_01_06691S820E0465_isis3.lbl", mk["kaguya_tc_TC1S2B0"]),
                     (wac, mk["lro_nac_M103595705LE"]), (late, mk["lro_nac_M103595705LE"])]
    listing = tmp_path / "images.txt"
    listing.write_text("".join(f"'{lab}' '{k}'\n" for lab, k in images))
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    res = subprocess.run([sys.executable, "-m", "workflows.isd_batch", "--list", str(listing), str(out)],
                         capture_output=True, text=True, cwd=tmp_path, env=env, timeout=300)
    assert res.returncode == 1, res.stderr
    assert "Traceback" not in res.stderr
    assert res.stdout.split() == [str(out / (lab.stem + ".isd.json")) for lab, _ in good]
    for name, (error, detail) in expected_failures.items():
        line = next(line for line in res.stderr.splitlines() if line.startswith("FAILED ") and name in line)
        assert f": {error}: " in line and detail in line, line
    assert "6 of 9 ISDs written, 3 failed" in res.stderr
    doc = json.loads((out / isd_batch.REPORT_NAME).read_text())
    assert [r["status"] for r in doc["results"]] == ["written"] * 6 + ["failed"] * 3
    assert sorted(p.name for p in out.iterdir()) == sorted([isd_batch.REPORT_NAME] +
                                                           [lab.stem + ".isd.json" for lab, _ in good])
    for lab, k in good:  # complete files, equal to the serial computation
        _same_isd(out / (lab.stem + ".isd.json"), lab, k)
