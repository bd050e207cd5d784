"""Writing SPICE kernels: text kernels from Python dicts, SPK type 13, CK type 3.

Every writer here is *atomic*: the kernel is written under a temporary name
in the destination folder and renamed onto the final name only when it is
complete, so a failure (bad data, a SPICE error, an interrupt) leaves nothing
half-written behind and never clobbers an existing file.

* :func:`format_assignments` / :func:`write_text_kernel` - ``\\begindata``
  blocks from mappings of variable name to value. Strings are quoted (quotes
  doubled), floats are written in full ``repr`` precision (Python reads them
  back exactly; SPICE's own parser within a few units in the last place,
  < 1.2e-15 relative as measured), sequences in
  parentheses, strings longer than SPICE's 80-character value limit are split
  into pieces ending in the ``'+'`` continuation marker (read them back with
  ``stpool``), :class:`KernelDate` values become ``@`` date tokens and an
  :class:`Append` value is written with ``+=``.
* :func:`write_spk` - SPK type 13 (Hermite, unequal time steps) segments from
  ET / position / velocity arrays.
* :func:`write_ck` - CK type 3 (linearly interpolated quaternions with angular
  velocity) segments from ET / quaternion / angular-velocity arrays; ET is
  converted to encoded spacecraft clock with ``sce2c``, so the LSK and SCLK
  must be given (they are loaded only for the conversion and unloaded again).

All SPICE calls are made while holding :data:`~lunarmap.spice.pool.SPICE_LOCK`.
"""

from __future__ import annotations

import contextlib
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping, Sequence, Union

import numpy as np
import spiceypy
from numpy.typing import ArrayLike, NDArray

from ..atomic import atomic_path
from ..errors import InvalidInputError
from .pool import SPICE_LOCK, spice_errors

__all__ = [
    "KernelDate",
    "Append",
    "MAX_NAME_LENGTH",
    "MAX_STRING_LENGTH",
    "format_value",
    "format_assignments",
    "text_kernel",
    "write_text_kernel",
    "atomic_path",
    "SpkSegment",
    "CkSegment",
    "write_spk",
    "write_ck",
    "loaded_temporarily",
]

#: Longest kernel-pool variable name SPICE accepts (characters).
MAX_NAME_LENGTH = 32
#: Longest string value SPICE stores in the kernel pool (characters).
MAX_STRING_LENGTH = 80
#: Target length of lines written into text kernels (SPICE reads up to 132).
_LINE = 80
#: Longest quoted string token written (characters inside the quotes, quotes doubled);
#: with a 32-character name and indentation a line stays within SPICE's 132.
_MAX_QUOTED = 88
#: Longest segment identifier of SPK and CK segments (characters).
_MAX_SEGID = 40
#: Largest integer a double holds exactly; pool numbers are doubles.
_MAX_EXACT_INT = 2 ** 53

_NAME_RE = re.compile(r"^[!-~]+$")  # printable ASCII, no blanks
_DATE_RE = re.compile(r"^[A-Za-z0-9:/.\-]+$")  # an @-date token has no blanks or quotes


@dataclass(frozen=True)
class KernelDate:
    """A calendar date written as a SPICE ``@`` date token (e.g. ``@2017-JAN-1``).

    The kernel pool stores it as seconds past J2000 (formal calendar, no leap
    seconds), as ``tparse`` would compute.

    Parameters
    ----------
    text : str
        The date without the ``@``, with no blanks (``'2017-JAN-1'``,
        ``'2026-01-01/00:00:00'``).
    """

    text: str

    def __post_init__(self) -> None:
        if not _DATE_RE.match(self.text or ""):
            raise InvalidInputError(f"invalid SPICE date token {self.text!r}: "
                                    "use letters, digits and - / : . only, no blanks")


@dataclass(frozen=True)
class Append:
    """A value to be appended with ``+=`` rather than assigned with ``=``.

    Frame kernels use this for ``NAIF_BODY_NAME`` / ``NAIF_BODY_CODE`` so as
    not to erase name-to-id mappings made by other kernels.
    """

    value: Any


