"""Atomic file output: write to a temporary file beside the target, then rename it over the target.

Every lunarmap writer (kernels, ISDs, RPCs, tie-point tables, control networks, BAL files)
goes through here, so a failed or interrupted write never leaves a half-written file: the
target is either the old file or the complete new one, and the temporary file is removed.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

from .errors import InvalidInputError

__all__ = ["atomic_path", "atomic_write"]


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
    fd, tmp_name = tempfile.mkstemp(prefix=f".{final.name}.", suffix=".tmp", dir=folder)
    os.close(fd)
    tmp = Path(tmp_name)
    tmp.unlink()
    try:
        yield tmp
        if not tmp.is_file():
            raise InvalidInputError(f"writing {final}: nothing was written")
        os.replace(tmp, final)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


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
