"""Property-based fuzzing of lunarmap's readers of outside files (shared by the tests and ``bench/fuzz.py``).

Each :class:`Target` is one reader with the real files it is seeded with. An input is a seed changed by
a few random edits drawn by ``hypothesis`` (truncation, deleted / repeated / swapped lines, values
replaced by garbage, flipped and inserted bytes; for JSON and netCDF also edits of the document's
structure: keys deleted, values of the wrong type or shape, variables dropped or cut short, attributes
spoiled), or a random input altogether. The contract checked on every input (:func:`check_input`):

* the reader returns a result (and the result can be used: each target's ``call`` goes one step on,
  e.g. projects a point through the model it read) or raises a :class:`lunarmap.errors.LunarmapError`;
  any other exception (a raw ``KeyError``, ``IndexError``, ``ValueError``...) is a failure;
* it returns within :data:`TIMEOUT` seconds (a hang is a failure);
* the folder holds nothing new afterwards (no partial output, no temporary file left behind), and
  no file descriptor is left open (netCDF-C kept one per damaged file it failed to open).

Outcomes are counted per target in :data:`COUNTS` so that a run can report how many inputs each reader
saw and how they ended.
"""

from __future__ import annotations

import collections
import json
import os
import shutil
import signal
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from lunarmap.errors import LunarmapError

__all__ = ["Seed", "Target", "Hang", "COUNTS", "TIMEOUT", "check_input", "inputs", "fuzz"]

#: Seconds an input may take before it counts as a hang.
TIMEOUT = 20.0

#: ``COUNTS[target][outcome]``: outcome ``"ok"`` or the name of the lunarmap exception raised.
COUNTS: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)

#: Per target, the slowest input: ``(seconds, seed name, bytes)``.
SLOWEST: dict[str, tuple[float, str, int]] = {}

#: Per target, the largest peak-memory growth of one input over the process's resident memory before it:
#: ``(MB, seed name, bytes)`` (Linux: ``VmHWM`` reset per input through ``/proc/self/clear_refs``).
PEAK_GROWTH: dict[str, tuple[float, str, int]] = {}

#: Peak resident memory of the process over every input (kB).
PEAK_RSS_KB = [0]

#: Per target, inputs that took longer than :data:`TIME_BUDGET` seconds.
OVER_TIME: collections.Counter = collections.Counter()

#: The per-input budgets of issue 28: 2 s, and 10 x the file's size + 64 MB of memory beyond the process's.
TIME_BUDGET = 2.0


def memory_budget_mb(nbytes: int) -> float:
    return (10 * nbytes + (64 << 20)) / 2 ** 20


def _status_kb(key: str) -> int:
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(key):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


def _reset_peak() -> bool:
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


#: When a dict, breaches are collected here (``(target, error type, where) -> example``) instead of
#: raised, so that one exploratory run lists every distinct bug (``bench/fuzz.py --collect``).
COLLECT: dict[tuple[str, str, str], str] | None = None

#: Garbage put in place of a value or number token.
GARBAGE = [b"", b"abc", b"1e999", b"-1e999", b"nan", b"NaN", b"inf", b"-1", b"0", b"-0", b"1.5", b"(",
           b")", b"{", b"}", b'"', b"'", b"<", b">", b"=", b":", b",", b"99999999999999999999999",
           b"-2147483649", b"1.2.3", b"0x10", b"1D5", b"()", b"(1, 2", b"(a, b)", b"<ms>", b"/*", b"*/",
           b"\\begindata", b"\\begintext", b"End", b"END_OBJECT", b"\x00", b"\xff\xfe", b"\xe9", b"-",
           b"TRUE", b"1/", b"1/2:3", b"2000-13-45T99:99:99", b"\t", b"# comment"]

#: Whole lines inserted at random places.
LINES = [b"End", b"END", b"END_OBJECT", b"End_Group", b"Object = Table", b"Group = X", b"End_Object",
         b"OBJECT = IMAGE", b"KEY = (1, 2", b"KEY = \"open", b"\\begindata", b"\\begintext",
         b"KERNELS_TO_LOAD = ( 'missing.bsp' )", b"PATH_VALUES += ( 'x' )", b"LINE_OFF: 1",
         b"# lunarmap reference radius (m): abc", b"# lunarmap image size (lines samples): 1",
         b"# lunarmap image size (lines samples): x y", b"# lunarmap reference radius (m):", b"=", b"\x00" * 8,
         b"a b c", b"3 2 1", b"-1 -1 -1"]


