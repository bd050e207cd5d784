"""lunarmap.spice.writer: text kernels, SPK type 13 and CK type 3, written atomically."""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Iterator

import numpy as np
import pytest
import spiceypy

from lunarmap.errors import InvalidInputError, LunarmapError
from lunarmap.spice import SPICE_LOCK
from lunarmap.spice.kernelset import parse_text_kernel_data
from lunarmap.spice.writer import (Append, CkSegment, KernelDate, SpkSegment, atomic_path, format_assignments,
                                   text_kernel, write_ck, write_spk, write_text_kernel)
from lunarmap.synthetic import textkernels

# SPICE's text-kernel number parser is not correctly rounded: a shortest-repr
# decimal reads back within a few units in the last place (measured: <= 1.2e-15
# relative over 3000 random doubles of all magnitudes).
PARSE_RTOL = 4e-15


@contextlib.contextmanager
def furnished(*paths: Path) -> Iterator[None]:
    """Load kernels under the SPICE lock and unload exactly them afterwards."""
    with SPICE_LOCK:
        before = spiceypy.ktotal("ALL")
        for p in paths:
            spiceypy.furnsh(str(p))
        try:
            yield
        finally:
            for p in paths:
                spiceypy.unload(str(p))
            assert spiceypy.ktotal("ALL") == before


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


SAMPLE = {
    "LM_FLOAT": 699.62,
    "LM_TINY": -1.81e-05,
    "LM_THIRD": 1.0 / 3.0,
    "LM_INT": -990100,
    "LM_LIST": [0.0, -0.007, 142.85714285714286, 1e300, -2.5e-300, 7],
    "LM_ARRAY": np.arange(40, dtype=float).reshape(4, 10) * -0.125,
    "LM_STR": "it's a 'quoted' string",
    "LM_LONG": "/a/very/long/path/" + "x" * 150 + "/end",
    "LM_STRS": ["short", "y" * 81, "z"],
    "LM_DATE": KernelDate("2017-JAN-1"),
    "LM_APPEND": Append(["one"]),
}


def test_text_kernel_round_trips_through_spice_pool(tmp_path):
    k = write_text_kernel(tmp_path / "sample.tpc", "PCK", [("first block", {"LM_APPEND": "zero"}), SAMPLE],
                          comments="Round-trip test kernel.")
    assert max(len(line) for line in k.read_text().splitlines()) <= 132
    with furnished(k):
        assert spiceypy.gdpool("LM_FLOAT", 0, 1)[0] == pytest.approx(699.62, rel=PARSE_RTOL)
        assert spiceypy.gdpool("LM_TINY", 0, 1)[0] == pytest.approx(-1.81e-05, rel=PARSE_RTOL)
        assert spiceypy.gdpool("LM_THIRD", 0, 1)[0] == pytest.approx(1 / 3, rel=PARSE_RTOL)
        assert spiceypy.gipool("LM_INT", 0, 1)[0] == -990100
        np.testing.assert_allclose(spiceypy.gdpool("LM_LIST", 0, 10), SAMPLE["LM_LIST"], rtol=PARSE_RTOL)
        np.testing.assert_allclose(spiceypy.gdpool("LM_ARRAY", 0, 100), SAMPLE["LM_ARRAY"].ravel(),
                                   rtol=PARSE_RTOL)
        assert spiceypy.gcpool("LM_STR", 0, 1, 100)[0] == "it's a 'quoted' string"
        # long strings are continued with '+'; each pool value stays within 80 characters
        pieces = spiceypy.gcpool("LM_LONG", 0, 10, 100)
        assert len(pieces) == 3 and all(len(p) <= 80 for p in pieces) and pieces[0].endswith("+")
        assert spiceypy.stpool("LM_LONG", 0, "+")[0] == SAMPLE["LM_LONG"]
        assert spiceypy.stpool("LM_STRS", 1, "+")[0] == "y" * 81
        assert spiceypy.stpool("LM_STRS", 2, "+")[0] == "z"
        assert spiceypy.gdpool("LM_DATE", 0, 1)[0] == spiceypy.tparse("2017-JAN-1")[0]
        assert spiceypy.gcpool("LM_APPEND", 0, 5, 80) == ["zero", "one"]


