"""``lunarmap run``: configuration validation, the chain as one dask graph on a small rendered block,
resumption, identical results serially / on a local cluster / on a separately started scheduler, a
worker killed mid-run, bad inputs."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from lunarmap.errors import ConfigError, LunarmapError, MissingKernelError, WorkflowError
from lunarmap.workflows import load_config, run, write_example

NAMES = ["orbit1_nac", "orbit2_nac", "orbit3_nac", "orbit2_frame_a"]


@pytest.fixture(scope="module")
def example(tmp_path_factory) -> Path:
    """A 4-image block (3 orbits, NAC-like and frame cameras) rendered once: its run.toml."""
    folder = tmp_path_factory.mktemp("run_example")
    return write_example(folder, quick=True, names=NAMES, n_control=4, n_check=8)


def _config(example: Path, output: str, **replace: str) -> Path:
    text = example.read_text().replace('output = "run"', f'output = "{output}"')
    for old, new in replace.items():
        assert old in text, old
        text = text.replace(old, new)
    path = example.parent / f"{output}.toml"
    path.write_text(text)
    return path


def _points(result) -> np.ndarray:
    with xr.open_dataset(result.outputs["adjustment"] / "points.nc") as ds:
        return ds["xyz"].values.copy()


@pytest.fixture(scope="module")
def serial(example):
    return run(_config(example, "serial"), scheduler="sync")


def test_serial_run_adjusts_the_block(serial):
    s = serial.summary
    assert serial.counts()["match"] == (6, 0) and serial.computed == sum(c for c, _ in serial.counts().values())
    assert abs(s["sigma0"] - 1.0) < 0.1 and s["converged"]
    before, after = np.array(s["check_rms_before_m"]), np.array(s["check_rms_after_m"])
    assert np.sqrt(np.sum(before ** 2)) > 10 * np.sqrt(np.sum(after ** 2))
    assert 0.5 < s["check_normalized_rms"] < 1.5          # 8 check points x 3: a loose band
    out = serial.outputs
    for p in (out["tiepoints"], out["metakernel"], out["adjustment"] / "points.nc",
              out["adjustment"] / "orbit1_nac.adjusted.json", out["rpc"] / "orbit1_nac_RPC.TXT",
              serial.folder / "run.log", serial.folder / "steps.json"):
        assert Path(p).is_file(), p
    with xr.open_dataset(out["adjustment"] / "points.nc") as ds:
        assert ds.attrs["crs"] == "IAU_2015:30100" and ds.attrs["config_sha256"] == serial.config.digest()
        assert ds.attrs["lunarmap_version"] and "navigation.tm" not in ds.attrs["kernels"]
    html = serial.report.read_text()
    assert html.count("data:image/png;base64,") == 4 and "sigma0" in html
    # the example's quality control (data snooping): its report beside the adjustment, in the summary and page
    q = s["qc"]
    assert q["steps"] == ["baarda"] and q["image_observations"] == s["n_observations"]
    assert q["image_observations_removed"] < 0.2 * q["image_observations"]
    # image measurements of control and check points are tested like any other: a few may go, not many
    measured = sum(q["removed_by_point_type"].get(k, 0) for k in ("control", "check"))
    assert measured <= 0.1 * int(np.sum(xr.open_dataset(out["adjustment"] / "residuals.nc")["point_type"].values
                                        != "tie")) and q["max_w"] <= 4.0
    with xr.open_dataset(out["adjustment"] / "qc.nc") as ds:
        # every image observation's last decision: removed, reinstated, withdrawn (with its point), dropped
        last = {int(i): a for k, a, i in zip(ds["kind"].values.astype(str), ds["action"].values.astype(str),
                                             ds["index"].values) if k == "image"}
    out_by_decisions = sum(a in ("removed", "withdrawn", "dropped") for a in last.values())
    with xr.open_dataset(out["adjustment"] / "residuals.nc") as ds:
        flags = ds["qc_removed"].values
        assert np.all(ds["weight_factor"].values[flags] == 0.0) and np.all(ds["weight_factor"].values[~flags] > 0)
    assert int(flags.sum()) == q["image_observations_removed"] == out_by_decisions
    # the final status of every observation (issue 27): in qc.nc, residuals.nc and the summary alike
    with xr.open_dataset(out["adjustment"] / "qc.nc") as ds:
        img = ds["status_kind"].values.astype(str) == "image"
        st = ds["status_status"].values.astype(str)[img]
        assert np.array_equal(np.sort(ds["status_index"].values[img]), np.arange(flags.size))
    assert int(np.sum(st != "in")) == int(flags.sum())
    assert sum(v for k, v in q["final_status"].items() if k.startswith("image ") and k != "image in") == flags.sum()
    assert isinstance(q["clean"], bool) and (q["clean"] or q["flags"])
    assert "quality control: steps baarda" in (out["adjustment"] / "qc.txt").read_text()
    assert ">Quality control</h2>" in html
    # the report judges (issue 29): a verdict first, the QC decisions as a sortable table with its columns
    # explained, the check points one by one, no "None" for what a run does not have
    assert html.index(">Verdict</h2>") < html.index(">Summary</h2>") and "sigma0 " in html.split(">Summary</h2>")[0]
    assert "errors / predicted sigma RMS" in html and 'onclick="sortTable(this)"' in html
    assert "what the columns mean" in html and html.count("<tr>") > out_by_decisions
    assert ">Check points, one by one</h2>" in html and ">None<" not in html


def _mtimes(folder: Path) -> dict[Path, int]:
    """Every file and folder under ``folder`` with its modification time (ns)."""
    return {p: p.stat().st_mtime_ns for p in sorted(folder.rglob("*"))}


def test_rerun_reuses_everything_and_a_changed_parameter_reruns_only_what_depends_on_it(example, serial):
    txts = sorted((serial.config.output / "outputs").glob("rpc*/*_RPC.TXT"))
    assert len(txts) == 2 * len(serial.config.images)
    made = {f: f.stat().st_mtime_ns for f in txts}
    # the first rerun writes nothing either: no output copied again, no store entry, no digest (the outputs'
    # digests were noted when they were written)
    outputs, store = serial.config.output / "outputs", serial.config.output / "store"
    written = {**_mtimes(outputs), **_mtimes(store)}
    again = run(serial.config, scheduler="sync", report=False)
    assert again.computed == 0 and again.counts()["adjust"] == (0, 1)
    assert {**_mtimes(outputs), **_mtimes(store)} == written
    # the RPCs' text forms are not written again (a rerun of 192 images spent 12 of its 28 s rewriting them),
    # but a damaged one is
    assert {f: f.stat().st_mtime_ns for f in txts} == made
    good = txts[0].read_text()
    txts[0].write_text(good[:-40])
    assert run(serial.config, scheduler="sync", report=False).computed == 0
    assert txts[0].read_text() == good and all(f.stat().st_mtime_ns == made[f] for f in txts[1:])
    np.testing.assert_array_equal(_points(again), _points(serial))
    changed = _config(example, "serial", **{"ftol = 1e-10": "ftol = 1e-9"})
    res = run(changed, scheduler="sync", report=False)
    counts = res.counts()
    assert counts["adjust"] == (1, 0) and counts["kernels"] == (1, 0)
    assert all(counts[s][0] == 0 for s in ("isd", "rpc", "detect", "match", "tiepoints"))
    # without quality control: only the adjustment and what follows it rerun, and nothing is removed
    text = example.read_text()
    plain = _config(example, "serial", **{text[text.index("[adjust.qc]"):text.index("[report]")]: ""})
    res = run(plain, scheduler="sync", report=False)
    counts = res.counts()
    assert counts["adjust"] == (1, 0) and all(counts[s][0] == 0 for s in ("isd", "rpc", "detect", "match", "tiepoints"))
    assert "qc" not in res.summary and not (res.outputs["adjustment"] / "qc.nc").exists()
    # the removals did not cost accuracy: check points of the quality-controlled run within 1.2x of the plain run's
    qc3, plain3 = (float(np.sqrt(np.sum(np.square(r.summary["check_rms_after_m"])))) for r in (serial, res))
    assert qc3 < 1.2 * plain3
    # the outputs of the quality-controlled run back in place for the other tests (from the store: nothing computed)
    assert run(serial.config, scheduler="sync", report=False).computed == 0


def test_variance_components_in_the_run_replace_the_tie_variance_factor(example, serial):
    """``steps = ["baarda", "variance"]``: variance components per navigation group (image groups) and of the
    navigation and control observations; groups without the redundancy for it (one image per navigation group)
    keep their a-priori sigma, named by the run's group labels; the adjustment still meets the check points."""
    cfg = _config(example, "serial", **{'steps = ["baarda"]': 'steps = ["baarda", "variance"]'})
    res = run(cfg, scheduler="sync", report=False)
    assert res.counts()["adjust"] == (1, 0) and res.counts()["match"][0] == 0
    s = res.summary
    assert s["qc"]["steps"] == ["baarda", "variance"] and s["variance_factors"] == []
    with xr.open_dataset(res.outputs["adjustment"] / "qc.nc") as ds:
        names = [str(n) for n in ds["obs_group"].values]
        est = ds["group_estimated"].values.astype(bool)
        f = ds["group_sigma_factor"].values
    img = [n.startswith("image ") for n in names]
    assert all(est[img]) and np.all((f[img] > 0.2) & (f[img] < 5.0))
    assert any(n.startswith("navigation position orbit 1-nac") for n in names)      # the run's labels
    assert np.all(f[~est] == 1.0)                                                     # kept at their sigma
    before, after = (np.sqrt(np.sum(np.square(s[k]))) for k in ("check_rms_before_m", "check_rms_after_m"))
    assert after * 10 < before
    assert run(serial.config, scheduler="sync", report=False).computed == 0


