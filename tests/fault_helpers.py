"""Real faults for the daemon's fault tests: a small disk that fills (a tmpfs of a few MB,
mounted for the test; where mounting is refused, a file-size limit on the daemon process,
which fails its writes with EFBIG), and a damaged SQLite file."""

from __future__ import annotations

import contextlib
import os
import sqlite3
import subprocess
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx

from tests.daemon_helpers import read_sse

SMALL_DISK_BYTES = 3 * 1024 * 1024
FILLER_BYTES = 1_300_000
"""Written beside the data folder so a dry run fills the disk within its first waypoints;
deleting it is how the tests free space again."""


@dataclass(frozen=True)
class SmallDisk:
    """Where the daemon's data folder goes, and how the disk is made full.

    ``how`` is ``"tmpfs"`` (a real file system of ``SMALL_DISK_BYTES``: ENOSPC) or
    ``"rlimit"`` (RLIMIT_FSIZE of ``file_size_limit_bytes`` on the daemon: EFBIG)."""

    root: Path
    how: str
    file_size_limit_bytes: int | None = None

    @property
    def filler(self) -> Path:
        """The file that takes up space until a test frees it."""
        return self.root / "filler"


@contextlib.contextmanager
def small_disk(where: Path) -> Iterator[SmallDisk]:
    """A small real file system at ``where`` (unmounted at the end), or the rlimit fallback
    (also chosen by ``LASERCAL_FAULT_DISK=rlimit``, to try it where mounting works)."""
    where.mkdir(parents=True, exist_ok=True)
    if os.environ.get("LASERCAL_FAULT_DISK") == "rlimit":
        yield SmallDisk(where, "rlimit", file_size_limit_bytes=SMALL_DISK_BYTES - FILLER_BYTES)
        return
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={SMALL_DISK_BYTES}", "tmpfs", str(where)],
        capture_output=True,
        check=False,
    )
    if mounted.returncode != 0:
        yield SmallDisk(where, "rlimit", file_size_limit_bytes=SMALL_DISK_BYTES - FILLER_BYTES)
        return
    try:
        yield SmallDisk(where, "tmpfs")
    finally:
        subprocess.run(["umount", "--lazy", str(where)], check=False)


def damage_page(database: Path, page: int = 1, page_size: int = 4096) -> None:
    """Overwrite one page of a SQLite file (not its header) with garbage, as a bad sector would."""
    with database.open("r+b") as db:
        db.seek(page * page_size)
        db.write(b"\xa5" * page_size)


def truncate(database: Path) -> None:
    """``: > lasercal.sqlite3``."""
    database.write_bytes(b"")


def drop_jobs_table(database: Path) -> None:
    """A table gone (a bad manual repair)."""
    with sqlite3.connect(database) as connection:
        connection.execute("DROP TABLE jobs")


def damage_header(database: Path) -> None:
    """The first bytes overwritten: not a database any more."""
    with database.open("r+b") as handle:
        handle.write(b"not a database at all")


DAMAGES: dict[str, tuple[Callable[[Path], None], str]] = {
    "truncated": (truncate, "is empty"),
    "deleted": (Path.unlink, "is missing"),
    "damaged page": (damage_page, "rebuild"),
    "dropped table": (drop_jobs_table, "lacks the table(s) jobs"),
    "damaged header": (damage_header, "rebuild"),
}
"""Ways to lose a history database, and words the refused start must say for each."""


def child_pids(pid: int) -> list[int]:
    """The direct children of process ``pid``, started from any of its threads (Linux /proc)."""
    children: list[int] = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        children += [int(child) for child in (task / "children").read_text().split()]
    return children


def follow_to_the_end(
    client: httpx.Client, job_id: str
) -> tuple[dict[str, Any], list[tuple[int, str, dict[str, Any]]]]:
    """Follow a job's events until its stream ends; a job the loaded machine's fakes stalled
    (device_error) is resumed and followed on, up to 3 times, as an operator would."""
    followed: list[tuple[int, str, dict[str, Any]]] = []
    for _attempt in range(4):
        after = {"Last-Event-ID": str(followed[-1][0])} if followed else {}
        with client.stream("GET", f"/v1/jobs/{job_id}/events", headers=after, timeout=240.0) as stream:
            followed.extend(read_sse(stream))
        job = client.get(f"/v1/jobs/{job_id}").json()
        if job["error"] is None or job["error"]["code"] != "device_error":
            break
        client.post(f"/v1/jobs/{job_id}/resume", json={"confirm_motion": True}).raise_for_status()
    return job, followed
