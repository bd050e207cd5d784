"""One regression test per bug the fuzzing of the readers found (tests/test_fuzz_readers.py, bench/fuzz.py).

Before the fixes each of these inputs let a raw ``KeyError`` / ``ValueError`` / ``IndexError`` /
``OSError`` / ``RuntimeError`` / ``UnicodeDecodeError`` out of the reader; now each raises a named
lunarmap exception whose message names the file and the keyword.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from lunarmap.errors import (AdjustmentInputError, InvalidInputError, KernelError, LabelError, LabelKeywordError,
                             LunarmapError, NetworkFormatError, RpcFormatError, TiePointFormatError)
from fuzz_targets import _bal_seed, _network_seed, _tiepoint_seed, isis_cube_bytes


# --- labels and drivers --------------------------------------------------------------------------

@pytest.mark.parametrize("edit, error, match", [
    (("      Lines   = 52224\n", ""), LabelKeywordError, "lacks IsisCube/Core/Dimensions/Lines"),   # was KeyError
    (("    Group = Dimensions", "    Group = Dims"), LabelKeywordError, "lacks IsisCube/Core/Dimensions"),
    (("Samples = 5064", "Samples = 1D5"), LabelError, "Samples '1D5' is not an integer"),         # was ValueError
    (("NaifFrameCode = -990100", "NaifFrameCode = -99o100"), LabelError, "NaifFrameCode"),          # was ValueError
    (("Lines   = 52224", "Lines   = -3"), LabelError, "Lines -3 is less than 1"),
])
def test_image_support_names_bad_label_keywords(sim_mission, tmp_path, edit, error, match):
    from lunarmap.orientation.drivers import image_support

    text = (sim_mission.parent / "sim_nac_equator.lbl").read_text()
    assert edit[0] in text
    lab = tmp_path / "bad.lbl"
    lab.write_text(text.replace(edit[0], edit[1]))
    with pytest.raises(error, match=match) as info:
        image_support(lab, sim_mission)
    assert str(lab) in str(info.value)


def test_label_lookup_names_the_file_and_the_path(sim_mission):
    from lunarmap.labels import load_label

    path = sim_mission.parent / "sim_frame_a.lbl"
    lab = load_label(path)
    with pytest.raises(LabelKeywordError, match=r"lacks IsisCube/Instrument/NoSuchKey") as info:
        lab["IsisCube"]["Instrument"]["NoSuchKey"]
    assert str(path) in str(info.value) and isinstance(info.value, KeyError)   # except KeyError still works


# --- ISIS cube tables ----------------------------------------------------------------------------

def _cube(tmp_path, edit=None):
    data = isis_cube_bytes({"InstrumentPosition": {"J2000X": np.arange(5.0), "ET": np.arange(5.0)}})
    if edit:
        assert edit[0] in data
        data = data.replace(edit[0], edit[1], 1)
    p = tmp_path / "c.cub"
    p.write_bytes(data)
    return p


@pytest.mark.parametrize("edit, match", [
    ((b"  Records = 5\n", b""), "lacks Records"),                       # was KeyError
    ((b"  StartByte = 4097\n", b""), "lacks StartByte"),                # was KeyError
    ((b"Bytes = 80", b"Bytes = 8O"), "Bytes '8O' is not an integer"),   # was ValueError
    ((b"Size = 1", b"Size = 1e999"), "Size"),                           # was OverflowError
    ((b"StartByte = 4097", b"StartByte = 99999999"), "extends past the end of the file"),
])
def test_isis_table_names_bad_table_labels(tmp_path, edit, match):
    from lunarmap.labels import read_isis_table

    good = _cube(tmp_path)
    cols, _ = read_isis_table(good, "InstrumentPosition")
    assert np.array_equal(cols["ET"], np.arange(5.0))
    with pytest.raises(LabelError, match=match):
        read_isis_table(_cube(tmp_path, edit), "InstrumentPosition")


# --- netCDF readers --------------------------------------------------------------------------------

@pytest.fixture
def netcdf_files(tmp_path):
    from lunarmap.adjust.network import write_network
    from lunarmap.matching import write_tiepoints
    from lunarmap.rpc import write_netcdf
    from fuzz_targets import _rfm_seed

    return {"network": write_network(_network_seed(), tmp_path / "n.nc"),
            "tiepoints": write_tiepoints(_tiepoint_seed(), tmp_path / "t.nc"),
            "rpc": write_netcdf(_rfm_seed(tmp_path), tmp_path / "r.nc")}


def _readers():
    from lunarmap.adjust.network import read_network
    from lunarmap.matching import read_tiepoints
    from lunarmap.rpc import read_netcdf

    return {"network": (read_network, NetworkFormatError), "tiepoints": (read_tiepoints, TiePointFormatError),
            "rpc": (read_netcdf, RpcFormatError)}


@pytest.mark.parametrize("kind", ["network", "tiepoints", "rpc"])
def test_unreadable_netcdf_is_named(netcdf_files, kind, tmp_path):
    read, error = _readers()[kind]
    data = netcdf_files[kind].read_bytes()
    read(netcdf_files[kind])                                        # the good file reads
    for k, bad in enumerate((data[: len(data) // 2], b"not netcdf at all", b"CDF\x01" + bytes(100))):
        p = tmp_path / f"bad{k}.nc"                                 # were OSError / RuntimeError
        p.write_bytes(bad)
        # the last one is an empty but valid netCDF-3 file: readable, but not this kind of dataset
        with pytest.raises(error, match="not a readable netCDF file" if k < 2 else "not a|missing") as info:
            read(p)
        assert str(p) in str(info.value)
    with pytest.raises(FileNotFoundError):
        read(tmp_path / "absent.nc")


def _rewrite(path, change):
    with xr.open_dataset(path) as ds:
        ds = change(ds.load())
    path.unlink()
    ds.to_netcdf(path)
    return path


@pytest.mark.parametrize("change, match", [
    (lambda ds: ds.assign_attrs(version="abc"), "version 'abc' is not an integer"),           # was ValueError
    (lambda ds: ds.assign_attrs(radius="big"), "radius 'big'"),                                # was ValueError
    (lambda ds: ds.drop_vars("sample").assign(sample=("m2", ds["sample"].values[:3])),
     "sample has dimensions"),                                                                 # was ValueError
    (lambda ds: ds.assign(point_type=("point", np.where(np.arange(ds.sizes["point"]) == 0, np.nan, 0.0))),
     "point_type holds non-integer"),                                                          # was a cast warning
    (lambda ds: ds.assign(xyz_cov=(("point", "axis", "axis2"), ds["xyz_cov"].values[:, :, :2].repeat(2, 2)[:, :, :3])
                          ).isel(axis2=slice(0, 2)), "dimension axis2 has length 2"),
])
def test_malformed_network_layout_is_named(netcdf_files, change, match):
    from lunarmap.adjust.network import read_network

    with pytest.raises(NetworkFormatError, match=match):
        read_network(_rewrite(netcdf_files["network"], change))


@pytest.mark.parametrize("change, match", [
    (lambda ds: ds.drop_vars("sigma_line"), "missing sigma_line"),
    (lambda ds: ds.assign(point_id=ds["point_id"].astype(float).where(ds["observation"] != 3)), "point_id holds NaN"),
    (lambda ds: ds.assign(image_id=ds["image_id"] + 5), "image_id out of range"),
    (lambda ds: ds.drop_vars("line").assign(line=("o2", ds["line"].values[:4])), "must share one dimension"),
])
def test_malformed_tiepoint_table_is_named(netcdf_files, change, match):
    from lunarmap.adjust.network import network_from_tiepoints
    from lunarmap.matching import read_tiepoints

    path = _rewrite(netcdf_files["tiepoints"], change)
    with pytest.raises(TiePointFormatError, match=match):
        read_tiepoints(path)
    with xr.open_dataset(path) as ds:                               # the same table in memory (was ValueError)
        with pytest.raises(NetworkFormatError, match=match):
            network_from_tiepoints(ds.load())


# --- BAL, meta-kernels, image lists ------------------------------------------------------------------

@pytest.mark.parametrize("sidecar, match", [
    (b"{not json", "not JSON"),                         # was JSONDecodeError
    (b'{"a": "\xe9"}', "not JSON"),                     # was UnicodeDecodeError
    (b"[1, 2]", "must hold a JSON object"),             # was AttributeError in bal_to_problem
    (b'{"control_points": [0, 99]}', r"control point indices must be integers in \[0, 12\)"),   # was IndexError
    (b'{"control_points": [0.5]}', "control point indices must be integers"),
    (b'{"control_points": "x"}', "control points must be a list"),                            # was ValueError
])
def test_bal_sidecar_is_checked(tmp_path, sidecar, match):
    from lunarmap.adjust.bal import bal_to_problem, read_bal, write_bal

    write_bal(tmp_path / "p.bal", _bal_seed())
    (tmp_path / "p.meta.json").write_bytes(sidecar)
    with pytest.raises(AdjustmentInputError, match=match):
        bal_to_problem(read_bal(tmp_path / "p.bal"))


@pytest.mark.parametrize("header, match", [("-1 5 4", "negative count"), (None, "not an integer")])
def test_bal_counts_and_indices(tmp_path, header, match):
    from lunarmap.adjust.bal import read_bal, write_bal

    write_bal(tmp_path / "p.bal", _bal_seed())
    lines = (tmp_path / "p.bal").read_text().splitlines()
    if header:
        lines[0] = header
    else:
        lines[1] = "0.5 " + lines[1].split(" ", 1)[1]         # a camera index of 0.5 (was truncated to 0)
    (tmp_path / "p.bal").write_text("\n".join(lines))
    with pytest.raises(AdjustmentInputError, match=match):
        read_bal(tmp_path / "p.bal")


def test_metakernel_with_a_nul_in_a_kernel_name(tmp_path):
    from lunarmap.spice import KernelSet

    mk = tmp_path / "m.tm"
    mk.write_bytes(b"KPL/MK\n\\begindata\nKERNELS_TO_LOAD = ( 'a\x00b.bsp' )\n\\begintext\n")
    with pytest.raises(KernelError, match="NUL character"):     # was ValueError from pathlib
        KernelSet.from_metakernel(mk)


def test_image_list_that_is_not_text(tmp_path):
    from workflows.isd_batch import read_image_list

    p = tmp_path / "images.txt"
    p.write_bytes(b"a.lbl m.tm\n\xf6\xff.lbl m.tm\n")
    with pytest.raises(InvalidInputError, match="not text") as info:   # was UnicodeDecodeError
        read_image_list(p)
    assert isinstance(info.value, LunarmapError)


def test_isd_json_cut_anywhere_is_named(sim_mission, tmp_path):
    """The ISD reader held (no bug found in 10,000 inputs); a sweep of cuts keeps it that way."""
    from lunarmap.errors import IsdFormatError
    from lunarmap.orientation.drivers import image_support
    from lunarmap.orientation.isd import ImageSupport

    path = tmp_path / "a.json"
    image_support(sim_mission.parent / "sim_frame_a.lbl", sim_mission).write_json(path)
    text = path.read_bytes()
    doc = json.loads(text)
    for cut in np.linspace(1, len(text) - 2, 25).astype(int):
        path.write_bytes(text[:cut])
        with pytest.raises(IsdFormatError):
            ImageSupport.read_json(path)
    for key in ("instrument_position", "focal_length_model", "radii", "name_model"):
        path.write_text(json.dumps({k: v for k, v in doc.items() if k != key}))
        with pytest.raises(IsdFormatError, match=key):
            ImageSupport.read_json(path)


def test_damaged_netcdf_files_leave_no_open_descriptor(netcdf_files, tmp_path):
    """netCDF-C / HDF5 kept the descriptor of every damaged file it failed to open (the fuzzing run had
    ~500 open when it was noticed); the readers now open from memory."""
    import os
    import random

    read, error = _readers()["network"]
    raw = netcdf_files["network"].read_bytes()
    rng = random.Random(1)

    def open_fds() -> int:
        return len(os.listdir("/proc/self/fd"))

    read(netcdf_files["network"])
    before, failed = open_fds(), 0
    for k in range(60):
        data = bytearray(raw)
        for _ in range(4):
            data[rng.randrange(len(data))] = rng.randrange(256)
        p = tmp_path / f"d{k}.nc"
        p.write_bytes(bytes(data) if k % 2 else raw[: rng.randrange(len(raw))])
        try:
            read(p)
        except error:
            failed += 1
        p.unlink()
    assert failed > 20                       # the damage was real
    assert open_fds() == before


def test_netcdf_file_that_hangs_the_hdf5_library_is_named(monkeypatch):
    """Fuzzing found a mutated tie-point table on which netCDF-C/HDF5 never returns from ``nc_open`` (from a
    file or from memory; no Python timeout can interrupt it). The reader probes the open in a child process:
    the caller gets a named error after the probe's time limit instead of hanging."""
    import time

    import lunarmap.ncread as ncread
    from lunarmap.errors import TiePointFormatError
    from lunarmap.matching import read_tiepoints

    bad = Path(__file__).parent / "data" / "hdf5_open_never_returns.nc"
    monkeypatch.setattr(ncread, "PROBE_TIMEOUT", 1.0)
    t = time.monotonic()
    with pytest.raises(TiePointFormatError, match="did not finish opening it within 1 s"):
        read_tiepoints(bad)
    assert time.monotonic() - t < 10.0
    # the same file really hangs the library: the fork probe alone reports it (not an exception)
    assert ncread._probe_fork(bad.read_bytes(), 1.0) == "hang"


