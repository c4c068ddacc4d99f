"""The data directory's health: start-up checks, the one-server lock, free space, and user-facing reasons.

No HTTP here.  Everything the service keeps (``skyloc.sqlite``, ``dems/``, ``jobs/``) lives in one data
directory; this module decides whether it can be used:

* :func:`check_data_dir` (start-up): the folder exists or can be created and a file can be written and
  synced in it, else :class:`board.errors.InvalidInputError` with the operating system's reason;
* :class:`DataDirLock`: an exclusive ``flock`` on ``DATA/server.lock`` held for the server's lifetime,
  so a second server on the same folder refuses to start (the kernel drops the lock when the process
  dies, even by SIGKILL);
* :class:`StorageMonitor`: while running, "not writable" or "short of space" (less than
  ``min_free_bytes`` free), cached for a second, for ``/healthz`` and the job runner;
* :func:`public_reason`: the text a job's ``error`` shows: storage failures (disk full, read-only)
  become a reason a user can act on, and server paths are replaced by ``<data>`` / ``<file>``.
"""
from __future__ import annotations

import errno
import fcntl
import logging
import os
import re
import threading
import time
from pathlib import Path

from board.errors import InvalidInputError, SkylocError

log = logging.getLogger(__name__)

LOCK_NAME = "server.lock"
_PROBE = ".write-probe"
NO_SPACE = ("the server's data directory is out of disk space: free space on the server (or ask its operator "
            "to), then submit the job again; finished tiles are kept and not rendered again")
READ_ONLY = ("the server cannot write its data directory (read-only or permission denied): ask its operator to "
             "make it writable, then submit the job again; finished tiles are kept")
_NO_SPACE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG}
_READ_ONLY_ERRNOS = {errno.EROFS, errno.EACCES, errno.EPERM}


def _probe_write(folder: Path) -> None:
    """Create, write, fsync and remove a small file in ``folder`` (raises OSError)."""
    path = folder / f"{_PROBE}-{os.getpid()}-{threading.get_ident()}"
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.write(fd, b"skyloc")
        os.fsync(fd)
    finally:
        os.close(fd)
        try:
            os.unlink(path)
        except FileNotFoundError:
            pass


def check_data_dir(data_dir: Path) -> None:
    """Start-up check: ``data_dir`` and its sub-folders exist (created) and are writable."""
    data_dir = Path(data_dir)
    try:
        for d in (data_dir, data_dir / "dems", data_dir / "jobs"):
            d.mkdir(parents=True, exist_ok=True)
        _probe_write(data_dir)
    except OSError as exc:
        raise InvalidInputError(f"cannot write the data directory {data_dir} ({exc.strerror or exc}): give a "
                                "writable --data folder (or remount it read-write) and start again") from None


class DataDirLock:
    """Exclusive lock on ``DATA/server.lock``: one server per data directory (InvalidInputError otherwise)."""

    def __init__(self, data_dir: Path) -> None:
        self.path = Path(data_dir) / LOCK_NAME
        self._fh = open(self.path, "a+")  # noqa: SIM115 (held open for the server's lifetime)
        try:
            fcntl.flock(self._fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._fh.seek(0)
            holder = self._fh.read().strip() or "unknown"
            self._fh.close()
            raise InvalidInputError(f"the data directory {Path(data_dir)} is in use by another skyloc server "
                                    f"(pid {holder}): stop that server, or give this one another --data folder")
        self._fh.seek(0)
        self._fh.truncate()
        self._fh.write(f"{os.getpid()}\n")
        self._fh.flush()

    def release(self) -> None:
        if not self._fh.closed:
            fcntl.flock(self._fh.fileno(), fcntl.LOCK_UN)
            self._fh.close()


def is_no_space(exc: BaseException) -> bool:
    """True for 'disk full' in any form the stack raises it (OSError, SQLite, a wrapped message)."""
    if isinstance(exc, OSError) and exc.errno in _NO_SPACE_ERRNOS:
        return True
    text = str(exc).lower()
    return ("disk is full" in text or "no space left" in text or "disk quota exceeded" in text
            or f"[errno {errno.ENOSPC}]" in text)


def is_read_only(exc: BaseException) -> bool:
    """True for 'cannot write' (read-only file system, permission denied, read-only SQLite database)."""
    if isinstance(exc, OSError) and exc.errno in _READ_ONLY_ERRNOS:
        return True
    text = str(exc).lower()
    return "read-only file system" in text or "readonly database" in text or "attempt to write a readonly" in text


def is_storage_error(exc: BaseException) -> bool:
    """True when ``exc`` means the data directory cannot take writes (full or read-only)."""
    return is_no_space(exc) or is_read_only(exc)


def storage_reason(exc: BaseException) -> str:
    """The user-facing reason of a storage error."""
    return NO_SPACE if is_no_space(exc) else READ_ONLY


_ABS_PATH = re.compile(r"(?<![\w.:/>])(/[\w.+@%=-]+){2,}/?")


def scrub_paths(text: str, data_dir: Path | None = None) -> str:
    """``text`` without server paths: the data directory becomes ``<data>``, any other absolute path ``<file>``."""
    if data_dir is not None:
        for d in {str(Path(data_dir)), str(Path(data_dir).resolve())}:
            text = text.replace(d, "<data>")
    return _ABS_PATH.sub("<file>", text)


def public_reason(exc: BaseException, data_dir: Path | None = None) -> str:
    """What a job's ``error`` says about ``exc``: storage failures in plain words, no server paths."""
    if is_storage_error(exc):
        return storage_reason(exc)
    text = str(exc) if isinstance(exc, SkylocError) else f"{type(exc).__name__}: {exc}"
    if isinstance(exc, KeyError) and exc.args:
        text = str(exc.args[0])
    return scrub_paths(text, data_dir)[:2000]


class StorageMonitor:
    """Whether the data directory takes writes now: None (fine) or the reason; checked at most once a second.

    min_free_bytes : below this much free space the directory counts as short of space
    """

    def __init__(self, data_dir: Path, *, min_free_bytes: int, ttl_s: float = 1.0) -> None:
        self.data_dir = Path(data_dir)
        self.min_free_bytes = int(min_free_bytes)
        self.ttl_s = ttl_s
        self._checked = -1e9
        self._problem: str | None = None
        self._lock = threading.Lock()

    def problem(self, *, force: bool = False) -> str | None:
        now = time.monotonic()
        with self._lock:
            if force or now - self._checked >= self.ttl_s:
                self._checked = now
                previous, self._problem = self._problem, self._check()
                if self._problem != previous:
                    (log.warning if self._problem else log.info)(
                        "data directory: %s", self._problem or "writable again")
            return self._problem

    def _check(self) -> str | None:
        try:
            st = os.statvfs(self.data_dir)
        except OSError as exc:
            return f"the data directory cannot be read ({exc.strerror}): ask the server's operator"
        free = st.f_bavail * st.f_frsize
        if free < self.min_free_bytes:
            return (f"the data directory is short of space ({free / 2**20:.1f} MiB free, "
                    f"{self.min_free_bytes / 2**20:.0f} MiB needed): jobs wait until space is freed")
        try:
            for folder in (self.data_dir, self.data_dir / "dems", self.data_dir / "jobs"):
                if folder.is_dir() or folder == self.data_dir:
                    _probe_write(folder)
        except OSError as exc:
            if exc.errno in _NO_SPACE_ERRNOS:
                return "the data directory is out of disk space: jobs wait until space is freed"
            return f"the data directory is not writable ({exc.strerror}): jobs wait until it is writable again"
        return None