class Hang(BaseException):
    """An input took longer than :data:`TIMEOUT` (a ``BaseException``: a reader cannot swallow it)."""


@dataclass
class Seed:
    """A real file a target starts from: its bytes, the suffix it needs and what the reader needs besides."""

    data: bytes
    suffix: str = ""
    context: dict[str, Any] = field(default_factory=dict)
    name: str = ""

    def __repr__(self) -> str:  # shown by hypothesis for a failing input: name it, not its bytes
        return f"Seed({self.name!r})"


@dataclass
class Target:
    """One reader under fuzzing.

    ``call(path, seed)`` reads the file at ``path`` (written from a mutated ``seed``) and uses the
    result a little; ``kind`` chooses the structural edits (``"text"``, ``"binary"``, ``"json"``,
    ``"netcdf"``, ``"cube"``: a PVL label followed by binary data).
    """

    name: str
    call: Callable[[Path, Seed], Any]
    seeds: list[Seed]
    kind: str = "text"
    #: run before each input, outside the checks: state a reader may legitimately hold (SPICE keeps
    #: loaded kernel files open) is set up here so that it does not count as a leaked descriptor
    prepare: Callable[[Seed], None] | None = None


# --- edits ------------------------------------------------------------------------------------------

def _lines(data: bytes) -> list[bytes]:
    return data.split(b"\n")


@st.composite
def _text_edit(draw, data: bytes) -> bytes:
    """One edit of text-like bytes."""
    op = draw(st.sampled_from(["truncate", "del_line", "dup_line", "swap_lines", "value", "number", "flip",
                               "insert_bytes", "del_bytes", "insert_line"]))
    n = len(data)
    if n == 0:
        return draw(st.binary(max_size=64))
    if op == "truncate":
        return data[: draw(st.integers(0, n - 1))]
    if op in ("flip", "insert_bytes", "del_bytes"):
        at = draw(st.integers(0, n - 1))
        if op == "flip":
            return data[:at] + bytes([draw(st.integers(0, 255))]) + data[at + 1:]
        if op == "insert_bytes":
            return data[:at] + draw(st.binary(min_size=1, max_size=16)) + data[at:]
        return data[:at] + data[at + draw(st.integers(1, 64)):]
    lines = _lines(data)
    i = draw(st.integers(0, len(lines) - 1))
    if op == "del_line":
        del lines[i]
    elif op == "dup_line":
        lines.insert(i, lines[i])
    elif op == "swap_lines":
        j = draw(st.integers(0, len(lines) - 1))
        lines[i], lines[j] = lines[j], lines[i]
    elif op == "insert_line":
        lines.insert(i, draw(st.sampled_from(LINES)))
    elif op == "value":
        # the value of a `key = value` / `key: value` line becomes garbage
        candidates = [k for k, ln in enumerate(lines) if b"=" in ln or b":" in ln] or [i]
        k = draw(st.sampled_from(candidates))
        ln = lines[k]
        sep = min((p for p in (ln.find(b"="), ln.find(b":")) if p >= 0), default=len(ln))
        lines[k] = ln[: sep + 1] + b" " + draw(st.sampled_from(GARBAGE))
    else:  # a number token anywhere becomes garbage
        toks = [(k, t) for k, ln in enumerate(lines) for t in ln.split() if t[:1].isdigit() or t[:1] in b"+-."]
        if toks:
            k, t = draw(st.sampled_from(toks[:5000]))
            lines[k] = lines[k].replace(t, draw(st.sampled_from(GARBAGE)), 1)
    return b"\n".join(lines)


_JSON_VALUES = [None, True, False, 0, -1, 1, 1.5, -1e308, 1e308, "x", "", [], {}, [1, 2], [[1, 2], [3]],
                {"a": 1}, [None], ["a", "b"], 2 ** 70, float("nan"), float("inf")]


