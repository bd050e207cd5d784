"""The run's ``outputs`` folder: copies of store entries and the RFMs' text forms, written only when stale.

Every file of ``<run>/outputs`` is made from a store entry: a copy (ISDs, RFMs as netCDF, the tie points,
the adjustment, meta-kernels) or a derived file (an RFM's ``_RPC.TXT``). The manifest
``outputs/.sources.json`` records, per file (path relative to ``outputs``), the entry it was made from:
``"<entry>"`` for a copy, ``"<entry>\\n<sha256 of the file>"`` for a derived file. A file is fresh, and
left as it is, when the manifest names the same entry and the file still has the content written then
(a copy: the entry's content digests; a derived file: its own digest), so a rerun writes nothing and a
damaged output is written again.

The per-image files are written by the per-image tasks themselves (:func:`export_image`,
:func:`export_rpcs`), on whichever worker runs them, so that a run of hundreds of images has no serial
export after its graph; they return their manifest rows (:class:`Exported`) and the engine writes the
manifest once. Every write is atomic (:func:`lunarmap.atomic.atomic_write`): a file under its final name
is complete, whichever task or process wrote it.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from .store import _entry_digests, file_digest, note_copy

__all__ = ["Exported", "Outputs", "MANIFEST", "read_manifest", "export_image", "export_rpcs"]

#: The manifest's name in the outputs folder.
MANIFEST = ".sources.json"


def read_manifest(out: str | Path) -> dict[str, str]:
    """The manifest rows of an outputs folder (empty when missing or unreadable: every file is then stale)."""
    try:
        doc = json.loads((Path(out) / MANIFEST).read_text())
    except (OSError, ValueError):
        return {}
    return {str(k): str(v) for k, v in doc.items()} if isinstance(doc, dict) else {}


@dataclass
class Exported:
    """Manifest rows of the output files a task wrote or found fresh (path relative to ``outputs`` -> source)."""

    rows: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class Outputs:
    """An outputs folder and the manifest rows a task needs of it (picklable: it travels with the task).

    Attributes
    ----------
    folder : str
        ``<run>/outputs``.
    rows : dict
        The previous manifest's rows of the files the task writes (the whole manifest for the engine's own
        copies).
    """

    folder: str
    rows: dict[str, str] = field(default_factory=dict)

    def subset(self, names: Sequence[str]) -> "Outputs":
        """The same folder with only the rows of ``names`` (what a task needs to travel with it)."""
        return Outputs(self.folder, {k: self.rows[k] for k in names if k in self.rows})

    def copy(self, src: str | Path, rel: str, done: Exported) -> Path:
        """Copy a store entry (file or directory) to ``outputs/<rel>`` unless the copy there is fresh."""
        out = Path(self.folder)
        dst = out / rel
        done.rows[rel] = str(src)
        if self._copy_fresh(src, dst, rel):
            return dst
        from ..atomic import atomic_write

        dst.parent.mkdir(parents=True, exist_ok=True)
        if Path(src).is_dir():
            tmp = dst.with_name(f".{dst.name}.tmp")
            shutil.rmtree(tmp, ignore_errors=True)
            shutil.copytree(src, tmp)
            shutil.rmtree(dst, ignore_errors=True)
            tmp.replace(dst)
        else:
            atomic_write(dst, lambda tmp: shutil.copyfile(src, tmp))
        note_copy(src, dst)
        return dst

    def _copy_fresh(self, src: str | Path, dst: Path, rel: str) -> bool:
        # copied from this store entry before, and still its content (a damaged copy is copied again)
        if not (self.rows.get(rel) == str(src) and dst.exists()):
            return False
        if Path(src).is_dir() != dst.is_dir():
            return False
        try:
            return _entry_digests(Path(src)) == _entry_digests(dst) if Path(src).exists() else True
        except OSError:
            return False

    def rpc_text(self, src: str | Path, rel: str, done: Exported) -> Path:
        """Write the ``_RPC.TXT`` form of a stored RFM (netCDF) to ``outputs/<rel>`` unless it is fresh."""
        dst = Path(self.folder) / rel
        was = self.rows.get(rel, "").split("\n")
        try:
            fresh = len(was) == 2 and was[0] == str(src) and dst.exists() and file_digest(dst) == was[1]
        except OSError:
            fresh = False
        if fresh:
            done.rows[rel] = "\n".join(was)        # its digest was just checked: not hashed a second time
            return dst
        from ..rpc import write_rpc_txt

        dst.parent.mkdir(parents=True, exist_ok=True)
        write_rpc_txt(_stored_rfm(src), dst)
        # a derived file's own digest (it never equals the entry's): a damaged one is written again
        done.rows[rel] = f"{src}\n{file_digest(dst)}"
        return dst


# RFMs this process just wrote to the store, by (path, size, modification time): their text forms are written
# from them rather than by reading each netCDF back (a guarded read forks a probe first: most of a 48-image
# run's export, profiled); one use each, so the dict stays small
_JUST_WRITTEN: dict[tuple[str, int, int], Any] = {}


def _stamp(path: str | Path) -> tuple[str, int, int]:
    st = Path(path).stat()
    return str(path), st.st_size, st.st_mtime_ns


def remember_rfm(path: str | Path, model: Any) -> None:
    """Note the model a step just stored at ``path`` (netCDF: it reads back to the same model, bit for bit)."""
    while len(_JUST_WRITTEN) >= 256:
        _JUST_WRITTEN.pop(next(iter(_JUST_WRITTEN)))
    _JUST_WRITTEN[_stamp(path)] = model


def _stored_rfm(path: str | Path) -> Any:
    """The RFM stored at ``path``: the one this process just wrote there, else read from the file."""
    model = _JUST_WRITTEN.pop(_stamp(path), None)
    if model is not None:
        return model
    from ..rpc import read_netcdf

    return read_netcdf(path)


def image_files(name: str, rpc: bool) -> list[str]:
    """The outputs of one image written by its per-image task (paths relative to ``outputs``)."""
    return [f"isd/{name}.json"] + ([f"rpc/{name}.nc", f"rpc/{name}_RPC.TXT"] if rpc else [])


def export_image(outputs: Outputs, records: Sequence[Any]) -> Exported:
    """An image's ISD and navigation RFM (netCDF and ``_RPC.TXT``) in ``outputs``, from its steps' records."""
    done = export_rpcs(outputs, [d for d in records if d.step == "rpc"], "rpc")
    for d in records:
        if d.step == "isd":
            outputs.copy(d.path, f"isd/{d.item}.json", done)
    return done


def export_rpcs(outputs: Outputs, records: Sequence[Any], stage: str) -> Exported:
    """RFMs (netCDF and ``_RPC.TXT``) of several images in ``outputs/<stage>``, from their steps' records."""
    done = Exported()
    for d in records:
        outputs.copy(d.path, f"{stage}/{d.item}.nc", done)
        outputs.rpc_text(d.path, f"{stage}/{d.item}_RPC.TXT", done)
    return done
