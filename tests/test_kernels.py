"""Kernel sets and the SPICE pool owner, on small text kernels written by the test."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import spiceypy

from lunarmap.errors import KernelError, MissingKernelError
from lunarmap.spice import KernelSet, clear, ensure_loaded, kernels, loaded_kernel_set
from lunarmap.spice.kernelset import parse_text_kernel_data
from threadhelp import ThreadFailure, in_threads


def _text_kernel(path: Path, body: str) -> Path:
    path.write_text("KPL/PCK\n\\begindata\n" + body + "\n\\begintext\n")
    return path


def _metakernel(path: Path, values: str, names: list[str]) -> Path:
    files = "\n".join(f"      '$K/{n}'" for n in names)
    path.write_text(f"KPL/MK\n\\begindata\n   PATH_VALUES = ( {values} )\n   PATH_SYMBOLS = ( 'K' )\n"
                    f"   KERNELS_TO_LOAD = (\n{files}\n   )\n\\begintext\n")
    return path


def test_parse_text_kernel_values():
    data = parse_text_kernel_data("\\begindata\nA = ( 1.5D3, -2 )\nB = 'x''y'\nB += 'z'\nC = @2020-01-01\n"
                                  "\\begintext\nD = 3\n")
    assert data["A"] == [1500.0, -2.0]
    assert data["B"] == ["x'y", "z"]
    assert "D" not in data


def test_metakernel_relative_path_values_resolve_against_its_folder(tmp_path, monkeypatch):
    sub = tmp_path / "kernels"
    sub.mkdir()
    _text_kernel(sub / "a.tpc", "LUNARMAP_TEST_A = 7")
    mk = _metakernel(tmp_path / "set.tm", "'kernels'", ["a.tpc"])
    monkeypatch.chdir("/")
    kset = KernelSet.from_metakernel(mk)
    assert kset.paths == (str((sub / "a.tpc").resolve()),)
    with kernels(kset):
        assert spiceypy.gdpool("LUNARMAP_TEST_A", 0, 1)[0] == 7
    assert spiceypy.ktotal("ALL") == 0  # the context manager unloads


def test_metakernel_long_path_values_with_continuation(tmp_path):
    deep = tmp_path / ("d" * 60) / ("e" * 60)
    deep.mkdir(parents=True)
    _text_kernel(deep / "b.tpc", "LUNARMAP_TEST_B = 1")
    half = len(str(deep)) // 2
    mk = tmp_path / "long.tm"
    mk.write_text("\\begindata\nPATH_VALUES = ( '" + str(deep)[:half] + "+'\n '" + str(deep)[half:] +
                  "' )\nPATH_SYMBOLS = ( 'K' )\nKERNELS_TO_LOAD = ( '$K/b.tpc' )\n\\begintext\n")
    assert KernelSet.from_metakernel(mk).paths == (str(deep / "b.tpc"),)


def test_missing_kernel_named(tmp_path):
    mk = _metakernel(tmp_path / "set.tm", "'.'", ["absent.bsp"])
    with pytest.raises(MissingKernelError, match="absent.bsp"):
        KernelSet.from_metakernel(mk)
    with pytest.raises(MissingKernelError, match="nothing.tm"):
        KernelSet.from_metakernel(tmp_path / "nothing.tm")
    with pytest.raises(MissingKernelError, match="gone.tpc"):
        with kernels(KernelSet.from_files([tmp_path / "gone.tpc"])):
            pass
    assert spiceypy.ktotal("ALL") == 0


def test_metakernel_without_kernels_to_load(tmp_path):
    (tmp_path / "bad.tm").write_text("\\begindata\nPATH_VALUES = ( '.' )\n\\begintext\n")
    with pytest.raises(KernelError, match="KERNELS_TO_LOAD"):
        KernelSet.from_metakernel(tmp_path / "bad.tm")


def test_nested_contexts_restore_resident_set(tmp_path):
    a = KernelSet.from_files([_text_kernel(tmp_path / "a.tpc", "LUNARMAP_X = 1")])
    b = KernelSet.from_files([_text_kernel(tmp_path / "b.tpc", "LUNARMAP_X = 2")])
    try:
        ensure_loaded(a)
        with kernels(b):
            assert spiceypy.gdpool("LUNARMAP_X", 0, 1)[0] == 2
            with kernels(b):  # same set: nothing reloaded
                assert loaded_kernel_set() == b
        assert loaded_kernel_set() == a
        assert spiceypy.gdpool("LUNARMAP_X", 0, 1)[0] == 1
    finally:
        clear()
    assert spiceypy.ktotal("ALL") == 0


def test_threads_each_see_their_own_set(tmp_path):
    sets = [KernelSet.from_files([_text_kernel(tmp_path / f"k{i}.tpc", f"LUNARMAP_Y = {i}")]) for i in range(4)]

    def work(i: int) -> list[float]:
        seen = []
        for _ in range(25):
            with kernels(sets[i]):
                seen.append(spiceypy.gdpool("LUNARMAP_Y", 0, 1)[0])
        return seen

    # in_threads re-raises a worker thread's exception: a crashing thread fails the test
    assert in_threads(work, 4) == [[float(i)] * 25 for i in range(4)]
    assert spiceypy.ktotal("ALL") == 0


def test_thread_helper_fails_when_a_thread_raises():
    def work(i: int) -> int:
        if i == 2:
            raise KeyError("boom")
        return i

    with pytest.raises(ThreadFailure, match="thread 2 raised KeyError") as info:
        in_threads(work, 4)
    assert isinstance(info.value.__cause__, KeyError)


def test_kernel_set_pickles_as_paths(tmp_path):
    import pickle

    k = KernelSet.from_files([_text_kernel(tmp_path / "p.tpc", "LUNARMAP_Z = 1")], source="x")
    k2 = pickle.loads(pickle.dumps(k))
    assert k2 == k and k2.fingerprint == k.fingerprint
    before = k2.fingerprint
    os.utime(k.paths[0], ns=(10**18, 10**18))
    assert k.fingerprint != before  # a touched file changes the fingerprint