Scalar = Union[str, int, float, KernelDate]
Value = Union[Scalar, Sequence[Scalar], NDArray[Any], Append]


def _check_name(name: str) -> str:
    if not isinstance(name, str) or not _NAME_RE.match(name) or any(c in name for c in "=()'\","):
        raise InvalidInputError(f"invalid kernel-pool variable name {name!r}: "
                                "printable ASCII without blanks, quotes, commas, '=' or parentheses")
    if len(name) > MAX_NAME_LENGTH:
        raise InvalidInputError(f"kernel-pool variable name {name!r} has {len(name)} characters; "
                                f"SPICE allows at most {MAX_NAME_LENGTH}")
    return name


def _split_string(s: str) -> list[str]:
    """Split a string into pool values of <= 80 characters using '+' continuation.

    A piece is also cut short when its quoted form (quotes doubled) would make
    the kernel line longer than SPICE's 132-character line limit.
    """
    if len(s) <= MAX_STRING_LENGTH and len(s) + s.count("'") <= _MAX_QUOTED:
        return [s]
    pieces: list[str] = []
    cur, cur_len = "", 0
    for c in s:
        w = 2 if c == "'" else 1
        # each continued piece keeps room for the '+' marker
        if len(cur) + 1 > MAX_STRING_LENGTH - 1 or cur_len + w > _MAX_QUOTED - 1:
            pieces.append(cur + "+")
            cur, cur_len = "", 0
        cur += c
        cur_len += w
    pieces.append(cur)
    return pieces


def _format_scalar(v: Any) -> list[str]:
    """Tokens (one, or several for a continued string) for a scalar value."""
    if isinstance(v, KernelDate):
        return ["@" + v.text]
    if isinstance(v, (bool, np.bool_)):
        raise InvalidInputError(f"boolean {v!r} has no SPICE text-kernel form; use 'YES'/'NO' or 1/0")
    if isinstance(v, str):
        if any(not (" " <= c <= "~") for c in v):
            raise InvalidInputError(f"string {v!r} contains characters other than printable ASCII")
        return ["'" + p.replace("'", "''") + "'" for p in _split_string(v)]
    if isinstance(v, (int, np.integer)):
        iv = int(v)
        if abs(iv) > _MAX_EXACT_INT:
            raise InvalidInputError(f"integer {iv} is too large to be stored exactly in the kernel pool")
        return [str(iv)]
    if isinstance(v, (float, np.floating)):
        fv = float(v)
        if not math.isfinite(fv):
            raise InvalidInputError(f"non-finite number {fv!r} cannot be written to a text kernel")
        # repr is the shortest string that reads back to the identical double
        return [repr(fv)]
    raise InvalidInputError(f"cannot write {type(v).__name__} value {v!r} to a text kernel")


def format_value(value: Value) -> list[str]:
    """The tokens of one assignment's right-hand side.

    Parameters
    ----------
    value : str, int, float, KernelDate, sequence of them, or ndarray
        Arrays are flattened in C order.

    Returns
    -------
    list of str
        Tokens, ready to be joined (a continued string yields several).

    Raises
    ------
    InvalidInputError
        Empty sequences, NaN/infinite numbers, booleans, non-ASCII strings,
        nested containers or mixed strings and numbers.
    """
    if isinstance(value, Append):
        value = value.value
    if isinstance(value, np.ndarray):
        value = value.ravel().tolist()
    if isinstance(value, (list, tuple)):
        if not value:
            raise InvalidInputError("an empty sequence cannot be written to a text kernel")
        kinds = set()
        tokens: list[str] = []
        for item in value:
            if isinstance(item, (list, tuple, np.ndarray, dict, Append)):
                raise InvalidInputError(f"nested value {item!r}: flatten it first")
            kinds.add("s" if isinstance(item, str) else "n")
            tokens.extend(_format_scalar(item))
        if len(kinds) > 1:
            raise InvalidInputError(f"mixed strings and numbers in one variable: {value!r}")
        return tokens
    if isinstance(value, Mapping):
        raise InvalidInputError("a mapping cannot be a kernel-pool value")
    return _format_scalar(value)


