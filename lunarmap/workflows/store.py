"""The run folder's store: every step's output under a key derived from its inputs and parameters.

A key is the SHA-256 of the step's name, its parameters and the identities of its inputs (content
digests of input files, keys of upstream steps), so that

* a rerun finds every finished output and skips its step;
* changing one parameter changes the keys of that step and of everything downstream, and nothing else;
* an interrupted step leaves no file: outputs are written to a temporary name and renamed into
  place (:mod:`lunarmap.atomic`), so a file under its key is complete.

Layout: ``<run>/store/<step>/<key>.<ext>`` (a directory ``<key>/`` for steps with several files, renamed
into place as a whole).

Integrity (issue 28): every entry has a checksum sidecar ``<entry>.sha256`` (JSON: the step, the key and
the SHA-256 of each of its files), written atomically right after the entry. Before a run reuses an
entry it verifies it (:func:`verify_entry`): a missing or wrong sidecar, a missing, extra or changed file
means the entry is removed and its step computed again, with a :class:`~lunarmap.errors.StoreDamageWarning`
naming the file; it is never reused. A rerun does not read every stored byte again: content digests are
remembered per path, size and modification time (``digests.json``, itself checksummed), as for the
inputs; ``lunarmap run CONFIG --check`` hashes everything afresh (:func:`verify_store`) without computing.
An entry without a sidecar is one whose writer was interrupted between the two renames: recomputed.
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

__all__ = ["Store", "file_digest", "files_digest", "step_key", "load_digests", "save_digests", "digest_rows",
           "add_digests", "seal", "verify_entry",
           "verify_store", "remove_entry", "entry_of", "SIDECAR"]

#: Suffix of an entry's checksum sidecar.
SIDECAR = ".sha256"

_DIGESTS: dict[tuple[str, int, int], str] = {}


def load_digests(path: str | os.PathLike[str]) -> int:
    """Remember the content digests a previous run of this folder computed (``digests.json``).

    An entry is used only for a file of the same path, size and modification time (nanoseconds), as
    ``make`` trusts a file's time: a rerun does not read gigabytes of images again to learn that they
    did not change. Returns the number of entries read; an unreadable file is ignored (the digests are
    recomputed).
    """
    try:
        doc = json.loads(Path(path).read_text())
        rows = doc["rows"] if isinstance(doc, dict) else doc
        if isinstance(doc, dict) and hashlib.sha256(json.dumps(rows).encode()).hexdigest() != doc.get("sha256"):
            raise ValueError("checksum mismatch")
        entries = {}
        for p, size, mtime, digest in rows:
            if not (isinstance(digest, str) and len(digest) == 64):
                raise ValueError(f"bad digest {digest!r:.80}")
            entries[(str(p), int(size), int(mtime))] = str(digest)
    except FileNotFoundError:
        return 0
    except (OSError, ValueError, TypeError, KeyError) as err:
        # a damaged cache of digests only costs reading the files again
        import logging

        logging.getLogger(__name__).warning("%s is damaged (%s): content digests are computed again", path, err)
        return 0
    _DIGESTS.update(entries)
    return len(entries)


def save_digests(path: str | os.PathLike[str]) -> None:
    """Write the digests of every file this process has hashed, atomically (see :func:`load_digests`); a file
    that already holds them is left as it is (a rerun that hashed nothing new writes nothing)."""
    from ..atomic import atomic_write

    rows = [[p, size, mtime, d] for (p, size, mtime), d in sorted(_DIGESTS.items())]
    doc = {"sha256": hashlib.sha256(json.dumps(rows).encode()).hexdigest(), "rows": rows}
    text = json.dumps(doc)
    p = Path(path)
    try:
        if p.read_text() == text:
            return
    except (OSError, UnicodeDecodeError):
        pass
    p.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(p, lambda tmp: tmp.write_text(text))


def digest_rows(under: str) -> list[tuple[str, int, int, str]]:
    """The content digests this process knows of files under the folder ``under`` (absolute, resolved):
    what a worker hashed while writing the store and the outputs, for the run's main process to keep
    (:func:`add_digests`), so that a rerun does not read those files again."""
    prefix = str(Path(under)) + os.sep
    return [(p, size, mtime, d) for (p, size, mtime), d in _DIGESTS.items() if p.startswith(prefix)]


def add_digests(rows: Iterable[tuple[str, int, int, str]]) -> None:
    """Remember digests another process computed (rows of :func:`digest_rows`)."""
    for p, size, mtime, d in rows:
        _DIGESTS[(str(p), int(size), int(mtime))] = str(d)


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


def _fresh_digest(path: Path) -> str:
    """SHA-256 of a file's content, read now (no cache); also refreshes the cache."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    st = path.stat()
    _DIGESTS[(str(path.resolve()), st.st_size, st.st_mtime_ns)] = h.hexdigest()
    return h.hexdigest()


