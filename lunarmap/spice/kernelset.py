"""Kernel sets: a picklable recipe of which kernel files to load, in what order.

A :class:`KernelSet` is the thing passed between processes (to dask workers):
a tuple of absolute paths plus a fingerprint. Loading it is the job of
:mod:`lunarmap.spice.pool`.

Meta-kernels are read by lunarmap itself rather than handed to ``furnsh``:
SPICE resolves relative ``PATH_VALUES`` against the process's working directory
and limits string values to 80 characters, so a meta-kernel copied elsewhere,
or living in a long path, would fail. Here a relative ``PATH_VALUES`` entry is
taken relative to the meta-kernel's own folder.
"""

from __future__ import annotations

import hashlib
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping

from ..errors import KernelError, MissingKernelError

__all__ = ["KernelSet", "parse_text_kernel_data"]

_ASSIGN = re.compile(r"([A-Za-z0-9_\-/]+)\s*(\+?=)\s*")


def _data_blocks(text: str) -> str:
    """Concatenate the ``\\begindata`` sections of a SPICE text kernel."""
    out, on = [], False
    for line in text.splitlines():
        s = line.strip()
        if s.startswith("\\begindata"):
            on = True
            continue
        if s.startswith("\\begintext"):
            on = False
            continue
        if on:
            out.append(line)
    return "\n".join(out)


def _tokens(value: str) -> list[str | float]:
    vals: list[str | float] = []
    for m in re.finditer(r"'((?:[^']|'')*)'|(@[^\s,()]+)|([^\s,()]+)", value):
        if m.group(1) is not None:
            vals.append(m.group(1).replace("''", "'"))
        elif m.group(2) is not None:
            vals.append(m.group(2))
        else:
            tok = m.group(3).replace("D", "E").replace("d", "e")
            try:
                vals.append(float(tok))
            except ValueError:
                vals.append(m.group(3))
    return vals


def parse_text_kernel_data(text: str) -> dict[str, list[str | float]]:
    """Parse the ``\\begindata`` assignments of a SPICE text kernel.

    Returns a mapping of variable name to its list of values (strings or
    floats). ``+=`` appends. Strings ending in ``+`` inside one assignment are
    *not* joined here (see :func:`_join_continued`).
    """
    data = _data_blocks(text)
    result: dict[str, list[str | float]] = {}
    matches = list(_ASSIGN.finditer(data))
    for i, m in enumerate(matches):
        end = matches[i + 1].start() if i + 1 < len(matches) else len(data)
        raw = data[m.end():end]
        if raw.lstrip().startswith("("):
            depth_end = raw.find(")")
            raw = raw[raw.find("(") + 1: depth_end if depth_end >= 0 else len(raw)]
        vals = _tokens(raw)
        if m.group(2) == "+=":
            result.setdefault(m.group(1), []).extend(vals)
        else:
            result[m.group(1)] = vals
    return result


def _join_continued(values: Iterable[str | float]) -> list[str]:
    """Join SPICE string continuations (a value ending in '+' continues in the next)."""
    out: list[str] = []
    buf = ""
    for v in values:
        s = str(v)
        if s.endswith("+"):
            buf += s[:-1]
        else:
            out.append(buf + s)
            buf = ""
    if buf:
        out.append(buf)
    return out


@dataclass(frozen=True)
class KernelSet:
    """An ordered, immutable list of kernel files.

    Parameters
    ----------
    paths : tuple of str
        Absolute paths, in load order (later kernels take priority).
    source : str
        Where the list came from (the meta-kernel path), for messages.
    """

    paths: tuple[str, ...]
    source: str = ""

    @classmethod
    def from_files(cls, paths: Iterable[str | os.PathLike[str]], source: str = "") -> "KernelSet":
        """A kernel set from explicit file names (made absolute)."""
        return cls(tuple(str(Path(p).expanduser().resolve()) for p in paths), source)

    @classmethod
    def from_metakernel(cls, path: str | os.PathLike[str],
                        path_values: Mapping[str, str] | None = None) -> "KernelSet":
        """Read a meta-kernel wherever it lives.

        Parameters
        ----------
        path : path-like
            The meta-kernel (``.tm``) file.
        path_values : mapping, optional
            Overrides for ``PATH_SYMBOLS`` (symbol name to folder). Relative
            ``PATH_VALUES`` in the file are resolved against the meta-kernel's
            folder; the placeholder values ``'.'`` and ``'$ROOT'`` mean that
            folder itself.

        Raises
        ------
        MissingKernelError
            The meta-kernel or one of the kernels it names does not exist.
        KernelError
            The meta-kernel has no ``KERNELS_TO_LOAD`` or is unreadable.
        """
        mk = Path(path).expanduser()
        if not mk.is_file():
            raise MissingKernelError(f"meta-kernel not found: {mk}")
        try:
            text = mk.read_text(errors="replace")
        except OSError as err:
            raise KernelError(f"cannot read meta-kernel {mk}: {err}") from err
        data = parse_text_kernel_data(text)
        if "KERNELS_TO_LOAD" not in data:
            raise KernelError(f"meta-kernel {mk} has no KERNELS_TO_LOAD assignment")
        folder = mk.resolve().parent
        symbols = [str(s) for s in data.get("PATH_SYMBOLS", [])]
        values = _join_continued(data.get("PATH_VALUES", []))
        if len(symbols) != len(values):
            raise KernelError(f"meta-kernel {mk}: PATH_SYMBOLS and PATH_VALUES differ in length")
        resolved: dict[str, str] = {}
        for sym, val in zip(symbols, values):
            if "\x00" in val:
                raise KernelError(f"meta-kernel {mk}: PATH_VALUES entry {val!r:.80} holds a NUL character")
            if path_values and sym in path_values:
                resolved[sym] = str(Path(path_values[sym]).expanduser().resolve())
            elif val in (".", "$ROOT", ""):
                resolved[sym] = str(folder)
            elif os.path.isabs(val):
                resolved[sym] = val
            else:
                resolved[sym] = str((folder / val).resolve())
        files = []
        for name in _join_continued(data["KERNELS_TO_LOAD"]):
            if "\x00" in name:  # the OS cannot name such a file (and pathlib raises ValueError)
                raise KernelError(f"meta-kernel {mk}: kernel name {name!r:.80} holds a NUL character")
            for sym in sorted(resolved, key=len, reverse=True):
                name = name.replace("$" + sym, resolved[sym])
            p = Path(name)
            files.append(str(p if p.is_absolute() else (folder / p).resolve()))
        kset = cls(tuple(files), str(mk.resolve()))
        kset.check_files()
        return kset

    def check_files(self) -> None:
        """Raise :class:`MissingKernelError` naming the first kernel that does not exist."""
        for p in self.paths:
            if not os.path.isfile(p):
                where = f" (named in {self.source})" if self.source else ""
                raise MissingKernelError(f"kernel file not found: {p}{where}")

    @property
    def fingerprint(self) -> str:
        """SHA-256 over the paths, sizes and modification times of the files."""
        h = hashlib.sha256()
        for p in self.paths:
            h.update(p.encode())
            try:
                st = os.stat(p)
                h.update(f"{st.st_size}:{st.st_mtime_ns}".encode())
            except OSError:
                h.update(b"missing")
        return h.hexdigest()

    def __len__(self) -> int:
        return len(self.paths)