def _assignment(name: str, value: Value, indent: str) -> list[str]:
    op = "+=" if isinstance(value, Append) else "="
    tokens = format_value(value)
    is_list = isinstance(value.value if isinstance(value, Append) else value,
                         (list, tuple, np.ndarray)) or len(tokens) > 1
    head = f"{indent}{name} {op} "
    if not is_list:
        return [head + tokens[0]]
    lines: list[str] = []
    cont = " " * (len(head) + 2)
    cur = head + "( "
    first_on_line = True
    for tok in tokens:
        candidate = cur + ("" if first_on_line else "  ") + tok
        if not first_on_line and len(candidate) > _LINE:
            lines.append(cur)
            cur = cont + tok
        else:
            cur = candidate
        first_on_line = False
    lines.append(cur + " )")
    return lines


def format_assignments(data: Mapping[str, Value], indent: str = "   ") -> str:
    """Format a ``\\begindata`` block (without the markers) from a mapping.

    Parameters
    ----------
    data : mapping of str to value
        Variable names to values, written in the mapping's order. See
        :func:`format_value` for the accepted values; wrap a value in
        :class:`Append` to write ``+=``.
    indent : str
        Leading blanks of each assignment.

    Returns
    -------
    str
        One assignment per line (lists wrap at 80 characters), ending in a newline.
    """
    lines: list[str] = []
    for name, value in data.items():
        lines.extend(_assignment(_check_name(name), value, indent))
    return "\n".join(lines) + "\n"


Section = Union[Mapping[str, Value], tuple[str, Mapping[str, Value]]]


def text_kernel(kind: str, sections: Mapping[str, Value] | Sequence[Section], comments: str = "") -> str:
    """The full text of a SPICE text kernel.

    Parameters
    ----------
    kind : str
        Kernel type for the ``KPL/<kind>`` header: ``LSK``, ``SCLK``, ``PCK``,
        ``FK``, ``IK``, ``MK``.
    sections : mapping or sequence
        A single mapping, or a sequence of mappings or ``(comment, mapping)``
        pairs; each becomes one ``\\begindata`` block preceded by its comment.
    comments : str
        Text placed at the top of the kernel (outside any data block).

    Returns
    -------
    str
        The kernel text, with Unix line ends.
    """
    if not re.match(r"^[A-Z]{2,4}$", kind):
        raise InvalidInputError(f"invalid text-kernel type {kind!r}")
    if isinstance(sections, Mapping):
        sections = [sections]
    out = [f"KPL/{kind}", "", "\\begintext", ""]
    if comments:
        out += [_check_comment(comments).rstrip("\n"), ""]
    for sec in sections:
        note, data = sec if isinstance(sec, tuple) else ("", sec)
        if note:
            out += [_check_comment(note).rstrip("\n"), ""]
        out += ["\\begindata", "", format_assignments(data).rstrip("\n"), "", "\\begintext", ""]
    return "\n".join(out) + "\n"


def _check_comment(text: str) -> str:
    for line in text.splitlines():
        if line.strip().startswith("\\begindata") or line.strip().startswith("\\begintext"):
            raise InvalidInputError("comment text must not contain \\begindata or \\begintext markers")
        if any(not (" " <= c <= "~") for c in line):
            raise InvalidInputError(f"comment line {line!r} contains non-printable or non-ASCII characters")
    return text


def write_text_kernel(path: str | os.PathLike[str], kind: str,
                      sections: Mapping[str, Value] | Sequence[Section], comments: str = "") -> Path:
    """Write a text kernel atomically (see :func:`text_kernel` for the arguments).

    The whole text is formatted before anything is written, so invalid data
    raises :class:`~lunarmap.errors.InvalidInputError` without touching the disk.

    Returns
    -------
    pathlib.Path
        The written file.
    """
    text = text_kernel(kind, sections, comments)
    final = Path(path)
    with atomic_path(final) as tmp:
        with open(tmp, "w", encoding="ascii", newline="\n") as fh:
            fh.write(text)
    return final