def test_text_kernel_parses_back_with_lunarmaps_own_reader():
    text = text_kernel("FK", {"A": [1.0 / 3.0, -5], "B": "q" * 100, "C": Append([2.5])})
    data = parse_text_kernel_data(text)
    assert data["A"] == [1.0 / 3.0, -5.0]  # repr round-trips exactly through Python's float()
    assert "".join(str(v).rstrip("+") for v in data["B"]) == "q" * 100
    assert data["C"] == [2.5]


def test_lists_wrap_within_80_columns():
    text = format_assignments({"INS-990100_FOV_BOUNDARY_CORNERS": [-0.025488836797118435] * 12})
    lines = text.splitlines()
    assert len(lines) > 1 and max(len(line) for line in lines) <= 80
    assert lines[0].startswith("   INS-990100_FOV_BOUNDARY_CORNERS = ( ") and lines[-1].endswith(" )")


@pytest.mark.parametrize("data", [
    {"INS-990100_LUNARMAP_DISTORTION_MODEL": "radial"},  # 36 characters: SPICE allows 32
    {"A B": 1.0},
    {"X": float("nan")},
    {"X": [1.0, float("inf")]},
    {"X": True},
    {"X": []},
    {"X": [1.0, "a"]},
    {"X": [[1.0, 2.0]]},
    {"X": "caf\u00e9"},
    {"X": object()},
    {"X": 2 ** 60},
])
def test_invalid_text_kernel_data_writes_nothing(tmp_path, data):
    target = tmp_path / "bad.tpc"
    with pytest.raises(InvalidInputError):
        write_text_kernel(target, "PCK", [{"GOOD": 1.0}, data])
    assert leftovers(tmp_path) == []


def test_atomic_path_failure_keeps_old_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "k.bsp"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            assert tmp.parent == tmp_path and not tmp.exists()
            tmp.write_text("half written")
            raise RuntimeError("simulated failure while writing")
    assert target.read_text() == "old"
    assert leftovers(tmp_path) == ["k.bsp"]
    with atomic_path(target) as tmp:
        tmp.write_text("new")
    assert target.read_text() == "new" and leftovers(tmp_path) == ["k.bsp"]


