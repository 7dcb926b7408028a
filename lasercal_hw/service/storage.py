"""The data folder's free space: what counts as "the disk is full", and a small reserve
file the daemon gives back when it is, so a job that ran out of space can still store how
it ended (``failed`` with ``storage_full``) and its followers get that final state.

New jobs are refused (``StorageFullError``) while the reserve cannot be kept or the free
space is below ``MIN_FREE_BYTES``; once space is back the next request takes the reserve
again, without a restart.
"""

from __future__ import annotations

import errno
import logging
import os
import sqlite3
import threading
from pathlib import Path

from lasercal_hw.service.errors import StorageFullError

logger = logging.getLogger(__name__)

RESERVE_FILE = "storage-reserve"
RESERVE_BYTES = 256 * 1024
MIN_FREE_BYTES = 1024 * 1024
_FULL_ERRNOS = (errno.ENOSPC, errno.EFBIG, errno.EDQUOT)


def storage_full_cause(exc: BaseException | None) -> str | None:
    """The one-line cause when ``exc`` (or what it was raised from) means the disk is full
    or a file may not grow (ENOSPC, EFBIG, EDQUOT, SQLite's SQLITE_FULL), else None."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, StorageFullError):
            return str(exc.detail.get("cause", exc.message))
        if isinstance(exc, OSError) and exc.errno in _FULL_ERRNOS:
            return f"{exc.strerror or os.strerror(exc.errno)}" + (f": {exc.filename}" if exc.filename else "")
        if isinstance(exc, sqlite3.Error) and getattr(exc, "sqlite_errorcode", None) == sqlite3.SQLITE_FULL:
            return "the history database cannot grow"
        exc = exc.__cause__ or exc.__context__
    return None


class StorageGuard:
    """Keeps ``RESERVE_BYTES`` of the data folder aside for the end of a job."""

    def __init__(self, data_dir: Path) -> None:
        self.data_dir = data_dir
        self._reserve = data_dir / RESERVE_FILE
        self._lock = threading.Lock()

    def free_bytes(self) -> int:
        """Bytes the daemon may still write in its data folder."""
        stats = os.statvfs(self.data_dir)
        return stats.f_bavail * stats.f_frsize

    def _refuse(self, why: str) -> StorageFullError:
        return StorageFullError(
            f"the data folder {self.data_dir} is full ({why}): free some space there, then try again; "
            "no restart is needed",
            {"data_dir": str(self.data_dir), "free_bytes": self.free_bytes(), "needed_bytes": MIN_FREE_BYTES},
        )

    def ensure(self) -> None:
        """Before a job: the reserve is in place and enough space is left (StorageFullError otherwise)."""
        with self._lock:
            if not self._reserve.exists():
                if self.free_bytes() < MIN_FREE_BYTES + RESERVE_BYTES:
                    raise self._refuse(f"{self.free_bytes() // 1024} KiB free")
                try:
                    with self._reserve.open("wb") as reserve:
                        reserve.write(b"\0" * RESERVE_BYTES)
                        reserve.flush()
                        os.fsync(reserve.fileno())
                except OSError as exc:
                    self._reserve.unlink(missing_ok=True)
                    if storage_full_cause(exc) is None:
                        raise
                    raise self._refuse(str(storage_full_cause(exc))) from None
            elif self.free_bytes() < MIN_FREE_BYTES:
                raise self._refuse(f"{self.free_bytes() // 1024} KiB free")

    def release(self) -> None:
        """The disk is full: give the reserve back so the job's end can be stored."""
        with self._lock:
            if self._reserve.exists():
                self._reserve.unlink()
                logger.warning(
                    "data folder %s is full: reserve released to store the job's end", self.data_dir
                )
