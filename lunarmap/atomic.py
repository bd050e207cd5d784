"""Atomic file output: write to a temporary file beside the target, then rename it over the target.

Every lunarmap writer (kernels, ISDs, RPCs, tie-point tables, control networks, BAL files)
goes through here, so a failed or interrupted write never leaves a half-written file: the
target is either the old file or the complete new one, and the temporary file is removed.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

from .errors import DiskError, DiskFullError, DiskWriteError, InvalidInputError

__all__ = ["atomic_path", "atomic_write", "disk_error", "disk_guard", "check_writable", "LOW_SPACE_BYTES"]

#: Free bytes below which a failed write is taken for a full disk, whatever the library said (netCDF/HDF5
#: report ENOSPC as "NetCDF: HDF error").
LOW_SPACE_BYTES = 1 << 20

_FULL = {errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC), errno.EFBIG}
_READ_ONLY = {errno.EROFS, errno.EACCES, errno.EPERM}


def _free(path: Path) -> int | None:
    for p in (path, *path.parents):
        try:
            return shutil.disk_usage(p).free
        except OSError:
            continue
    return None


def disk_error(err: BaseException, path: str | os.PathLike[str], what: str) -> DiskError | None:
    """The named disk error for a failed write of ``path`` (``what``: what was being written), or ``None``
    when ``err`` is not the disk's doing."""
    if isinstance(err, DiskError):
        return err
    p = Path(path)
    code = getattr(err, "errno", None)
    if code in _FULL:
        return DiskFullError(f"writing {what} {p}: no space left on the device ({err})")
    if code in _READ_ONLY:
        return DiskWriteError(f"writing {what} {p}: not writable ({os.strerror(code)}: {err})")
    if isinstance(err, Exception):
        free = _free(p.parent if not p.is_dir() else p)
        if free is not None and free < LOW_SPACE_BYTES:
            return DiskFullError(f"writing {what} {p}: the disk is full ({free} bytes free; "
                                 f"{type(err).__name__}: {err})")
    return None


@contextlib.contextmanager
def disk_guard(path: str | os.PathLike[str], what: str) -> Iterator[None]:
    """Turn a disk fault inside the block into :class:`DiskFullError` / :class:`DiskWriteError` naming ``path``."""
    try:
        yield
    except BaseException as err:
        named = disk_error(err, path, what)
        if named is None or named is err:
            raise
        raise named from err


def check_writable(folder: str | os.PathLike[str], what: str) -> Path:
    """Create ``folder`` if needed and prove it writable with a probe file, before any work.

    Raises
    ------
    DiskWriteError
        Read-only file system, permission denied (the folder and what it is for are named).
    DiskFullError
        No space for even the probe.
    """
    p = Path(folder)
    try:
        p.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=".write_probe.", dir=p)
        try:
            os.write(fd, b"x")
        finally:
            os.close(fd)
            os.unlink(name)
    except OSError as err:
        named = disk_error(err, p, what)
        if named is None:
            raise DiskWriteError(f"writing {what} {p}: {type(err).__name__}: {err}") from err
        raise named from err
    return p


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a fresh temporary file name next to ``path``; rename it onto ``path`` on success.

    The temporary name does not exist when yielded (SPICE refuses to open an
    existing file for writing). If the block raises, the temporary file is
    removed and ``path`` is left untouched.

    Parameters
    ----------
    path : path-like
        Final file name; its folder must exist.

    Raises
    ------
    InvalidInputError
        The folder does not exist, or the block wrote nothing.
    """
    final = Path(path)
    folder = final.parent if str(final.parent) else Path(".")
    if not folder.is_dir():
        raise InvalidInputError(f"cannot write {final}: folder {folder} does not exist")
    # Same folder as the target: os.replace is only atomic within one file system.
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=f".{final.name}.", suffix=".tmp", dir=folder)
    except OSError as err:
        named = disk_error(err, final, "file")
        if named is None:
            raise
        raise named from err
    os.close(fd)
    tmp = Path(tmp_name)
    tmp.unlink()
    try:
        yield tmp
        if not tmp.is_file():
            raise InvalidInputError(f"writing {final}: nothing was written")
        os.replace(tmp, final)
    except BaseException as err:
        with contextlib.suppress(OSError):
            tmp.unlink()
        named = disk_error(err, final, "file") if not isinstance(err, InvalidInputError) else None
        if named is None or named is err:
            raise
        raise named from err


def atomic_write(path: str | os.PathLike[str], write: Callable[[Path], object]) -> Path:
    """Call ``write(tmp)`` on a temporary file name beside ``path``, then rename it over ``path``.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    with atomic_path(path) as tmp:
        write(tmp)
    return Path(path)