def _circle(et: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    w = 2 * np.pi / 7000.0
    pos = 1800.0 * np.stack([np.cos(w * et), np.sin(w * et), 0.1 * np.sin(2 * w * et)], axis=1)
    vel = 1800.0 * w * np.stack([-np.sin(w * et), np.cos(w * et), 0.2 * np.cos(2 * w * et)], axis=1)
    return pos, vel


def test_spk13_round_trip(tmp_path):
    et = np.arange(0.0, 3601.0, 10.0) + 8.0e8
    pos, vel = _circle(et)
    k = write_spk(tmp_path / "c.bsp", [SpkSegment(-999, 301, "J2000", et, pos, vel, "TEST CIRCLE", 7)],
                  comments=["a test SPK", ""])
    probe = np.random.default_rng(3).uniform(et[0], et[-1], 50)
    ppos, pvel = _circle(probe)
    with furnished(k):
        got = np.array([spiceypy.spkez(-999, t, "J2000", "NONE", 301)[0] for t in probe])
    np.testing.assert_allclose(got[:, :3], ppos, atol=1e-9)  # km
    np.testing.assert_allclose(got[:, 3:], pvel, atol=1e-12)  # km/s
    assert leftovers(tmp_path) == ["c.bsp"]


def test_spk_bad_data_fails_before_writing(tmp_path):
    et = np.array([0.0, 10.0, 10.0, 30.0])
    pos, vel = _circle(et)
    with pytest.raises(InvalidInputError, match="strictly increasing"):
        write_spk(tmp_path / "c.bsp", [SpkSegment(-999, 301, "J2000", et, pos, vel)])
    with pytest.raises(InvalidInputError, match="NaN"):
        write_spk(tmp_path / "c.bsp", [SpkSegment(-999, 301, "J2000", et + np.arange(4), pos * np.nan, vel)])
    assert leftovers(tmp_path) == []


def test_spk_spice_failure_mid_write_leaves_nothing(tmp_path):
    et = np.arange(0.0, 100.0, 10.0)
    pos, vel = _circle(et)
    target = tmp_path / "c.bsp"
    target.write_bytes(b"previous")
    good = SpkSegment(-999, 301, "J2000", et, pos, vel, "GOOD")
    bad = SpkSegment(-998, 301, "NOT_A_FRAME", et, pos, vel, "BAD")  # SPICE rejects it after opening the file
    with pytest.raises(LunarmapError, match="NOT_A_FRAME|INVALIDREFFRAME"):
        write_spk(target, [good, bad])
    assert target.read_bytes() == b"previous"
    assert leftovers(tmp_path) == ["c.bsp"]


def _time_kernels(folder: Path, zero_et: float) -> tuple[Path, Path]:
    c, s = textkernels.lsk()
    lsk = write_text_kernel(folder / "t.tls", "LSK", s, c)
    c, s = textkernels.sclk(zero_et)
    return lsk, write_text_kernel(folder / "t.tsc", "SCLK", s, c)


def _spin(et: np.ndarray, t0: float) -> tuple[np.ndarray, np.ndarray]:
    """Rotation about +z at 1e-3 rad/s: C = [w t]_3 (J2000 -> frame)."""
    half = 0.5e-3 * (et - t0)
    q = np.stack([np.cos(half), np.zeros_like(half), np.zeros_like(half), -np.sin(half)], axis=1)
    av = np.tile([0.0, 0.0, 1e-3], (et.size, 1))
    return q, av


def test_ck3_round_trip_and_pool_restored(tmp_path):
    zero = 8.2e8
    lsk, sclk = _time_kernels(tmp_path, zero)
    et = zero + 1000.0 + np.arange(0.0, 600.5, 0.5)
    q, av = _spin(et, zero)
    with furnished(lsk):  # an already loaded kernel must stay loaded
        k = write_ck(tmp_path / "s.bc", [CkSegment(-990000, "J2000", et, q, av, "SPIN")],
                     time_kernels=[lsk, sclk])
        assert spiceypy.ktotal("ALL") == 1
        spiceypy.kinfo(str(lsk))
    assert spiceypy.ktotal("ALL") == 0
    probe = zero + 1000.0 + np.array([0.1, 123.456, 599.9])
    with furnished(lsk, sclk, k):
        for t in probe:
            cmat, clkout = spiceypy.ckgp(-990000, spiceypy.sce2c(-990, t), 0.0, "J2000")
            ang = 1e-3 * (t - zero)
            expect = np.array([[np.cos(ang), np.sin(ang), 0], [-np.sin(ang), np.cos(ang), 0], [0, 0, 1]])
            np.testing.assert_allclose(cmat, expect, atol=1e-13)
    assert sorted(leftovers(tmp_path)) == ["s.bc", "t.tls", "t.tsc"]


def test_ck_failures_leave_nothing(tmp_path):
    zero = 8.2e8
    lsk, sclk = _time_kernels(tmp_path, zero)
    et = zero + np.arange(0.0, 10.0, 0.5)
    q, av = _spin(et, zero)
    with pytest.raises(InvalidInputError, match="unit norm"):
        write_ck(tmp_path / "s.bc", [CkSegment(-990000, "J2000", et, 2 * q, av)], time_kernels=[lsk, sclk])
    with pytest.raises(LunarmapError):
        write_ck(tmp_path / "s.bc", [CkSegment(-990000, "J2000", et, q, av, "OK"),
                                     CkSegment(-990000, "NOT_A_FRAME", et, q, av, "BAD")],
                 time_kernels=[lsk, sclk])
    assert sorted(leftovers(tmp_path)) == ["t.tls", "t.tsc"]
    with SPICE_LOCK:
        assert spiceypy.ktotal("ALL") == 0
