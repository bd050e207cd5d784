"""Issue 28: faults injected into runs. A damaged store entry of every kind is detected, named and computed
again, with final figures identical to an undamaged run; ``--check`` finds the damage without computing;
a killed run resumes to the same figures; a read-only run folder and a full disk (a small tmpfs, where
this machine allows mounting) raise named errors before work / without half-written files; a second
run in the same folder stops with :class:`RunLockedError` or waits and computes nothing; a stale lock
is taken over. Renamed, reordered and edited inputs recompute exactly the steps whose output depends
on them.

``LUNARMAP_FAULTS_FULL=1`` runs every store kind x every damage separately (33 reruns, ~2 min) instead
of one rerun with every kind damaged at once.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from lunarmap.errors import DiskFullError, DiskWriteError, RunLockedError, StoreDamageWarning
from lunarmap.workflows import load_config, run, write_example

NAMES = ["orbit1_nac", "orbit2_nac", "orbit2_frame_a"]
FULL = os.environ.get("LUNARMAP_FAULTS_FULL") == "1"

#: store kinds: step folder and the file to damage inside an entry ("" = the entry itself)
KINDS = {"isd": "", "footprint": "", "rpc": "", "pyramid": "", "detect": "", "match": "", "tiepoints": "",
         "adjust": "summary.json", "kernels": "kernels.json", "rpc_adjusted": ""}
DAMAGES = ("truncate", "empty", "flip")


@pytest.fixture(scope="module")
def example(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("faults_example")
    cfg = write_example(folder, quick=True, names=NAMES, n_control=4, n_check=8)
    # the faults are the store's, not the adjustment's: a plain, quick adjustment (no quality control)
    text = cfg.read_text()
    text = text.replace(text[text.index("[adjust.qc]"):text.index("[report]")], "")
    cfg.write_text(text.replace("estimate_tie_variance = true", "estimate_tie_variance = false"))
    return cfg


def _config(example: Path, output: str, text: str | None = None) -> Path:
    text = (text if text is not None else example.read_text()).replace('output = "run"', f'output = "{output}"')
    path = example.parent / f"{output}.toml"
    path.write_text(text)
    return path


def _figures(folder: Path) -> dict:
    """What a run produced, for comparing runs bit for bit."""
    out = folder / "outputs"
    with xr.open_dataset(out / "adjustment" / "points.nc") as ds:
        xyz = ds["xyz"].values.copy()
    with xr.open_dataset(out / "tiepoints.nc") as ds:
        ties = {k: ds[k].values.copy() for k in ("point_id", "image_id", "line", "sample")}
    s = json.loads((out / "adjustment" / "summary.json").read_text())
    keep = {k: s[k] for k in ("sigma0", "iterations", "n_points", "n_observations", "rms_px", "check_rms_after_m")}
    return {"xyz": xyz, "ties": ties, "summary": keep,
            "kernels": sorted(p.name for p in (folder / "outputs").glob("*.tm"))}


def _same(a: dict, b: dict) -> None:
    np.testing.assert_array_equal(a["xyz"], b["xyz"])
    for k in a["ties"]:
        np.testing.assert_array_equal(a["ties"][k], b["ties"][k])
    assert a["summary"] == b["summary"] and a["kernels"] == b["kernels"]


@pytest.fixture(scope="module")
def baseline(example):
    res = run(_config(example, "baseline"), scheduler="sync", report=False)
    return res, _figures(res.folder)


def _run_tolerating_damage(cfg, **kw):
    """A run that may find entries a kill or a full disk left without their checksum (warned, recomputed)."""
    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always", StoreDamageWarning)
        return run(cfg, scheduler="sync", report=False, **kw)


def _copy_run(baseline, dst: Path) -> Path:
    shutil.copytree(baseline[0].folder, dst)
    return dst


def _entry(store: Path, kind: str) -> Path:
    entries = sorted(p for p in (store / kind).iterdir() if not p.name.endswith(".sha256") and not p.name.startswith("."))
    assert entries, kind
    e = entries[0]
    return e / KINDS[kind] if KINDS[kind] else e


def _damage(path: Path, how: str) -> None:
    data = path.read_bytes()
    st = path.stat()
    if how == "truncate":
        data = data[: len(data) // 2]
    elif how == "empty":
        data = b""
    else:                                    # a few bytes flipped in place, same size
        b = bytearray(data)
        for k in range(len(b) // 3, len(b) // 3 + 8):
            b[k] ^= 0xFF
        data = bytes(b)
    path.write_bytes(data)
    if how == "flip":                        # same size; a new time (as any write gives it)
        os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))


def _rerun_damaged(example, baseline, tmp_name: str, damaged: dict[str, str], tmp_path: Path) -> None:
    folder = _copy_run(baseline, tmp_path / tmp_name)
    cfg = _config(example, tmp_name, example.read_text().replace('output = "run"', f'output = "{folder}"'))
    store = folder / "store"
    paths = {}
    for kind, how in damaged.items():
        if kind == "digests.json":
            p = store / "digests.json"
        elif kind == "outputs":
            p = folder / "outputs" / "adjustment" / "summary.json"
        else:
            p = _entry(store, kind)
        _damage(p, how)
        paths[kind] = p
    # --check finds every damaged store entry and changes nothing
    from lunarmap.workflows.engine import check_run

    before = sorted(str(p) for p in store.rglob("*"))
    n, problems = check_run(cfg)
    assert sorted(str(p) for p in store.rglob("*")) == before
    for kind, p in paths.items():
        if kind != "outputs":
            assert any(str(p) in why or str(p.parent) in why for why in problems), (kind, problems)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = run(cfg, scheduler="sync", report=False)
    named = [str(w.message) for w in caught if issubclass(w.category, StoreDamageWarning)]
    counts = res.counts()
    for kind, p in paths.items():
        if kind in KINDS:
            entry = p if not KINDS[kind] else p.parent
            assert any(str(entry) in m for m in named), (kind, named)
            if kind != "footprint":                              # footprints are part of the image task
                assert counts[kind][0] >= 1, (kind, counts)    # recomputed, not reused
    _same(_figures(folder), baseline[1])
    assert check_run(cfg)[1] == []


def test_every_kind_of_damaged_store_entry_is_recomputed_with_identical_results(example, baseline, tmp_path):
    """One rerun with one entry of every kind damaged (damages rotating), digests.json and an output copy."""
    damaged = {kind: DAMAGES[i % 3] for i, kind in enumerate(KINDS)}
    damaged["digests.json"] = "truncate"
    damaged["outputs"] = "empty"
    _rerun_damaged(example, baseline, "damaged_all", damaged, tmp_path)


@pytest.mark.skipif(not FULL, reason="the full matrix of store kinds x damages: LUNARMAP_FAULTS_FULL=1")
@pytest.mark.parametrize("kind", list(KINDS) + ["digests.json"])
@pytest.mark.parametrize("how", DAMAGES)
def test_each_damage_of_each_store_kind(example, baseline, tmp_path, kind, how):
    _rerun_damaged(example, baseline, f"damaged_{kind}_{how}".replace(".", "_"), {kind: how}, tmp_path)


def test_a_store_entry_without_its_checksum_is_not_reused(example, baseline, tmp_path):
    folder = _copy_run(baseline, tmp_path / "nosidecar")
    cfg = _config(example, "nosidecar", example.read_text().replace('output = "run"', f'output = "{folder}"'))
    tie = _entry(folder / "store", "tiepoints")
    Path(str(tie) + ".sha256").unlink()                 # killed between the output's rename and its checksum's
    with pytest.warns(StoreDamageWarning, match="no checksum"):
        res = run(cfg, scheduler="sync", report=False)
    assert res.counts()["tiepoints"] == (1, 0) and res.counts()["adjust"] == (0, 1)
    _same(_figures(folder), baseline[1])


# --- kill and resume ------------------------------------------------------------------------------

def test_a_run_killed_at_random_points_resumes_to_identical_results(example, baseline, tmp_path):
    rng = np.random.default_rng(28)
    folder = tmp_path / "killed"
    cfg = _config(example, "killed", example.read_text().replace('output = "run"', f'output = "{folder}"'))
    cmd = [sys.executable, "-m", "lunarmap", "run", str(cfg), "--serial"]
    for delay in sorted(rng.uniform(2.0, 6.0, 2 if FULL else 1)):
        p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        time.sleep(delay)
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
        p.wait()
    res = _run_tolerating_damage(cfg)
    _same(_figures(folder), baseline[1])
    # nothing half-written: every entry verifies, no temporary name is left
    from lunarmap.workflows.store import verify_store

    assert verify_store(folder / "store")[1] == []
    assert not [p for p in (folder / "store").rglob(".*")]
    assert res.summary["n_points"] == baseline[0].summary["n_points"]


# --- disk faults ----------------------------------------------------------------------------------

def _mount_tmpfs(where: Path, size: str) -> None:
    where.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a small tmpfs needs root (this machine: not root): disk-full/read-only not tested")
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)], capture_output=True)
    if r.returncode:
        pytest.skip(f"this machine does not allow mounting a tmpfs: {r.stderr.decode().strip()}")


def _umount(where: Path) -> None:
    subprocess.run(["umount", "-l", str(where)], capture_output=True)


def test_read_only_run_folder_is_named_before_any_work(example, baseline, tmp_path):
    mnt = tmp_path / "ro"
    _mount_tmpfs(mnt, "16m")
    try:
        shutil.copytree(baseline[0].folder, mnt / "done")          # a finished run: it would reuse everything
        (mnt / "fresh").mkdir()
        r = subprocess.run(["mount", "-o", "remount,ro", str(mnt)], capture_output=True)
        if r.returncode:
            pytest.skip(f"cannot remount the tmpfs read-only: {r.stderr.decode().strip()}")
        for name in ("done", "fresh", "fresh/sub"):
            cfg = _config(example, f"ro_{name.replace('/', '_')}",
                          example.read_text().replace('output = "run"', f'output = "{mnt / name}"'))
            t = time.perf_counter()
            with pytest.raises(DiskWriteError, match="the run folder") as info:
                run(cfg, scheduler="sync", report=False)
            assert str(mnt / name) in str(info.value) and time.perf_counter() - t < 5
            assert isinstance(info.value, OSError)
        assert not (mnt / "fresh" / "store").exists()
    finally:
        _umount(mnt)


def test_full_disk_is_named_up_front_and_mid_run_leaves_nothing_half_written(example, baseline, tmp_path,
                                                                          monkeypatch):
    import lunarmap.workflows.engine as engine
    from lunarmap.workflows.store import verify_store

    mnt = tmp_path / "full"
    _mount_tmpfs(mnt, "1200k")
    try:
        cfg = _config(example, "full", example.read_text().replace('output = "run"', f'output = "{mnt / "run"}"'))
        # up front: the images' pyramids and points will not fit
        with pytest.raises(DiskFullError, match="MB needed") as info:
            run(cfg, scheduler="sync", report=False)
        assert not list((mnt / "run" / "store").glob("*/*"))
        # the estimate passed (as if the disk were bigger): the disk fills mid-run
        monkeypatch.setattr(engine, "_space_needed", lambda cfg, graph: 0)
        with pytest.raises(DiskFullError, match="no space left|the disk is full") as info:
            run(cfg, scheduler="sync", report=False)
        assert str(mnt / "run") in str(info.value)
        store = mnt / "run" / "store"
        assert verify_store(store)[1] == [] or all("no checksum" in w for w in verify_store(store)[1])
        assert not [p for p in store.rglob(".*")]                     # no temporary file left behind
        # more space: the run resumes and ends as an undamaged run does
        subprocess.run(["mount", "-o", "remount,size=32m", str(mnt)], check=True)
        monkeypatch.undo()
        _run_tolerating_damage(cfg)
        _same(_figures(mnt / "run"), baseline[1])
    finally:
        _umount(mnt)


# --- concurrent runs and the lock -----------------------------------------------------------------

def test_second_run_in_one_folder_stops_or_waits_and_the_work_is_done_once(example, baseline, tmp_path):
    # the first run has the block left to compute (adjustment, kernels, adjusted RFMs): seconds, not a minute
    folder = _copy_run(baseline, tmp_path / "concurrent")
    from lunarmap.workflows.store import remove_entry

    for step in ("adjust", "kernels", "rpc_adjusted"):
        for e in list((folder / "store" / step).iterdir()):
            if not e.name.endswith(".sha256"):
                remove_entry(e)
    shutil.rmtree(folder / "outputs")
    (folder / "run.log").unlink()
    cfg = _config(example, "concurrent", example.read_text().replace('output = "run"', f'output = "{folder}"'))
    first = subprocess.Popen([sys.executable, "-m", "lunarmap", "run", str(cfg), "--serial"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        lock = folder / "run.lock"
        t0 = time.monotonic()
        while not (lock.exists() and lock.read_text().strip() and "released" not in lock.read_text()):
            assert time.monotonic() - t0 < 60 and first.poll() is None
            time.sleep(0.05)
        with pytest.raises(RunLockedError, match=f"pid {first.pid}"):
            run(cfg, scheduler="sync", report=False)
        second = run(cfg, scheduler="sync", report=False, wait=True)      # waits, then finds everything stored
        assert first.wait(120) == 0
    finally:
        if first.poll() is None:
            first.kill()
    assert second.computed == 0
    _same(_figures(folder), baseline[1])
    log = (folder / "run.log").read_text()
    assert log.count("run finished") == 2


def test_a_stale_lock_is_taken_over(example, baseline, tmp_path, caplog):
    folder = _copy_run(baseline, tmp_path / "stale")
    cfg = _config(example, "stale", example.read_text().replace('output = "run"', f'output = "{folder}"'))
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    (folder / "run.lock").write_text(json.dumps({"pid": dead.pid, "host": os.uname().nodename,
                                                 "started": "2026-01-01T00:00:00Z"}))
    import logging

    with caplog.at_level(logging.WARNING, logger="lunarmap"):
        res = run(cfg, scheduler="sync", report=False)
    assert res.computed == 0 and any("stale lock" in r.message and str(dead.pid) in r.message for r in caplog.records)
    held = json.loads((folder / "run.lock").read_text())
    assert held["pid"] == os.getpid() and "released" in held


# --- keys cover every input ------------------------------------------------------------------------

def test_renamed_reordered_and_edited_inputs_recompute_exactly_what_depends_on_them(example, baseline, tmp_path):
    """Issue 28's rename (o1_nac -> orbit1_nac: the stored tie-point table with the old names was reused and
    the adjustment failed), plus a reorder and an edited label, in the baseline's own folder copy."""
    folder = _copy_run(baseline, tmp_path / "keys")
    text = example.read_text().replace('output = "run"', f'output = "{folder}"')

    def rerun(t: str, name: str):
        return run(_config(example, name, t), scheduler="sync", report=False)

    # 1. rename every image: per-image steps and matches are reused (they do not depend on names), the
    #    tie-point table and everything after it are computed again, and the run succeeds
    renamed = text
    for n in NAMES:
        renamed = renamed.replace(f'name = "{n}"', f'name = "x_{n}"')
    # the control and check points name their images too: the same points under the new names
    from dataclasses import replace

    from lunarmap.adjust.network import read_network, write_network

    net = read_network(example.parent / "points.nc")
    write_network(replace(net, image_id=np.array([f"x_{n}" for n in net.image_id])), tmp_path / "points_x.nc")
    renamed = renamed.replace('path = "points.nc"', f'path = "{tmp_path / "points_x.nc"}"')
    assert renamed.count("x_") >= len(NAMES) + 0 and str(tmp_path / "points_x.nc") in renamed
    res = rerun(renamed, "keys_renamed")
    c = res.counts()
    assert all(c[s] == (0, len(NAMES)) for s in ("isd", "pyramid", "detect")) and c["match"][0] == 0
    assert c["tiepoints"] == (1, 0) and c["adjust"] == (1, 0) and c["kernels"] == (1, 0)
    assert sorted(res.summary["images"]) == sorted(f"x_{n}" for n in NAMES)
    with xr.open_dataset(folder / "outputs" / "tiepoints.nc") as ds:
        assert sorted(ds["image"].values.tolist()) == sorted(f"x_{n}" for n in NAMES)
    np.testing.assert_array_equal(_figures(folder)["xyz"], baseline[1]["xyz"])
    # 2. back to the original names: everything is found stored
    assert rerun(text, "keys_back").computed == 0
    # 3. the images listed in another order: the per-image steps are reused; the table (its images in
    #    the configuration's order) and the adjustment are computed again
    head, *blocks = text.split("[[images]]\n")
    last = blocks[-1]
    cut = last.index("\n\n") + 2
    blocks[-1], tail = last[:cut], last[cut:]
    reordered = head + "".join("[[images]]\n" + b for b in blocks[::-1]) + tail
    assert reordered != text and load_config(_config(example, "keys_reordered", reordered)).images[0].name == NAMES[-1]
    c = rerun(reordered, "keys_reordered").counts()
    assert all(c[s] == (0, len(NAMES)) for s in ("isd", "pyramid", "detect"))
    assert c["tiepoints"] == (1, 0) and c["adjust"] == (1, 0)
    # 4. an edited label (one image's): its ISD and everything downstream of it recompute, the other
    #    images' per-image steps are reused
    lab = next(p for p in example.parent.rglob("*.lbl") if NAMES[2] in p.name)
    edited_lab = tmp_path / lab.name
    edited_lab.write_text(lab.read_text() + "\n")
    edited = text.replace(f'"{lab.relative_to(example.parent)}"', f'"{edited_lab}"')
    assert edited != text
    c = rerun(edited, "keys_edited").counts()
    assert c["isd"] == (1, 2) and c["pyramid"] == (0, 3) and c["detect"] == (0, 3)
    assert c["tiepoints"] == (1, 0) and c["adjust"] == (1, 0)
