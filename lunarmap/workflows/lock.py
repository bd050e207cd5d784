"""The run folder's lock: one run at a time per folder (``<run>/run.lock``).

An advisory ``flock`` on ``run.lock``, which holds the holder's pid, host and start time. The kernel
releases a ``flock`` when its process dies, so a lock left by a killed run is free at once; the file's
content then only says who held it last (logged as a stale lock). Where ``flock`` is not available
(some network file systems), the content decides: a lock of this host whose pid no longer runs is stale
and taken over; any other is held.

A second run in the same folder either waits for the lock (``wait=True``: it then finds the first run's
outputs in the store and computes nothing) or stops at once with :class:`~lunarmap.errors.RunLockedError`
naming the holder. ``force=True`` (``lunarmap run --force``) takes the folder whatever the lock says,
e.g. after a crash on another host of a shared file system; two runs then really do share the folder.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import socket
import time
from pathlib import Path
from typing import Any

from ..errors import RunLockedError

__all__ = ["RunLock", "LOCK_NAME"]

LOCK_NAME = "run.lock"
_log = logging.getLogger(__name__)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class RunLock:
    """The lock of a run folder (a context manager)."""

    def __init__(self, folder: str | os.PathLike[str], wait: bool = False, force: bool = False,
                 poll: float = 0.5, timeout: float | None = None) -> None:
        self.path = Path(folder) / LOCK_NAME
        self.wait, self.force, self.poll, self.timeout = wait, force, poll, timeout
        self._fd: int | None = None
        self.waited = 0.0

    def holder(self) -> dict[str, Any]:
        """What the lock file says (pid, host, started), ``{}`` when unreadable."""
        try:
            doc = json.loads(self.path.read_text() or "{}")
            return doc if isinstance(doc, dict) else {}
        except (OSError, ValueError):
            return {}

    def _describe(self, h: dict[str, Any]) -> str:
        if not h:
            return "another process"
        return f"pid {h.get('pid')} on host {h.get('host')} (since {h.get('started')})"

    def acquire(self) -> "RunLock":
        import fcntl

        t0 = time.monotonic()
        self._fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        while True:
            try:
                fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except OSError as err:
                if err.errno in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS):
                    self._fallback()
                    break
                if err.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise
            if self.force:
                _log.warning("run folder %s is locked by %s: taking it anyway (--force)", self.path.parent,
                             self._describe(self.holder()))
                break
            if not self.wait or (self.timeout is not None and time.monotonic() - t0 > self.timeout):
                os.close(self._fd)
                self._fd = None
                raise RunLockedError(f"run folder {self.path.parent} is in use by {self._describe(self.holder())} "
                                     f"({self.path}); wait for it (--wait), or, if that run is gone, --force")
            time.sleep(self.poll)
        self.waited = time.monotonic() - t0
        old = self.holder()
        if old and not self.force and (old.get("host") != socket.gethostname() or old.get("pid") != os.getpid()):
            if old.get("released") is None:
                _log.warning("stale lock of run folder %s removed: %s did not release it (killed?)",
                             self.path.parent, self._describe(old))
        self._write({"pid": os.getpid(), "host": socket.gethostname(),
                     "started": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())})
        return self

    def _fallback(self) -> None:
        """No flock here: decide by the file's pid and host."""
        h = self.holder()
        held = h and h.get("released") is None and not (
            h.get("host") == socket.gethostname() and not _alive(int(h.get("pid", -1))))
        if held and not self.force:
            raise RunLockedError(f"run folder {self.path.parent} is in use by {self._describe(h)} ({self.path}; "
                                 "no flock on this file system); if that run is gone, --force")

    def _write(self, doc: dict[str, Any]) -> None:
        assert self._fd is not None
        data = json.dumps(doc).encode()
        os.ftruncate(self._fd, 0)
        os.pwrite(self._fd, data, 0)

    def release(self) -> None:
        if self._fd is None:
            return
        import fcntl

        try:
            h = self.holder()
            h["released"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
            self._write(h)
            fcntl.flock(self._fd, fcntl.LOCK_UN)
        finally:
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> "RunLock":
        return self.acquire()

    def __exit__(self, *exc: Any) -> None:
        self.release()
