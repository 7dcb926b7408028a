"""One process at a time in a data folder: the daemon and ``--rebuild-history`` hold an OS lock
(``fcntl.flock`` on ``<data folder>/daemon.lock``) before they read or write anything else there.

The kernel releases the lock when its holder exits, however it ends (kill -9 included), so
a stale lock file never blocks a start. The file names the holder's pid, for the message a
second process gets; the lock itself, not the file, is what counts. The descriptor is not
inherited by child processes (a dry run's fake cell), so a killed daemon's children never
keep its folder.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
from pathlib import Path

from lasercal_hw.errors import ConfigError

LOCK_FILE = "daemon.lock"


class DataFolderBusyError(ConfigError):
    """Another process holds the data folder's lock."""


class DataFolderLock:
    """The data folder's lock, held from ``acquire`` until ``release`` or the process's end."""

    def __init__(self, data_dir: Path, refusal: str) -> None:
        self.path = data_dir / LOCK_FILE
        self._refusal = refusal  # what is refused and what to do, the message's end
        self._fd: int | None = None

    def acquire(self) -> DataFolderLock:
        """Take the lock (DataFolderBusyError, touching nothing, when another process holds it)."""
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o600)
        except OSError as exc:
            raise ConfigError(f"cannot open the lock file {self.path}: {exc.strerror or exc}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder_pid(fd)
            os.close(fd)
            who = f"process {holder}" if holder is not None else "another process (pid unknown)"
            raise DataFolderBusyError(
                f"the data folder {self.path.parent} is in use by {who} (a running lasercal serve "
                f"or --rebuild-history holds {self.path}); {self._refusal}"
            ) from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd
        return self

    def release(self) -> None:
        """Give the lock back (the file stays; the next holder rewrites its pid)."""
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._fd = None


def _holder_pid(fd: int) -> int | None:
    """The pid the lock file names, or None when it names none."""
    with contextlib.suppress(OSError, ValueError):
        return int(os.pread(fd, 32, 0).decode("ascii").strip())
    return None