def note_copy(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
    """Remember that ``dst`` (a file or directory just copied) holds the bytes of ``src``: its content digests
    are those of ``src``, so that checking the copy later (a rerun's export) does not read it again."""
    dst = Path(dst)
    for rel, d in _entry_digests(Path(src)).items():
        f = dst / rel if rel else dst
        st = f.stat()
        _DIGESTS[(str(f.resolve()), st.st_size, st.st_mtime_ns)] = d


def sidecar(entry: str | os.PathLike[str]) -> Path:
    """The checksum sidecar of a store entry (file or directory)."""
    p = Path(entry)
    return p.with_name(p.name + SIDECAR)


def _entry_files(entry: Path) -> list[Path]:
    if entry.is_dir():
        return sorted(p for p in entry.rglob("*") if p.is_file())
    return [entry]


def _entry_digests(entry: Path, fresh: bool = False) -> dict[str, str]:
    digest = _fresh_digest if fresh else file_digest
    if entry.is_dir():
        return {str(p.relative_to(entry)): digest(p) for p in _entry_files(entry)}
    return {"": digest(entry)}


def seal(entry: str | os.PathLike[str], step: str, key: str) -> Path:
    """Write the checksum sidecar of a complete store entry (atomically)."""
    from ..atomic import atomic_write

    p = Path(entry)
    doc = {"step": step, "key": key, "files": _entry_digests(p, fresh=True)}
    return atomic_write(sidecar(p), lambda tmp: tmp.write_text(json.dumps(doc, indent=0, sort_keys=True)))


def entry_of(store_root: Path, path: str | os.PathLike[str]) -> Path:
    """The store entry an output path belongs to (a file inside an entry directory -> the directory)."""
    p = Path(path)
    while p.parent.parent != Path(store_root) and p.parent != p and Path(store_root) in p.parents:
        p = p.parent
    return p


def _key_of(entry: Path) -> str:
    name = entry.name
    return name.split(".", 1)[0] if not entry.is_dir() else name


def verify_entry(entry: str | os.PathLike[str], fresh: bool = False) -> str | None:
    """``None`` when the entry is complete and matches its sidecar, else what is wrong (for the warning).

    ``fresh`` re-reads every byte; otherwise a file's digest is taken from the cache when its path, size
    and modification time are those it was hashed with.
    """
    p = Path(entry)
    if not p.exists():
        return f"{p} is missing"
    side = sidecar(p)
    try:
        doc = json.loads(side.read_text())
        files, key = dict(doc["files"]), str(doc["key"])
    except FileNotFoundError:
        return f"{p} has no checksum ({side.name} missing: its write was interrupted, or it predates checksums)"
    except (OSError, ValueError, TypeError, KeyError) as err:
        return f"{p}: its checksum file {side.name} is damaged ({type(err).__name__}: {err})"
    if key != _key_of(p):
        return f"{p}: its checksum file names key {key}, not {_key_of(p)}"
    try:
        now = _entry_digests(p, fresh=fresh)
    except OSError as err:
        return f"{p} is unreadable ({type(err).__name__}: {err})"
    if set(now) != set(files):
        missing, extra = sorted(set(files) - set(now)), sorted(set(now) - set(files))
        return f"{p}: files missing {missing[:5]} / unexpected {extra[:5]}"
    bad = [k for k in files if files[k] != now[k]]
    if bad:
        return f"{p / bad[0] if bad[0] else p}: content does not match its checksum (damaged)"
    return None


def remove_entry(entry: str | os.PathLike[str]) -> None:
    """Delete a store entry and its sidecar."""
    p = Path(entry)
    if p.is_dir():
        shutil.rmtree(p, ignore_errors=True)
    else:
        p.unlink(missing_ok=True)
    sidecar(p).unlink(missing_ok=True)


def verify_store(root: str | os.PathLike[str], fresh: bool = True) -> tuple[int, list[str]]:
    """Verify every entry of a run's store: ``(entries checked, problems)`` (see :func:`verify_entry`)."""
    root = Path(root)
    problems: list[str] = []
    n = 0
    if not root.is_dir():
        return 0, []
    for step in sorted(p for p in root.iterdir() if p.is_dir()):
        for entry in sorted(step.iterdir()):
            if entry.name.startswith(".") or entry.name.endswith(SIDECAR):
                continue          # temporary names of interrupted writes; sidecars
            n += 1
            why = verify_entry(entry, fresh=fresh)
            if why is not None:
                problems.append(why)
    return n, problems


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
        from ..atomic import atomic_write, disk_guard

        final = self.path(step, key, ext)
        with disk_guard(final, f"the {step} step's output"):
            final.parent.mkdir(parents=True, exist_ok=True)
            atomic_write(final, writer)
            seal(final, step, key)
        return final

    def write_dir(self, step: str, key: str, writer: Callable[[Path], Any]) -> Path:
        """Fill a new directory with ``writer(tmp_dir)`` and rename it into place as a whole."""
        from ..atomic import disk_guard

        final = self.path(step, key)
        with disk_guard(final, f"the {step} step's output"):
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
            if not sidecar(final).exists():
                seal(final, step, key)
        return final

    def seal(self, step: str, key: str, ext: str = "") -> Path:
        """Write the checksum sidecar of an entry a step wrote itself (pyramids, kernels)."""
        from ..atomic import disk_guard

        final = self.path(step, key, ext)
        with disk_guard(final, f"the {step} step's checksum"):
            return seal(final, step, key)