# ----------------------------------------------------------------------------- binary kernels

def _check_segid(segid: str) -> str:
    if len(segid) > _MAX_SEGID or any(not (" " <= c <= "~") for c in segid):
        raise InvalidInputError(f"segment id {segid!r}: at most {_MAX_SEGID} printable ASCII characters")
    return segid


def _check_times(et: ArrayLike, what: str) -> NDArray[np.float64]:
    t = np.asarray(et, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise InvalidInputError(f"{what}: epochs must be a 1-D array of at least 2 times")
    if not np.all(np.isfinite(t)):
        raise InvalidInputError(f"{what}: epochs contain NaN or infinity")
    if np.any(np.diff(t) <= 0.0):
        raise InvalidInputError(f"{what}: epochs must be strictly increasing")
    return t


def _check_rows(a: ArrayLike, n: int, width: int, what: str) -> NDArray[np.float64]:
    arr = np.asarray(a, dtype=float)
    if arr.shape != (n, width):
        raise InvalidInputError(f"{what}: expected shape ({n}, {width}), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InvalidInputError(f"{what}: contains NaN or infinity")
    return arr


def _comment_lines(comments: str | Sequence[str]) -> list[str]:
    lines = comments.splitlines() if isinstance(comments, str) else list(comments)
    for line in lines:
        if len(line) > 1000 or any(not (" " <= c <= "~") for c in line):
            raise InvalidInputError(f"comment line {line[:40]!r}...: printable ASCII, <= 1000 characters")
    return [line if line else " " for line in lines]


@dataclass(frozen=True, eq=False)
class SpkSegment:
    """One SPK type 13 (Hermite interpolation, unequal steps) segment.

    Parameters
    ----------
    body, center : int
        NAIF ids of the target and of the centre of motion.
    frame : str
        Reference frame of the states (e.g. ``'J2000'``).
    et : array_like, shape (n,)
        Epochs, TDB seconds past J2000, strictly increasing.
    position : array_like, shape (n, 3)
        Positions of ``body`` relative to ``center``, km.
    velocity : array_like, shape (n, 3)
        Velocities, km/s.
    segment_id : str
        At most 40 characters.
    degree : int
        Odd Hermite polynomial degree (1 to 27); the interpolation window uses
        ``(degree + 1) / 2`` records.
    """

    body: int
    center: int
    frame: str
    et: ArrayLike
    position: ArrayLike
    velocity: ArrayLike
    segment_id: str = ""
    degree: int = 7

    def validated(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``(epochs, states)`` after checking every argument; raises InvalidInputError."""
        what = f"SPK segment for body {self.body}"
        if int(self.body) == int(self.center):
            raise InvalidInputError(f"{what}: body and centre are the same ({self.body})")
        if self.degree % 2 != 1 or not 1 <= self.degree <= 27:
            raise InvalidInputError(f"{what}: degree must be odd and within 1..27, got {self.degree}")
        t = _check_times(self.et, what)
        if t.size < (self.degree + 1) // 2:
            raise InvalidInputError(f"{what}: {t.size} records are fewer than the window "
                                    f"({(self.degree + 1) // 2}) of degree {self.degree}")
        pos = _check_rows(self.position, t.size, 3, f"{what}: positions")
        vel = _check_rows(self.velocity, t.size, 3, f"{what}: velocities")
        _check_segid(self.segment_id)
        return t, np.ascontiguousarray(np.hstack([pos, vel]))


@dataclass(frozen=True, eq=False)
class CkSegment:
    """One CK type 3 segment with angular velocities and a single interpolation interval.

    Parameters
    ----------
    inst : int
        CK frame id (the ``CLASS_ID`` of the CK frame, e.g. ``-990000``).
    ref : str
        Reference frame (e.g. ``'J2000'``).
    et : array_like, shape (n,)
        Epochs, TDB seconds past J2000, strictly increasing.
    quaternions : array_like, shape (n, 4)
        SPICE quaternions ``(w, x, y, z)`` of the matrices rotating vectors
        from ``ref`` into the CK frame (``spiceypy.m2q`` of the C-matrix);
        they are normalised before writing.
    angular_velocity : array_like, shape (n, 3)
        Angular velocity of the CK frame relative to ``ref``, expressed in
        ``ref``, rad/s.
    segment_id : str
        At most 40 characters.
    sclk_id : int, optional
        Spacecraft clock of this segment's epochs; overrides ``write_ck``'s
        ``sclk_id`` (for CK files holding frames of several clocks).
    """

    inst: int
    ref: str
    et: ArrayLike
    quaternions: ArrayLike
    angular_velocity: ArrayLike
    segment_id: str = ""
    sclk_id: int | None = None

    def validated(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """``(epochs, unit quaternions, angular velocities)``; raises InvalidInputError."""
        what = f"CK segment for frame {self.inst}"
        t = _check_times(self.et, what)
        q = _check_rows(self.quaternions, t.size, 4, f"{what}: quaternions")
        norm = np.linalg.norm(q, axis=1)
        if np.any(np.abs(norm - 1.0) > 1e-6):
            raise InvalidInputError(f"{what}: quaternions must have unit norm (within 1e-6)")
        av = _check_rows(self.angular_velocity, t.size, 3, f"{what}: angular velocities")
        _check_segid(self.segment_id)
        return t, np.ascontiguousarray(q / norm[:, None]), np.ascontiguousarray(av)


def write_spk(path: str | os.PathLike[str], segments: Sequence[SpkSegment], *,
              internal_name: str = "LUNARMAP SPK", comments: str | Sequence[str] = "") -> Path:
    """Write an SPK file of type 13 segments, atomically.

    Parameters
    ----------
    path : path-like
        Destination; replaced if it exists (only once writing has succeeded).
    segments : sequence of SpkSegment
        Written in order (later segments take priority where they overlap).
    internal_name : str
        The DAF internal file name (at most 60 characters).
    comments : str or sequence of str
        Comment-area text.

    Returns
    -------
    pathlib.Path
        The written file.

    Raises
    ------
    InvalidInputError
        Bad arrays (checked before any file is created).
    SpiceError, KernelCoverageError
        SPICE rejected the data (e.g. an unknown frame); no file is left behind.
    """
    if not segments:
        raise InvalidInputError(f"writing {path}: no SPK segments given")
    prepared = [(s, *s.validated()) for s in segments]
    lines = _comment_lines(comments)
    final = Path(path)
    with atomic_path(final) as tmp, SPICE_LOCK:
        with _daf_open("SPK", final, tmp, internal_name, lines) as handle:
            for seg, t, states in prepared:
                spiceypy.spkw13(handle, int(seg.body), int(seg.center), seg.frame,
                                float(t[0]), float(t[-1]), seg.segment_id, int(seg.degree),
                                int(t.size), states, t)
    return final


@contextlib.contextmanager
def _daf_open(kind: str, final: Path, tmp: Path, internal_name: str, lines: list[str]) -> Iterator[int]:
    """Open a new SPK or CK for writing, add the comments, close it; on failure close without finishing.

    Errors inside the block are reported as ``writing <kind> <final>``; the
    caller's :func:`atomic_path` removes the temporary file.
    """
    opener, closer = (spiceypy.spkopn, spiceypy.spkcls) if kind == "SPK" else (spiceypy.ckopn, spiceypy.ckcls)
    with spice_errors(f"writing {kind} {final}"):
        handle = opener(str(tmp), internal_name[:60], max(5000, 100 * len(lines)))
    try:
        with spice_errors(f"writing {kind} {final}"):
            if lines:
                spiceypy.dafac(handle, lines)
            yield handle
    except BaseException:
        with contextlib.suppress(Exception):
            spiceypy.dafcls(handle)
        raise
    with spice_errors(f"closing {kind} {final}"):
        closer(handle)


def _loaded(path: str) -> bool:
    try:
        spiceypy.kinfo(path)
    except Exception:  # spiceypy raises NotFoundError when the file is not loaded
        return False
    return True


@contextlib.contextmanager
def loaded_temporarily(files: Iterable[str | os.PathLike[str]]) -> Iterator[None]:
    """Furnish the kernels not already loaded; on exit unload exactly those.

    The caller must hold :data:`~lunarmap.spice.pool.SPICE_LOCK` for the whole
    ``with`` block, so no other thread sees the temporarily extended pool.
    Kernels that were already loaded are neither reloaded nor unloaded.
    """
    mine: list[str] = []
    try:
        for f in files:
            p = str(Path(f).resolve())
            if not os.path.isfile(p):
                raise InvalidInputError(f"time kernel {p} does not exist")
            if not _loaded(p):
                with spice_errors(f"loading kernel {p}"):
                    spiceypy.furnsh(p)
                mine.append(p)
        yield
    finally:
        for p in reversed(mine):
            with contextlib.suppress(Exception):
                spiceypy.unload(p)


def write_ck(path: str | os.PathLike[str], segments: Sequence[CkSegment], *,
             time_kernels: Sequence[str | os.PathLike[str]], sclk_id: int | None = None,
             internal_name: str = "LUNARMAP CK", comments: str | Sequence[str] = "") -> Path:
    """Write a CK file of type 3 segments (with angular velocity), atomically.

    Each segment is one interpolation interval: SPICE interpolates between any
    two consecutive records of a segment, so a discontinuity (a slew that is
    not to be interpolated) must start a new segment.

    Parameters
    ----------
    path : path-like
        Destination; replaced if it exists (only once writing has succeeded).
    segments : sequence of CkSegment
        Written in order; where segments share an epoch, the later one wins.
    time_kernels : sequence of path-like
        The LSK and the SCLK of the spacecraft; loaded only while converting
        ET to encoded SCLK (``sce2c``) and unloaded afterwards (kernels already
        in the pool are left as they are).
    sclk_id : int, optional
        NAIF id of the spacecraft clock; by default ``inst // 1000`` as SPICE
        itself assumes (``ckmeta``) for every segment. A segment's own
        ``sclk_id`` takes precedence.
    internal_name : str
        The DAF internal file name (at most 60 characters).
    comments : str or sequence of str
        Comment-area text.

    Returns
    -------
    pathlib.Path
        The written file.
    """
    if not segments:
        raise InvalidInputError(f"writing {path}: no CK segments given")
    prepared = [(s, *s.validated()) for s in segments]
    lines = _comment_lines(comments)
    final = Path(path)
    with SPICE_LOCK:
        ticks = []
        with loaded_temporarily(time_kernels):
            for seg, t, _q, _av in prepared:
                clock = (int(seg.sclk_id) if seg.sclk_id is not None else
                         int(sclk_id) if sclk_id is not None else _default_sclk(int(seg.inst)))
                with spice_errors(f"converting ET to SCLK {clock} for CK {final}"):
                    ticks.append(np.array([spiceypy.sce2c(clock, float(e)) for e in t]))
        for (seg, *_), tk in zip(prepared, ticks):
            if np.any(np.diff(tk) <= 0.0):
                raise InvalidInputError(f"CK segment for frame {seg.inst}: epochs closer than one "
                                        "clock tick map to non-increasing SCLK")
        with atomic_path(final) as tmp:
            with _daf_open("CK", final, tmp, internal_name, lines) as handle:
                for (seg, _t, q, av), tk in zip(prepared, ticks):
                    spiceypy.ckw03(handle, float(tk[0]), float(tk[-1]), int(seg.inst), seg.ref,
                                   True, seg.segment_id, int(tk.size), tk, q, av, 1,
                                   np.array([tk[0]]))
    return final


def _default_sclk(inst: int) -> int:
    # SPICE's default (CKMETA without CK_<id>_SCLK): the instrument id divided by 1000, truncated.
    return int(inst / 1000)
