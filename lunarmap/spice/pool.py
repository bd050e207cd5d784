"""The one owner of SPICE's global kernel pool.

CSPICE keeps a single kernel pool per process and is not thread-safe;
spiceypy releases the GIL on every call, so two threads really do race.
Every lunarmap call into SPICE therefore goes through :data:`SPICE_LOCK`, and
only this module furnishes or clears kernels.

* :func:`kernels` - context manager: load a :class:`~lunarmap.spice.kernelset.KernelSet`
  (unless it is already loaded), hold the lock, and restore the previous pool
  state afterwards.
* :func:`ensure_loaded` - make a kernel set the process's resident set (used by
  the dask worker plugin); later :func:`kernels` calls with the same set cost
  nothing.
* :func:`spice_errors` - translate spiceypy exceptions into lunarmap ones whose
  message names the body, frame, file or time concerned.
"""

from __future__ import annotations

import contextlib
import threading
from typing import Iterator

import spiceypy
from spiceypy.utils.exceptions import NotFoundError, SpiceyError

from ..errors import KernelCoverageError, MissingKernelError, SpiceError
from .kernelset import KernelSet

__all__ = ["SPICE_LOCK", "kernels", "ensure_loaded", "loaded_kernel_set", "clear", "spice_errors"]

#: Re-entrant process-wide lock around every SPICE call.
SPICE_LOCK = threading.RLock()

_state: dict[str, KernelSet | None] = {"loaded": None}

_MISSING = {"NOSUCHFILE", "FILENOTFOUND", "FILEDOESNOTEXIST", "NOLOADEDFILES"}
_COVERAGE = {
    "SPKINSUFFDATA", "CKINSUFFDATA", "NOFRAMECONNECT", "FRAMEDATANOTFOUND", "NOTINPOOL",
    "KERNELVARNOTFOUND", "NOLEAPSECONDS", "MISSINGTIMEINFO", "NOSCLKFILENAMES", "UNKNOWNFRAME",
    "FRAMEIDNOTFOUND", "IDCODENOTFOUND", "NOTRANSLATION", "NOINSTRUMENTID", "BODYIDNOTFOUND",
    "EMPTYSEGMENT", "COVERAGEGAP", "NOFRAMEDATA", "CKLOOKUPFAILED", "SPKLOOKUPFAILED",
    "VALUEOUTOFRANGE", "TIMEOUTOFBOUNDS", "NOTCOVERED",
}


def _short(err: SpiceyError) -> str:
    short = getattr(err, "short", "") or ""
    return short.replace("SPICE(", "").rstrip(")")


@contextlib.contextmanager
def spice_errors(context: str) -> Iterator[None]:
    """Run a block of SPICE calls; re-raise SPICE errors as lunarmap exceptions.

    Parameters
    ----------
    context : str
        What was being computed, e.g. ``"position of body -85 at ET 302228504.37"``;
        it starts the exception message.
    """
    try:
        yield
    except NotFoundError as err:
        raise KernelCoverageError(f"{context}: not found in the loaded kernels ({err})") from err
    except SpiceyError as err:
        code = _short(err)
        detail = (getattr(err, "long", "") or str(err)).strip()
        msg = f"{context}: SPICE({code}) {detail}"
        if code in _MISSING:
            raise MissingKernelError(msg) from err
        if code in _COVERAGE or "INSUFF" in code or "NOTFOUND" in code:
            raise KernelCoverageError(msg) from err
        raise SpiceError(msg) from err


def _load(kset: KernelSet | None) -> None:
    spiceypy.kclear()
    _state["loaded"] = None
    if kset is None:
        return
    kset.check_files()
    for path in kset.paths:
        with spice_errors(f"loading kernel {path}"):
            spiceypy.furnsh(str(path))
    _state["loaded"] = kset


def loaded_kernel_set() -> KernelSet | None:
    """The kernel set currently resident in this process's pool, if any."""
    return _state["loaded"]


def ensure_loaded(kset: KernelSet) -> None:
    """Make ``kset`` the resident kernel set of this process (no-op if it already is)."""
    with SPICE_LOCK:
        if _state["loaded"] != kset:
            try:
                _load(kset)
            except BaseException:
                _load(None)  # never leave a half-loaded pool behind
                raise


def clear() -> None:
    """Unload every kernel."""
    with SPICE_LOCK:
        _load(None)


@contextlib.contextmanager
def kernels(kset: KernelSet) -> Iterator[KernelSet]:
    """Hold the SPICE lock with ``kset`` loaded; restore the previous state on exit.

    Nested use with the same set, or use after :func:`ensure_loaded` with the
    same set, does not reload anything.
    """
    with SPICE_LOCK:
        previous = _state["loaded"]
        ensure_loaded(kset)
        try:
            yield kset
        finally:
            if previous != kset:
                try:
                    _load(previous)
                except BaseException:
                    _load(None)
                    raise