def _json_paths(doc: Any, prefix: tuple = (), out: list | None = None, limit: int = 4000) -> list[tuple]:
    out = [] if out is None else out
    if len(out) >= limit:
        return out
    if isinstance(doc, dict):
        for k, v in doc.items():
            out.append(prefix + (k,))
            _json_paths(v, prefix + (k,), out, limit)
    elif isinstance(doc, list):
        for i, v in enumerate(doc[:3] + ([doc[-1]] if len(doc) > 3 else [])):
            j = i if i < 3 else len(doc) - 1
            out.append(prefix + (j,))
            _json_paths(v, prefix + (j,), out, limit)
    return out


_JSON_CACHE: dict[int, tuple[Any, list[tuple]]] = {}


@st.composite
def _json_edit(draw, data: bytes) -> bytes:
    """One structural edit of a JSON document (falls back to a text edit when it does not parse)."""
    key = hash(data)
    if key not in _JSON_CACHE:
        try:
            doc = json.loads(data)
        except ValueError:
            return draw(_text_edit(data))
        if len(_JSON_CACHE) > 64:
            _JSON_CACHE.clear()
        _JSON_CACHE[key] = (doc, _json_paths(doc))
    doc, paths = _JSON_CACHE[key]
    if not paths:
        return draw(_text_edit(data))
    doc = json.loads(data)  # a fresh copy to edit
    path = draw(st.sampled_from(paths))
    parent = doc
    for k in path[:-1]:
        parent = parent[k]
    last = path[-1]
    op = draw(st.sampled_from(["delete", "replace", "shorten", "lengthen", "swap", "scale"]))
    value = parent[last]
    if op == "delete":
        del parent[last]
    elif op == "replace":
        parent[last] = draw(st.sampled_from(_JSON_VALUES))
    elif op == "shorten" and isinstance(value, list):
        parent[last] = value[: draw(st.integers(0, max(len(value) - 1, 0)))]
    elif op == "lengthen" and isinstance(value, list) and value:
        parent[last] = value + value[-1:]
    elif op == "swap" and isinstance(value, list) and len(value) > 1:
        i, j = draw(st.integers(0, len(value) - 1)), draw(st.integers(0, len(value) - 1))
        value[i], value[j] = value[j], value[i]
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        parent[last] = value * draw(st.sampled_from([-1.0, 0.0, 1e-9, 1e9, 1.000001]))
    else:
        parent[last] = draw(st.sampled_from(_JSON_VALUES))
    return json.dumps(doc).encode()


_SERIAL = [0]


def _spoil(draw, ds):
    """One structural edit of a dataset (drop, rename, cut or retype a variable, spoil a value or attribute)."""
    import numpy as np

    names = sorted(ds.variables)
    op = draw(st.sampled_from(["drop", "values", "dtype", "cut", "attr_del", "attr_set", "rename"]))
    if op in ("drop", "values", "dtype", "cut", "rename") and names:
        v = draw(st.sampled_from(names))
        var = ds[v]
        if op == "drop":
            ds = ds.drop_vars(v)
        elif op == "rename":
            ds = ds.rename({v: v + "_x"})
        elif op == "values" and var.dtype.kind in "iuf" and var.size:
            new = draw(st.sampled_from([np.nan, np.inf, -1, 0, 10 ** 6, -(10 ** 9), 0.5, 1e300]))
            a = np.array(var.values, dtype=float if (isinstance(new, float) and var.dtype.kind != "f") else var.dtype)
            idx = draw(st.integers(0, a.size - 1))
            try:
                a.flat[idx] = new
            except (OverflowError, ValueError):
                a = a.astype(float)
                a.flat[idx] = new
            ds[v] = (var.dims, a, var.attrs)
        elif op == "dtype":
            target = draw(st.sampled_from(["str", "f4", "i1", "u1"]))
            try:
                ds[v] = (var.dims, var.values.astype(target), var.attrs)
            except (ValueError, TypeError, OverflowError):
                ds[v] = (var.dims, var.values.astype(str), var.attrs)
        elif op == "cut" and var.ndim and var.shape[0] > 0:
            dim = var.dims[0]
            k = draw(st.integers(0, var.shape[0] - 1))
            ds = ds.drop_vars(v)
            ds[v] = var.isel({dim: slice(0, k)}).rename({dim: dim + "_cut"}).variable
    elif op == "attr_del" and ds.attrs:
        a = draw(st.sampled_from(sorted(ds.attrs)))
        del ds.attrs[a]
    else:
        a = draw(st.sampled_from(sorted(ds.attrs) + ["version", "radius", "Conventions"]))
        ds.attrs[a] = draw(st.sampled_from(["abc", "", -1, 0, 99, 1.5, -1e300, "nan", "1e999"]))
    return ds