def test_separability_check_in_the_run_can_be_turned_off(example, serial):
    """``baarda_separable = false``: no point is withdrawn (the example's run withdraws some: points whose
    failing ray no test can single out), each removal stands alone, and only the adjustment reruns."""
    assert any(k.endswith("withdrawn") for k in serial.summary["qc"]["actions"])
    off = 'baarda_sigma0 = "robust"\nbaarda_separable = false'
    cfg = _config(example, "serial", **{'baarda_sigma0 = "robust"': off})
    res = run(cfg, scheduler="sync", report=False)
    assert res.counts()["adjust"] == (1, 0) and res.counts()["match"][0] == 0
    q = res.summary["qc"]
    assert not any(k.endswith("withdrawn") for k in q["actions"])
    with xr.open_dataset(res.outputs["adjustment"] / "qc.nc") as ds:
        act = ds["action"].values.astype(str)
        removed, reinstated = int(np.sum(act == "removed")), int(np.sum(act == "reinstated"))
    assert q["image_observations_removed"] == removed - reinstated
    assert q["image_observations_removed"] < serial.summary["qc"]["image_observations_removed"]
    assert run(serial.config, scheduler="sync", report=False).computed == 0


def test_robust_first_in_the_run_is_the_first_adjustment(example, serial):
    """``steps = ["robust", "baarda"]``: no least-squares adjustment before the robust one (the summary and
    the printed line say so); the tie points' mismatches go, the measured control/check points are left to the
    w-tests, and the adjustment still meets the check points."""
    from lunarmap.workflows.report import qc_text

    cfg = _config(example, "serial", **{'steps = ["baarda"]': 'steps = ["robust", "baarda"]'})
    res = run(cfg, scheduler="sync", report=False)
    assert res.counts()["adjust"] == (1, 0) and res.counts()["match"][0] == 0
    q = res.summary["qc"]
    assert q["steps"] == ["robust", "baarda"] and q["first_adjustment"] == "robust"
    assert "in the robust adjustment" in qc_text(res.summary)
    assert 0 < q["image_observations_removed"] < 0.2 * q["image_observations"]
    assert np.isfinite(q["sigma0_first"]) and q["sigma0_last"] < 1.5 * q["sigma0_first"]
    before, after = (np.sqrt(np.sum(np.square(res.summary[k]))) for k in ("check_rms_before_m", "check_rms_after_m"))
    assert after * 10 < before
    assert run(serial.config, scheduler="sync", report=False).computed == 0


