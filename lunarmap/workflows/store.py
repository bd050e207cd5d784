"""The run folder's store: every step's output under a key derived from its inputs and parameters.

A key is the SHA-256 of the step's name, its parameters and the identities of its inputs (content
digests of input files, keys of upstream steps), so that

* a rerun finds every finished output and skips its step;
* changing one parameter changes the keys of that step and of everything downstream, and nothing else;
* an interrupted step leaves no file: outputs are written to a temporary name and renamed into
  place (:mod:`lunarmap.atomic`), so a file under its key is complete.

Layout: ``<run>/store/<step>/<key>.<ext>`` (a directory ``<key>/`` for steps with several files, renamed
into place as a whole).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable

__all__ = ["Store", "file_digest", "files_digest", "step_key", "load_digests", "save_digests"]

_DIGESTS: dict[tuple[str, int, int], str] = {}


def load_digests(path: str | os.PathLike[str]) -> int:
    """Remember the content digests a previous run of this folder computed (``digests.json``).

    An entry is used only for a file of the same path, size and modification time (nanoseconds), as
    ``make`` trusts a file's time: a rerun does not read gigabytes of images again to learn that they
    did not change. Returns the number of entries read; an unreadable file is ignored (the digests are
    recomputed).
    """
    try:
        rows = json.loads(Path(path).read_text())
        for p, size, mtime, digest in rows:
            _DIGESTS[(str(p), int(size), int(mtime))] = str(digest)
        return len(rows)
    except (OSError, ValueError, TypeError):
        return 0


def save_digests(path: str | os.PathLike[str]) -> None:
    """Write the digests of every file this process has hashed, atomically (see :func:`load_digests`)."""
    from ..atomic import atomic_write

    rows = [[p, size, mtime, d] for (p, size, mtime), d in sorted(_DIGESTS.items())]
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda tmp: tmp.write_text(json.dumps(rows)))


def file_digest(path: str | os.PathLike[str]) -> str:
    """SHA-256 of a file's content (cached per path, size and modification time)."""
    p = Path(path)
    st = p.stat()
    memo = (str(p.resolve()), st.st_size, st.st_mtime_ns)
    if memo not in _DIGESTS:
        h = hashlib.sha256()
        with open(p, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
        _DIGESTS[memo] = h.hexdigest()
    return _DIGESTS[memo]


def files_digest(paths: Iterable[str | os.PathLike[str]]) -> str:
    """SHA-256 over the content digests of several files, in order."""
    h = hashlib.sha256()
    for p in paths:
        h.update(file_digest(p).encode())
    return h.hexdigest()


def step_key(step: str, params: Any = None, inputs: Iterable[str] = ()) -> str:
    """The key of a step's output: a digest of its name, parameters (JSON) and input identities."""
    doc = json.dumps({"step": step, "params": params, "inputs": list(inputs)}, sort_keys=True, default=str)
    return hashlib.sha256(doc.encode()).hexdigest()[:24]


@dataclass(frozen=True)
class Store:
    """Outputs of a run's steps (see the module docstring); picklable, safe to share between processes."""

    root: Path

    def path(self, step: str, key: str, ext: str = "") -> Path:
        """Where the output of ``step`` with ``key`` lives (``ext`` without the dot; empty for a directory)."""
        return self.root / step / (f"{key}.{ext}" if ext else key)

    def has(self, step: str, key: str, ext: str = "") -> bool:
        return self.path(step, key, ext).exists()

    def write(self, step: str, key: str, ext: str, writer: Callable[[Path], Any]) -> Path:
        """Write one file atomically with ``writer(tmp_path)``; returns the final path."""
        from ..atomic import atomic_write

        final = self.path(step, key, ext)
        final.parent.mkdir(parents=True, exist_ok=True)
        return atomic_write(final, writer)

    def write_dir(self, step: str, key: str, writer: Callable[[Path], Any]) -> Path:
        """Fill a new directory with ``writer(tmp_dir)`` and rename it into place as a whole."""
        final = self.path(step, key)
        final.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{key}.", dir=final.parent))
        try:
            writer(tmp)
            if final.exists():       # written meanwhile by another attempt of the same task: identical
                shutil.rmtree(tmp)
            else:
                os.replace(tmp, final)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return final