def _netcdf_edit_factory(draw, data: bytes, folder: Path) -> bytes:
    """One structural edit of a netCDF file: a spoiled dataset written with the netCDF library."""
    import numpy as np
    import xarray as xr

    _SERIAL[0] += 1
    src = folder / f"_seed{_SERIAL[0]}.nc"   # a new name each time: the netCDF library caches by name
    src.write_bytes(data)
    try:
        with xr.open_dataset(src, engine="netcdf4") as ds0:
            ds = ds0.load()
    except Exception:  # an earlier edit broke the file: nothing structural left to edit
        return data
    finally:
        src.unlink()
    try:
        ds = _spoil(draw, ds)
    except (ValueError, TypeError, KeyError, OverflowError):  # an edit xarray refuses: keep the seed
        return data
    out = folder / f"_edit{_SERIAL[0]}.nc"
    try:
        ds.to_netcdf(out, engine="netcdf4")
        return out.read_bytes()
    except Exception:  # this edit cannot be stored in netCDF: keep the seed
        return data
    finally:
        if out.exists():
            out.unlink()


@st.composite
def _cube_edit(draw, data: bytes) -> bytes:
    """An edit of an ISIS cube: of its PVL label (usually) or of the binary data after it."""
    end = data.find(b"\nEnd\n")
    if end < 0 or draw(st.integers(0, 4)) == 0:
        return draw(_text_edit(data))
    head, tail = data[: end + 5], data[end + 5:]
    new_head = draw(_text_edit(head))
    return new_head + tail


def inputs(target: Target, scratch: Path):
    """The hypothesis strategy of ``(seed, input bytes)`` for a target."""

    @st.composite
    def build(draw):
        seed = draw(st.sampled_from(target.seeds))
        if draw(st.integers(0, 19)) == 0:  # a random input, nothing like the format
            return seed, draw(st.one_of(st.binary(max_size=512), st.text(max_size=512).map(str.encode)))
        data = seed.data
        for step in range(draw(st.integers(1, 3))):
            if target.kind == "json" and draw(st.booleans()):
                data = draw(_json_edit(data))
            elif target.kind == "netcdf":
                # one structural edit at most (each costs a netCDF write and read), then byte edits
                if step == 0 and data[:4] == b"\x89HDF" and draw(st.integers(0, 3)) > 0:
                    data = _netcdf_edit_factory(draw, data, scratch)
                else:
                    at = draw(st.integers(0, max(len(data) - 1, 0)))
                    data = data[:at] if draw(st.booleans()) else \
                        data[:at] + bytes([draw(st.integers(0, 255))]) + data[at + 1:]
            elif target.kind == "cube":
                data = draw(_cube_edit(data))
            else:
                data = draw(_text_edit(data))
        return seed, data

    return build()


# --- the contract -----------------------------------------------------------------------------------

def _alarm(signum, frame):  # noqa: ARG001
    raise Hang(f"no answer within {TIMEOUT} s")


def _open_fds() -> int:
    """Open file descriptors of this process (Linux; 0 elsewhere, which disables the check)."""
    try:
        return len(os.listdir("/proc/self/fd"))
    except OSError:
        return 0


def _where(err: BaseException) -> str:
    """The innermost lunarmap (or test) frame of a traceback: file:line function."""
    import traceback

    frames = [f for f in traceback.extract_tb(err.__traceback__) if "lunarmap" in f.filename or "workflows" in f.filename]
    f = frames[-1] if frames else traceback.extract_tb(err.__traceback__)[-1]
    return f"{f.filename.rsplit('/', 2)[-2:]}:{f.lineno} {f.name}"