def test_interrupted_run_resumes_with_only_the_unfinished_steps(example, monkeypatch):
    import lunarmap.workflows.steps as run_mod  # match batches call their pairs' match_step

    cfg = _config(example, "interrupted")
    calls = {"n": 0}
    real = run_mod.match_step

    def interrupted(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 4:
            raise KeyboardInterrupt("simulated Ctrl-C in the 4th pair")
        return real(*args, **kwargs)

    monkeypatch.setattr(run_mod, "match_step", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run(cfg, scheduler="sync", report=False)
    monkeypatch.undo()
    store = Path(load_config(cfg).output) / "store"
    stored = {s: len([p for p in (store / s).glob("*") if not p.name.startswith(".") and not p.name.endswith(".sha256")]) if (store / s).is_dir() else 0
              for s in ("isd", "rpc", "detect", "match", "tiepoints", "adjust")}
    assert stored["match"] == 3 and stored["tiepoints"] == 0 and not list(store.rglob(".*"))   # nothing half-written
    res = run(cfg, scheduler="sync", report=False)
    counts = res.counts()
    for stage, n_stored in stored.items():      # exactly the unfinished steps are computed
        assert counts[stage][1] == n_stored, stage
    assert counts["match"] == (3, 3) and counts["tiepoints"] == (1, 0) and counts["adjust"] == (1, 0)


def _export_files(folder: Path) -> dict[str, bytes]:
    """The per-image output files of a run (ISDs, RFMs as netCDF and text), by path in ``outputs``."""
    out = folder / "outputs"
    return {str(p.relative_to(out)): p.read_bytes() for sub in ("isd", "rpc", "rpc_adjusted")
            for p in sorted((out / sub).iterdir())}


def test_local_cluster_gives_identical_results(example, serial, monkeypatch, tmp_path):
    import lunarmap.workflows.outputs as outputs_mod

    def not_here(*args, **kwargs):
        raise AssertionError("a per-image output file was written after the graph, in the main process")

    # the per-image output files are written by the tasks on the workers (processes of their own: this
    # process's patch does not reach them), none by the main process after the graph
    monkeypatch.setattr(outputs_mod.Outputs, "rpc_text", not_here)
    res = run(_config(example, "cluster"), scheduler=None, workers=2, report=False)
    monkeypatch.undo()
    # byte for byte the files of the serial run (written there by the same tasks in this process)
    mine, theirs = _export_files(res.folder), _export_files(serial.folder)
    assert len(theirs) == 5 * len(NAMES) and mine.keys() == theirs.keys()
    assert [k for k in mine if mine[k] != theirs[k]] == []
    # each text form (written by its task from the model it had just fitted) is the one of its netCDF file read
    # back, byte for byte, and reads back to that model
    from lunarmap.rpc import read_netcdf, read_rpc_txt, write_rpc_txt

    for name in NAMES:
        for sub in ("rpc", "rpc_adjusted"):
            nc = read_netcdf(res.outputs[sub] / f"{name}.nc")
            again = write_rpc_txt(nc, tmp_path / f"{sub}_{name}_RPC.TXT")
            assert again.read_bytes() == mine[f"{sub}/{name}_RPC.TXT"], (sub, name)
            np.testing.assert_array_equal(read_rpc_txt(again).coefficients, nc.coefficients)
    a, b = _points(res), _points(serial)
    assert np.max(np.abs(a - b) / np.abs(b).max()) <= 1e-9
    assert res.summary["sigma0"] == pytest.approx(serial.summary["sigma0"], rel=1e-9)
    # memory: the main process and both workers' VmHWM, and per step the largest peak of a process while one
    # of its tasks computed; a step's peak cannot exceed the high-water mark of the processes that ran it
    peaks, by_step = res.summary["peak_rss_mb"], res.summary["peak_rss_mb_by_step"]
    assert len(peaks) == 3 and "main" in peaks and all(v > 50 for v in peaks.values())
    assert {"isd", "pyramid", "detect", "match", "tiepoints", "adjust"} <= set(by_step)
    assert all(0 < v <= max(peaks.values()) + 1 for v in by_step.values()), (by_step, peaks)
    # every computed record carries its own; reused records none
    assert all(d.peak_mb > 0 for d in res.done if d.computed) and all(d.peak_mb == 0 for d in res.done if not d.computed)


def _start_scheduler(tmp: Path) -> tuple[list[subprocess.Popen], str]:
    sched_file = tmp / "scheduler.json"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    bindir = Path(sys.executable).parent
    procs = [subprocess.Popen([str(bindir / "dask"), "scheduler", "--host", "127.0.0.1", "--port", "0",
                               "--dashboard-address", ":0", "--scheduler-file", str(sched_file)], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    for _ in range(200):
        if sched_file.exists() and sched_file.stat().st_size > 0:
            break
        time.sleep(0.1)
    import json

    address = json.loads(sched_file.read_text())["address"]
    for _ in range(2):
        procs.append(subprocess.Popen([str(bindir / "dask"), "worker", address, "--nthreads", "1",
                                       "--nworkers", "1", "--no-dashboard"], env=env,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
    from distributed import Client

    with Client(address, timeout="20s") as c:
        c.wait_for_workers(2, timeout=60)
    return procs, address


def test_separately_started_scheduler_gives_identical_results(example, serial, tmp_path):
    procs, address = _start_scheduler(tmp_path)
    try:
        res = run(_config(example, "external"), scheduler=address, report=False)
    finally:
        for p in procs[::-1]:
            p.send_signal(signal.SIGINT)
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
    a, b = _points(res), _points(serial)
    assert np.max(np.abs(a - b) / np.abs(b).max()) <= 1e-9


def test_a_worker_killed_mid_run_does_not_change_the_results(example, serial):
    """One of two worker processes is killed once the first match tasks have finished; the nanny restarts
    it, its tasks are rerun, the results are those of the serial run."""
    import dask
    from distributed import Client, LocalCluster

    from lunarmap.matching import WORKER_ENVIRON

    cfg = _config(example, "killed")
    store = Path(load_config(cfg).output) / "store"
    with dask.config.set({"distributed.nanny.pre-spawn-environ": WORKER_ENVIRON}):
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0")
    client = Client(cluster)
    killed = {}

    def killer():
        deadline = time.time() + 300
        while time.time() < deadline:
            if (store / "match").is_dir() and len(list((store / "match").glob("*.npz"))) >= 1:
                pids = client.run(os.getpid)
                victim = sorted(pids.values())[0]
                os.kill(victim, signal.SIGKILL)
                killed["pid"] = victim
                killed["matches_done"] = len(list((store / "match").glob("*.npz")))
                return
            time.sleep(0.05)

    t = threading.Thread(target=killer)
    t.start()
    try:
        res = run(cfg, scheduler=client, report=False)
    finally:
        t.join()
        client.close()
        cluster.close()
    assert killed and killed["matches_done"] < 6          # the kill happened mid-graph
    a, b = _points(res), _points(serial)
    assert np.max(np.abs(a - b) / np.abs(b).max()) <= 1e-9


def test_a_qc_budget_in_the_run_is_spent_and_flagged(example, serial):
    """``max_rounds = 0``: the run's quality control is the first adjustment only; its summary and report say the
    block is not clean, and why (the warning is logged, not raised into the run)."""
    cfg = _config(example, "budget", **{"baarda_limit = 4.0": "baarda_limit = 4.0\nmax_rounds = 0"})
    res = run(cfg, scheduler="sync")
    q = res.summary["qc"]
    assert q["clean"] is False and any("budget of 0" in f for f in q["flags"])
    assert q["image_observations_removed"] == 0 and q["final_status"]["image in"] == q["image_observations"]
    assert "quality control ended without a clean block" in res.report.read_text()


def test_bad_configurations_are_named(example, tmp_path):
    base = example.read_text()
    cases = [
        (base.replace("[report]", "[reprot]"), "unknown section \\[reprot\\]"),
        (base.replace("degree = 1", "degree = 1\npolynomial = 2"), "unknown key adjust.polynomial"),
        (base.replace("cell = 64", 'cell = "64"'), "tiepoints.cell must be an integer"),
        (base.replace('metakernel = "mission/navigation.tm"', 'metakernel = "mission/nothere.tm"'),
         "kernels.metakernel.*does not exist"),
        (base.replace('pixels = "mission/orbit1_nac.nc"', 'pixels = "mission/missing.nc"'),
         "images\\[0\\].pixels.*does not exist"),
        (base.replace('offset = "observed"', 'offset = "sometimes"'), "adjust.navigation.offset must be one of"),
        (base.replace("[run]", "[run"), "not valid TOML"),
        (base.replace('steps = ["baarda"]', 'steps = ["robust", "snoop"]'), "adjust.qc.steps must be"),
        (base.replace('steps = ["baarda"]', 'steps = ["baarda", "baarda"]'), "adjust.qc.steps must be"),
        (base.replace("baarda_limit = 4.0", "baarda_limit = 0.0"), "adjust.qc.baarda_limit must be > 0"),
        (base.replace('robust_function = "danish"', 'robust_function = "tukey"'),
         "adjust.qc.robust_function must be one of"),
        (base.replace('robust_scale = "mad"', 'robust_scale = "iqr"'), "adjust.qc.robust_scale must be one of"),
        (base.replace("baarda_limit = 4.0", "baarda_limit = 4.0\nalpha = 0.001"), "unknown key adjust.qc.alpha"),
        (base.replace("baarda_limit = 4.0", "baarda_limit = 4.0\nmax_seconds = -1.0"),
         "adjust.qc.max_seconds must be >= 0"),
        (base.replace("baarda_limit = 4.0", "baarda_limit = 4.0\nmax_rounds = 2.5"), "adjust.qc.max_rounds must be"),
        (base.replace("baarda_limit = 4.0", 'baarda_limit = 4.0\nbaarda_separable = "yes"'),
         "adjust.qc.baarda_separable must be"),
        (base[:base.index("[adjust.navigation]")] + base[base.index("[adjust.qc]"):].replace(
            'steps = ["baarda"]', 'steps = ["offsets"]'), "there are no navigation observations"),
        # every navigation group of the example has one image: an offset of a group cannot be estimated
        (base.replace('steps = ["baarda"]', 'steps = ["baarda", "offsets"]'),
         "no navigation group has 2 or more images"),
    ]
    for k, (text, match) in enumerate(cases):
        p = example.parent / f"bad{k}.toml"
        p.write_text(text)
        with pytest.raises(ConfigError, match=match) as err:
            run(p, scheduler="sync")
        assert p.name in str(err.value)                # the file is named


def test_bad_inputs_fail_early_with_named_errors(example, tmp_path):
    # an unreadable image: found while building the graph, before any step runs
    folder = example.parent
    bad = folder / "mission" / "broken.nc"
    bad.write_bytes(b"not a netCDF file")
    cfg = _config(example, "badimage", **{'pixels = "mission/orbit1_nac.nc"': 'pixels = "mission/broken.nc"'})
    with pytest.raises(ConfigError, match="broken.nc are not a readable image"):
        run(cfg, scheduler="sync")
    assert not (folder / "badimage" / "store").exists() or not any((folder / "badimage" / "store").rglob("*.*"))
    # a meta-kernel naming a kernel that is not there: MissingKernelError before any step
    mk = folder / "mission" / "navigation.tm"
    broken_mk = folder / "mission" / "broken.tm"
    broken_mk.write_text(mk.read_text().replace("block_navigation.bc", "block_navigation_gone.bc"))
    cfg = _config(example, "badkernel", **{'metakernel = "mission/navigation.tm"': 'metakernel = "mission/broken.tm"'})
    with pytest.raises(MissingKernelError, match="block_navigation_gone.bc"):
        run(cfg, scheduler="sync")
    assert issubclass(MissingKernelError, LunarmapError)


def test_images_without_overlap_are_reported_and_skipped(example):
    """Every pair is skipped when the overlap threshold cannot be met: a named error, not a traceback."""
    cfg = _config(example, "nooverlap", **{"min_overlap = 0.05": "min_overlap = 0.999"})
    with pytest.raises(WorkflowError, match="no image pair overlaps"):
        run(cfg, scheduler="sync", report=False)
    steps = (example.parent / "nooverlap" / "store" / "match")
    notes = [np.load(p)["note"].item() for p in steps.glob("*.npz")]
    assert len(notes) == 6 and all(n.startswith("skipped") for n in notes)


def test_isis_cube_pixels_give_the_same_run(example, serial):
    """The same images as ISIS cubes (lunarmap.io) instead of netCDF: identical adjustment."""
    from lunarmap.io.cube import write_cube
    from lunarmap.workflows.steps import read_pixels

    replace = {}
    for name in NAMES:
        nc = example.parent / "mission" / f"{name}.nc"
        cube = example.parent / "mission" / f"{name}.cub"
        write_cube(cube, read_pixels(nc).values, pixel_type="Real")
        replace[f'pixels = "mission/{name}.nc"'] = f'pixels = "mission/{name}.cub"'
    res = run(_config(example, "cubes", **replace), scheduler="sync", report=False)
    np.testing.assert_array_equal(_points(res), _points(serial))


def test_graph_stays_small_and_a_rerun_starts_no_cluster(example, serial, monkeypatch):
    """About two tasks per image (one per image, about one match batch per image, the block), and a rerun
    whose outputs are all stored neither computes nor starts a cluster; renaming images gives another
    tie-point table (its key covers the names) and reuses every match."""
    import lunarmap.workflows.engine as eng
    from lunarmap.workflows.store import Store

    cfg = serial.config
    store = Store(cfg.output / "store")
    first = eng.build_graph(cfg, store, images_only=True)
    assert sorted(first.stage_of.values()) == ["image"] * 4 and not first.computes()
    done = eng._execute(first, "sync", eng._Progress(first.stage_of))
    graph = eng.build_graph(cfg, store, done=done)
    stages = list(graph.stage_of.values())
    assert stages.count("match") <= len(NAMES) and len(graph.pairs) == 6
    assert len(first.tasks) + len(graph.tasks) <= 2 * len(NAMES) + 3 + min(16, len(NAMES))
    assert not graph.computes()
    # the adjustment is a barrier: every other task of the block's graph comes before or after it, so it runs
    # alone and may take every core of its worker (workflows.steps._step(threads=ALL))
    from dask.core import get_dependencies

    dsk: dict = {}
    for task in graph.tasks.values():
        dsk.update(dict(task.__dask_graph__()))
    deps = {k: set(get_dependencies(dsk, k)) & set(graph.tasks) for k in graph.tasks}

    def before(k: str) -> set:
        out, todo = set(), list(deps[k])
        while todo:
            d = todo.pop()
            if d not in out:
                out.add(d)
                todo.extend(deps[d])
        return out

    (adj,) = [k for k, s in graph.stage_of.items() if s == "adjust"]
    after = {k for k in graph.tasks if adj in before(k)}
    assert before(adj) | after | {adj} == set(graph.tasks)
    assert {graph.stage_of[k] for k in before(adj)} == {"match", "tiepoints"}
    assert {graph.stage_of[k] for k in after} == {"kernels", "rpc_adjusted"}

    def no_cluster(*args, **kwargs):
        raise AssertionError("a cluster was started for a run with nothing to compute")

    monkeypatch.setattr(eng, "_client", no_cluster)
    assert run(cfg, scheduler=None, report=False).computed == 0
    monkeypatch.undo()
    renamed = load_config(_config(example, "serial", **{'name = "orbit2_nac"': 'name = "orbit2_nac_b"'}))
    g2 = eng.build_graph(renamed, store, done={k.replace("orbit2_nac", "orbit2_nac_b"): v for k, v in done.items()})
    tie = [k for k, s in graph.stage_of.items() if s == "tiepoints"]
    tie2 = [k for k, s in g2.stage_of.items() if s == "tiepoints"]
    assert tie != tie2 and not Path(g2.outputs[tie2[0]][0]).exists()
    assert {k for k, s in g2.stage_of.items() if s == "match"} == {k for k, s in graph.stage_of.items() if s == "match"}


def test_the_steps_called_in_order_without_dask_fill_the_serial_run_s_store(example, serial, tmp_path):
    """``engine.call_steps`` (the bench's ``steps`` baseline) calls the graph's own step functions: into a fresh
    store they write every entry of the serial run under the same keys, with the same matches and points."""
    import lunarmap.workflows.engine as eng
    from lunarmap.workflows.store import Store

    cfg = serial.config.__class__(**{**serial.config.__dict__, "output": tmp_path / "steps"})
    store = Store(cfg.output / "store")
    store.root.mkdir(parents=True)
    seconds: dict[str, float] = {}
    first = eng.build_graph(cfg, store, images_only=True)
    done = eng.call_steps(first, seconds)
    res = eng.call_steps(eng.build_graph(cfg, store, done=done), seconds)
    assert set(seconds) == {"image", "match", "tiepoints", "adjust", "kernels", "rpc_adjusted"}
    ref = serial.folder / "store"
    # the serial run's store also holds what other tests of this module computed into it (their QC or
    # navigation variants): every entry of the steps must be there under the same key
    for step in ("isd", "footprint", "rpc", "pyramid", "detect", "match", "tiepoints", "adjust", "rpc_adjusted"):
        mine = {p.name for p in (store.root / step).iterdir()}
        assert mine and mine <= {p.name for p in (ref / step).iterdir()}, step
    for p in (store.root / "match").glob("*.npz"):
        with np.load(ref / "match" / p.name) as a, np.load(p) as b:
            assert all(np.array_equal(a[k], b[k]) for k in a.files), p.name
    adj = next(v for k, v in res.items() if k.startswith("adjust-"))
    with xr.open_dataset(Path(adj.path) / "points.nc") as ds:
        np.testing.assert_allclose(ds["xyz"].values, _points(serial), rtol=1e-9, atol=0)


def test_a_pyramid_store_lost_mid_run_is_computed_again_with_the_same_results(example, serial, monkeypatch, caplog):
    """Pyramid stores deleted after the images' phase (or damaged) are computed again; results identical."""
    import logging

    import lunarmap.workflows.engine as eng

    out = serial.config.output
    cfg = _config(example, "pyramids")
    shutil.copytree(out / "store", Path(load_config(cfg).output) / "store", dirs_exist_ok=True)
    store = Path(load_config(cfg).output) / "store"
    for p in (store / "match").glob("*.npz"):
        p.unlink()                                    # the pairs must read the images again
    real = eng.build_graph

    def lose_pyramids(*args, **kwargs):
        if kwargs.get("done") is not None:            # between the two phases
            files = sorted((store / "pyramid").glob("*.nc"))
            files[0].unlink()
            files[1].write_bytes(files[1].read_bytes()[:2000])
        return real(*args, **kwargs)

    monkeypatch.setattr(eng, "build_graph", lose_pyramids)
    with caplog.at_level(logging.WARNING, logger="lunarmap"):
        res = run(cfg, scheduler="sync", report=False)
    assert res.counts()["match"] == (6, 0) and res.counts()["pyramid"] == (0, 4)
    assert sum("computing its pyramid again" in r.message for r in caplog.records) == 2
    np.testing.assert_array_equal(_points(res), _points(serial))
    monkeypatch.undo()
    # a damaged store found by the images' phase: recomputed there
    victim = sorted((store / "pyramid").glob("*.nc"))[0]
    victim.write_bytes(b"garbage")
    from lunarmap.errors import StoreDamageWarning

    with pytest.warns(StoreDamageWarning, match=victim.name):      # its checksum says so (issue 28)
        res = run(cfg, scheduler="sync", report=False)
    assert res.counts()["pyramid"] == (1, 3) and res.computed == 1


def test_pixels_that_do_not_match_their_label_are_named(example):
    cfg = _config(example, "mismatch", **{'pixels = "mission/orbit1_nac.nc"': 'pixels = "mission/orbit2_frame_a.nc"'})
    with pytest.raises(WorkflowError, match="orbit1_nac.*label.*says"):
        run(cfg, scheduler="sync", report=False)


# -- checks before any work (issue 29) ---------------------------------------------------------------

def _without(text: str, start: str, end: str) -> str:
    return text[:text.index(start)] + text[text.index(end):]


def _no_store_entries(folder: Path) -> bool:
    return not (folder / "store").exists() or not any(p.is_file() and p.name != "digests.json"
                                                      for p in (folder / "store").rglob("*"))


def test_points_measured_in_images_not_in_the_configuration_fail_before_any_step(example):
    text = example.read_text().replace('output = "run"', 'output = "subset"')
    sub = _without(text, '[[images]]\nname = "orbit2_frame_a"', "[dtm]")
    cfg = example.parent / "subset.toml"
    cfg.write_text(sub)
    with pytest.raises(ConfigError, match='points.path.*orbit2_frame_a.*other_images = "ignore"') as err:
        run(cfg, scheduler="sync")
    assert "subset.toml" in str(err.value) and "points.nc" in str(err.value)
    assert _no_store_entries(example.parent / "subset")
    # the fix the message names: those measures are dropped, and the plan says so
    from lunarmap.workflows import plan

    cfg.write_text(sub.replace('path = "points.nc"', 'path = "points.nc"\nother_images = "ignore"'))
    p = plan(cfg)
    assert p.images == NAMES[:3] and p.points.dropped_measures > 0 and p.points.control >= 3
    assert "measures in other images dropped" in p.text()
    assert _no_store_entries(example.parent / "subset")


def test_no_points_and_no_navigation_is_a_datum_error_before_any_step(example):
    text = example.read_text().replace('output = "run"', 'output = "nodatum"')
    text = _without(_without(text, "[points]", "[rpc]"), "[adjust.navigation]", "[adjust.qc]")
    cfg = example.parent / "nodatum.toml"
    cfg.write_text(text)
    with pytest.raises(ConfigError, match=r"no datum.*add \[adjust.navigation\].*3 or more control points"):
        run(cfg, scheduler="sync")
    assert _no_store_entries(example.parent / "nodatum")


def test_without_points_the_run_estimates_the_tie_variance_from_the_tie_points(example, serial):
    """No [points] (optional): the default estimate_tie_variance has only the tie-point group to estimate."""
    text = example.read_text().replace('output = "run"', 'output = "nopoints"')
    text = _without(_without(text, "[points]", "[rpc]"), "[adjust.qc]", "[report]")
    cfg = example.parent / "nopoints.toml"
    cfg.write_text(text)
    shutil.copytree(serial.folder / "store", example.parent / "nopoints" / "store", dirs_exist_ok=True)
    res = run(cfg, scheduler="sync", report=False)
    counts = res.counts()
    assert counts["adjust"] == (1, 0) and counts["match"][0] == 0     # only the adjustment and what follows
    s = res.summary
    assert abs(s["sigma0"] - 1.0) < 0.1 and s["converged"] and len(s["variance_factors"][-1]) == 1
    assert "check_rms_after_m" not in s


def test_dry_run_prints_the_plan_and_computes_nothing(example, serial, capsys):
    from lunarmap.cli import main

    # (other tests rewrite serial.toml: the serial run's configuration is written again)
    assert main(["run", str(_config(example, "serial")), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert f"images ({len(NAMES)}): " + ", ".join(NAMES) in out
    assert "candidate pairs: 6 of 6" in out and "nothing was run" in out
    assert "adjust           0 compute    1 reuse" in out         # the serial run's store has it
    cfg = _config(example, "dryrun")
    assert main(["run", str(cfg), "--dry-run"]) == 0
    assert "image            4 compute    0 reuse" in capsys.readouterr().out
    assert _no_store_entries(example.parent / "dryrun")


def test_a_failing_step_prints_one_lunarmap_line_and_nothing_from_dask(example):
    """On a local cluster: the worker's "Compute Failed" block and the shutdown notices go to dask.log."""
    cfg = _config(example, "failing", **{'pixels = "mission/orbit1_nac.nc"': 'pixels = "mission/orbit2_frame_a.nc"'})
    proc = subprocess.run([sys.executable, "-m", "lunarmap", "run", str(cfg), "--workers", "1"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("lunarmap: error:")]
    assert len(errors) == 1 and "orbit1_nac" in errors[0] and "run.log" in errors[0], proc.stderr
    assert all(ln.startswith("lunarmap: ") for ln in proc.stderr.splitlines()), proc.stderr
    for noise in ("distributed", "Traceback", "Compute Failed", "nanny"):
        assert noise not in proc.stderr
    log = (example.parent / "failing" / "run.log").read_text()
    assert "Traceback" in log and "WorkflowError" in log