def test_netcdf_probe_falls_back_to_a_fresh_interpreter(netcdf_files, monkeypatch):
    """A fork probe that stalls on a good file (a lock held by another thread at fork time) is retried in a
    fresh interpreter, and the good file is read."""
    import lunarmap.ncread as ncread
    from lunarmap.matching import read_tiepoints

    calls = []
    monkeypatch.setattr(ncread, "_probe_fork", lambda data, timeout: calls.append(len(data)) or "hang")
    tp = read_tiepoints(netcdf_files["tiepoints"])
    assert calls and tp.sizes["observation"] > 0


@pytest.mark.parametrize("which", ["lunar_orbiter", "apollo"])
def test_historical_drivers_name_a_bad_frame_code(which, tmp_path, request):
    """bench/fuzz.py (10,000 inputs): the Lunar Orbiter driver raised a raw ValueError on
    ``NaifFrameCode = End`` (the Apollo driver read the code the same way)."""
    from lunarmap.orientation.drivers import image_support

    kset = request.getfixturevalue({"lunar_orbiter": "lo_set", "apollo": "apollo_set"}[which])
    label = next(p for p in sorted(kset.glob("*.lbl")))
    text = label.read_text()
    code = next(line for line in text.splitlines() if line.strip().startswith("NaifFrameCode"))
    bad = tmp_path / label.name
    bad.write_text(text.replace(code, "    NaifFrameCode             = End"))
    with pytest.raises(LabelError, match="NaifFrameCode 'End' is not an integer"):
        image_support(bad, next(kset.glob("*.tm")))


def test_absurd_image_size_is_named(sim_mission, tmp_path):
    """bench/fuzz.py: ``Lines`` of 10^18 made the line-scan sampling grid raise numpy's raw ValueError
    ("Maximum allowed size exceeded")."""
    from lunarmap.orientation.drivers import image_support

    text = (sim_mission.parent / "sim_nac_equator.lbl").read_text()
    lab = tmp_path / "huge.lbl"
    lab.write_text(text.replace("Lines   = 52224", "Lines   = 1000000000000000000"))
    with pytest.raises(LabelError, match="Lines 1000000000000000000 is more than 10000000"):
        image_support(lab, sim_mission)