def check_input(target: Target, seed: Seed, data: bytes, folder: Path) -> str:
    """Run the reader on one input in an empty ``folder``; return the outcome, raise AssertionError on a breach."""
    for p in folder.iterdir():
        if p.is_dir():
            shutil.rmtree(p)
        else:
            p.unlink()
    _SERIAL[0] += 1
    path = folder / f"input{_SERIAL[0]}{seed.suffix}"   # a new name each time: libraries cache by name
    path.write_bytes(data)
    before = sorted(os.listdir(folder))
    if target.prepare is not None:
        target.prepare(seed)
    fds = _open_fds()
    measured = _reset_peak()
    rss0 = _status_kb("VmRSS:")
    t0 = time.perf_counter()
    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, TIMEOUT)
    try:
        target.call(path, seed)
        outcome = "ok"
    except LunarmapError as err:
        outcome = type(err).__name__
        if not str(err):
            raise AssertionError(f"{target.name}: {outcome} without a message") from err
    except Hang as err:
        raise AssertionError(f"{target.name}: hang on input from {seed.name} ({len(data)} bytes)") from err
    except Exception as err:
        if COLLECT is None:
            raise AssertionError(f"{target.name}: raw {type(err).__name__} from input of {seed.name}: {err}") from err
        outcome = f"RAW {type(err).__name__}"
        COLLECT.setdefault((target.name, type(err).__name__, _where(err)), f"{seed.name}: {err!s:.200}")
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
        seconds = time.perf_counter() - t0
        hwm = _status_kb("VmHWM:")
        PEAK_RSS_KB[0] = max(PEAK_RSS_KB[0], hwm)
        growth = (hwm - rss0) / 1024.0 if measured else 0.0
        if seconds > SLOWEST.get(target.name, (-1.0,))[0]:
            SLOWEST[target.name] = (seconds, seed.name, len(data))
        if growth > PEAK_GROWTH.get(target.name, (-1.0,))[0]:
            PEAK_GROWTH[target.name] = (growth, seed.name, len(data))
        if seconds > TIME_BUDGET:
            OVER_TIME[target.name] += 1
    if measured and growth > memory_budget_mb(len(data)):
        msg = (f"{target.name}: an input of {len(data)} bytes from {seed.name} grew the process by {growth:.0f} MB, "
               "more than 10 x its size + 64 MB")
        if COLLECT is None:
            raise AssertionError(msg)
        COLLECT.setdefault((target.name, "memory budget", ""), msg)
    after = sorted(os.listdir(folder))
    if after != before:
        raise AssertionError(f"{target.name}: files left behind: {sorted(set(after) - set(before))}")
    if _open_fds() > fds:
        raise AssertionError(f"{target.name}: {_open_fds() - fds} file descriptor(s) left open by input of {seed.name}")
    COUNTS[target.name][outcome] += 1
    return outcome


_WARM: set[str] = set()


def warm_up(target: Target, folder: Path) -> None:
    """Read every seed once before the timed inputs: imports and numba's compilation (tens of seconds on a
    loaded machine the first time) are not an input's time."""
    if target.name in _WARM:
        return
    _WARM.add(target.name)
    for k, seed in enumerate(target.seeds):
        path = folder / f"warm{k}{seed.suffix}"
        path.write_bytes(seed.data)
        if target.prepare is not None:
            target.prepare(seed)
        try:
            target.call(path, seed)
        except Exception:  # noqa: BLE001 - a seed's own outcome is the fuzzing's business, not the warm-up's
            pass
        finally:
            path.unlink()


def fuzz(target: Target, max_examples: int, derandomize: bool = True, seed: int | None = None) -> None:
    """Run ``max_examples`` generated inputs through ``target`` (raises on the first breach, shrunk)."""
    scratch = Path(tempfile.mkdtemp(prefix=f"fuzz_{target.name}_"))
    work = scratch / "work"
    work.mkdir()
    warm_up(target, scratch)
    try:
        @settings(max_examples=max_examples, deadline=None, database=None, derandomize=derandomize,
                  suppress_health_check=list(HealthCheck), print_blob=False,
                  phases=[Phase.explicit, Phase.generate, Phase.shrink])
        @given(inputs(target, scratch))
        def run(case):
            check_input(target, case[0], case[1], work)

        if seed is not None and not derandomize:
            from hypothesis import seed as hseed
            run = hseed(seed)(run)
        run()
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
