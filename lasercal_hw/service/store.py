"""The daemon's history: jobs, their events, calibrations, activations and verifies in one
SQLite file (standard library ``sqlite3``, WAL, ``PRAGMA user_version`` as schema version).

Rows are only ever added or, for a job, updated in place; a calibration is never
overwritten and the active one is the newest activation. Every write is one transaction,
so a kill at any moment leaves the previous state readable.
"""

from __future__ import annotations

import json
import secrets
import sqlite3
import threading
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from lasercal_hw.config import DEFAULT_SCANNER_NAME
from lasercal_hw.errors import ConfigError
from lasercal_hw.service.errors import HistoryUnavailableError, StorageFullError
from lasercal_hw.service.job_record import UNFINISHED_STATES, next_step_after_stop

SCHEMA_VERSION = 3
DB_FILE = "lasercal.sqlite3"
_JSON_COLUMNS = ("request", "progress", "verdict", "error", "document")

_SCHEMA_V1 = """
CREATE TABLE jobs (
    id TEXT PRIMARY KEY, kind TEXT NOT NULL, state TEXT NOT NULL,
    created_utc TEXT NOT NULL, started_utc TEXT, finished_utc TEXT,
    request TEXT NOT NULL, progress TEXT NOT NULL, verdict TEXT, error TEXT,
    calibration_id TEXT, verify_id TEXT, out_dir TEXT NOT NULL, document TEXT
);
CREATE TABLE events (
    id INTEGER PRIMARY KEY AUTOINCREMENT, job_id TEXT, kind TEXT NOT NULL,
    data TEXT NOT NULL, time_utc TEXT NOT NULL
);
CREATE INDEX events_job ON events (job_id, id);
CREATE TABLE calibrations (
    id TEXT PRIMARY KEY, created_utc TEXT NOT NULL, job_id TEXT, dry_run INTEGER NOT NULL,
    passed INTEGER NOT NULL, summary TEXT NOT NULL, dir TEXT NOT NULL
);
CREATE TABLE activations (
    id INTEGER PRIMARY KEY AUTOINCREMENT, calibration_id TEXT NOT NULL REFERENCES calibrations (id),
    time_utc TEXT NOT NULL, reason TEXT NOT NULL
);
CREATE TABLE verifies (
    id TEXT PRIMARY KEY, created_utc TEXT NOT NULL, calibration_id TEXT, job_id TEXT,
    document TEXT NOT NULL
);
"""
# Version 2 (issue 22): the robot's kinematics checksum a calibration was made with, and
# who marked a calibration bad, when and why (a bad one is never active).
_SCHEMA_V2 = """
ALTER TABLE calibrations ADD COLUMN robot_calibration_checksum TEXT;
ALTER TABLE calibrations ADD COLUMN bad_utc TEXT;
ALTER TABLE calibrations ADD COLUMN bad_by TEXT;
ALTER TABLE calibrations ADD COLUMN bad_reason TEXT
"""
#: Version 3 (issue 22): each calibration is of one of the cell's scanners (docs/cell.md); the
#: calibrations of a one-scanner daemon, and all those filed before, are of the scanner "default".
_SCANNER_V3 = f"ALTER TABLE calibrations ADD COLUMN scanner TEXT NOT NULL DEFAULT '{DEFAULT_SCANNER_NAME}'"
_MIGRATIONS = {1: _SCHEMA_V1, 2: _SCHEMA_V2, 3: _SCANNER_V3}
TABLES = ("jobs", "events", "calibrations", "activations", "verifies")
REBUILD_HINT = "lasercal serve --rebuild-history (docs/daemon.md, Crash safety)"


def utc_now() -> str:
    """The current time, ISO 8601 in UTC."""
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def new_id(prefix: str) -> str:
    """A sortable, unique id: ``<prefix>-<UTC time>-<random hex>``."""
    return f"{prefix}-{datetime.now(UTC).strftime('%Y%m%dT%H%M%S')}-{secrets.token_hex(3)}"


class HistoryStore:
    """One SQLite file shared by the daemon's threads (calls are serialised by a lock)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            self._db = sqlite3.connect(path, check_same_thread=False, isolation_level=None, timeout=10.0)
            self._db.row_factory = sqlite3.Row
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.execute("PRAGMA foreign_keys=ON")
            self._check_integrity()
            self._migrate()
            self._check_tables()
        except sqlite3.DatabaseError as exc:
            if getattr(exc, "sqlite_errorcode", None) == sqlite3.SQLITE_FULL:
                raise ConfigError(
                    f"cannot open the history database {path}: its folder is full; free some space there "
                    "and start again"
                ) from None
            raise ConfigError(
                f"cannot open the history database {path}: {exc}; rebuild it from the job folders with "
                f"{REBUILD_HINT}"
            ) from None
        self._lock = threading.Lock()

    def _check_integrity(self) -> None:
        """``PRAGMA integrity_check``: a damaged page is found at start, not by a request later."""
        problems = [str(row[0]) for row in self._db.execute("PRAGMA integrity_check(5)").fetchall()]
        if problems != ["ok"]:
            raise ConfigError(
                f"the history database {self.path} is damaged ({'; '.join(problems)[:300]}): rebuild it "
                f"from the job folders with {REBUILD_HINT}"
            )

    def _check_tables(self) -> None:
        rows = self._db.execute("SELECT name FROM sqlite_master WHERE type = 'table'").fetchall()
        missing = sorted(set(TABLES) - {str(row[0]) for row in rows})
        if missing:
            raise ConfigError(
                f"the history database {self.path} lacks the table(s) {', '.join(missing)}: rebuild it "
                f"from the job folders with {REBUILD_HINT}"
            )

    def _backup(self, version: int) -> Path:
        """A copy of the database as it is, before migrating it from ``version``."""
        backup_path = self.path.with_name(f"{self.path.name}.v{version}.bak")
        target = sqlite3.connect(backup_path)
        try:
            self._db.backup(target)
        finally:
            target.close()
        return backup_path

    def _migrate(self) -> None:
        version = int(self._db.execute("PRAGMA user_version").fetchone()[0])
        if version > SCHEMA_VERSION:
            raise ConfigError(
                f"{self.path} has schema version {version}, newer than this lasercal "
                f"({SCHEMA_VERSION}); upgrade lasercal"
            )
        if 0 < version < SCHEMA_VERSION:
            self._backup(version)
        for target in range(version + 1, SCHEMA_VERSION + 1):
            self._db.execute("BEGIN IMMEDIATE")
            try:
                for statement in _MIGRATIONS[target].split(";"):
                    if statement.strip():
                        self._db.execute(statement)
                self._db.execute(f"PRAGMA user_version = {target}")
                self._db.execute("COMMIT")
            except BaseException:
                self._db.execute("ROLLBACK")
                raise

    def close(self) -> None:
        """Close the database (a checkpoint folds the WAL back into the file)."""
        with self._lock:
            self._db.close()

    def _execute(self, sql: str, params: tuple[Any, ...] = ()) -> sqlite3.Cursor:
        with self._lock:
            try:
                return self._db.execute(sql, params)
            except sqlite3.DatabaseError as exc:
                raise self._problem(exc) from exc

    def _query(self, sql: str, params: tuple[Any, ...] = ()) -> list[sqlite3.Row]:
        with self._lock:
            try:
                return self._db.execute(sql, params).fetchall()
            except sqlite3.DatabaseError as exc:
                raise self._problem(exc) from exc

    def _problem(self, exc: sqlite3.DatabaseError) -> StorageFullError | HistoryUnavailableError:
        """The service's error for a failed statement: the disk is full, or the file is damaged."""
        if getattr(exc, "sqlite_errorcode", None) == sqlite3.SQLITE_FULL:
            return StorageFullError(
                f"the history database {self.path} cannot grow: its folder is full ({exc}); free some "
                "space there, then try again",
                {"data_dir": str(self.path.parent), "cause": "the history database cannot grow"},
            )
        return HistoryUnavailableError(
            f"the history database {self.path} cannot be read ({exc}): stop the daemon and rebuild it "
            f"with {REBUILD_HINT}",
            {"database": str(self.path)},
        )

    # -- jobs ------------------------------------------------------------------------------------

    def insert_job(self, job: dict[str, Any]) -> None:
        """Add a new job row."""
        columns = list(job)
        values = tuple(json.dumps(job[c]) if c in _JSON_COLUMNS else job[c] for c in columns)
        self._execute(
            f"INSERT INTO jobs ({', '.join(columns)}) VALUES ({', '.join('?' * len(columns))})", values
        )

    def update_job(self, job_id: str, **fields: Any) -> None:
        """Change some fields of a job."""
        assignments = ", ".join(f"{name} = ?" for name in fields)
        values = tuple(json.dumps(v) if k in _JSON_COLUMNS else v for k, v in fields.items())
        self._execute(f"UPDATE jobs SET {assignments} WHERE id = ?", (*values, job_id))

    def job(self, job_id: str) -> dict[str, Any] | None:
        """One job as a dict, or None."""
        rows = self._query("SELECT * FROM jobs WHERE id = ?", (job_id,))
        return _job_dict(rows[0]) if rows else None

    def jobs(self, limit: int = 100) -> list[dict[str, Any]]:
        """The newest jobs first."""
        return [
            _job_dict(row)
            for row in self._query("SELECT * FROM jobs ORDER BY created_utc DESC, id DESC LIMIT ?", (limit,))
        ]

    def mark_unfinished_interrupted(self) -> list[str]:
        """After a crash: every job left in a running state becomes ``interrupted``."""
        placeholders = ", ".join("?" * len(UNFINISHED_STATES))
        query = f"SELECT id, kind FROM jobs WHERE state IN ({placeholders})"
        ids = [(row["id"], row["kind"]) for row in self._query(query, UNFINISHED_STATES)]
        for job_id, kind in ids:
            next_step = next_step_after_stop(kind)
            error = json.dumps(
                {"code": "interrupted", "message": f"the daemon stopped during this job; {next_step}"}
            )
            self._execute(
                "UPDATE jobs SET state = 'interrupted', finished_utc = ?, error = ? WHERE id = ?",
                (utc_now(), error, job_id),
            )
        return [job_id for job_id, _kind in ids]

    # -- events ----------------------------------------------------------------------------------

    def add_event(self, job_id: str | None, kind: str, data: dict[str, Any], time_utc: str) -> int:
        """Store one event; returns its id (increasing across restarts)."""
        cursor = self._execute(
            "INSERT INTO events (job_id, kind, data, time_utc) VALUES (?, ?, ?, ?)",
            (job_id, kind, json.dumps(data, allow_nan=False), time_utc),
        )
        return int(cursor.lastrowid or 0)

    def events_after(
        self, after_id: int, job_id: str | None = None, limit: int = 500
    ) -> list[tuple[int, str, str]]:
        """``(id, kind, data JSON)`` of stored events after ``after_id`` (of one job, or all)."""
        if job_id is None:
            rows = self._query(
                "SELECT id, kind, data FROM events WHERE id > ? ORDER BY id LIMIT ?", (after_id, limit)
            )
        else:
            rows = self._query(
                "SELECT id, kind, data FROM events WHERE job_id = ? AND id > ? ORDER BY id LIMIT ?",
                (job_id, after_id, limit),
            )
        return [(int(r["id"]), str(r["kind"]), str(r["data"])) for r in rows]

    def latest_event_id(self) -> int:
        """The newest stored event's id (0: none)."""
        rows = self._query("SELECT COALESCE(MAX(id), 0) AS id FROM events", ())
        return int(rows[0]["id"])

    def event_id_before(self, time_utc: str) -> int:
        """The id of the newest event stored before ``time_utc`` (ISO 8601 as ``utc_now``)."""
        rows = self._query("SELECT COALESCE(MAX(id), 0) AS id FROM events WHERE time_utc < ?", (time_utc,))
        return int(rows[0]["id"])

    def prune_events(self, keep: int) -> None:
        """Keep only the newest ``keep`` events, and no scans (older daemons stored them)."""
        self._execute(
            "DELETE FROM events WHERE kind = 'scan' OR id <= (SELECT COALESCE(MAX(id), 0) FROM events) - ?",
            (keep,),
        )

    # -- calibrations ----------------------------------------------------------------------------

    def add_calibration(
        self,
        calibration_id: str,
        job_id: str | None,
        dry_run: bool,
        passed: bool,
        summary: dict[str, Any],
        directory: Path,
        scanner: str = DEFAULT_SCANNER_NAME,
    ) -> None:
        """Store a finished calibration of ``scanner`` (never replaced); ``robot_calibration_checksum``
        is the robot's kinematics checksum it was made with (None: unknown)."""
        robot_calibration = (summary.get("devices") or {}).get("robot_calibration") or {}
        self._execute(
            "INSERT INTO calibrations (id, created_utc, job_id, dry_run, passed, summary, dir, "
            "robot_calibration_checksum, scanner) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
            (
                calibration_id,
                summary["created_utc"],
                job_id,
                int(dry_run),
                int(passed),
                json.dumps(summary, allow_nan=False),
                str(directory),
                robot_calibration.get("checksum"),
                scanner,
            ),
        )

    def calibration(self, calibration_id: str) -> tuple[dict[str, Any], Path] | None:
        """A calibration's stored summary (with its ``scanner`` and ``bad``: who marked it bad,
        when and why, or None) and folder, or None."""
        rows = self._query(
            f"SELECT {_CALIBRATION_COLUMNS}, dir FROM calibrations WHERE id = ?", (calibration_id,)
        )
        return (_calibration_dict(rows[0]), Path(rows[0]["dir"])) if rows else None

    def calibrations(self, scanner: str | None = None) -> list[dict[str, Any]]:
        """Every calibration's stored summary (of ``scanner``, or of all; with its scanner and
        ``bad``), newest first."""
        where, params = ("WHERE scanner = ?", (scanner,)) if scanner is not None else ("", ())
        return [
            _calibration_dict(r)
            for r in self._query(
                f"SELECT {_CALIBRATION_COLUMNS} FROM calibrations {where} ORDER BY created_utc DESC, id DESC",
                params,
            )
        ]

    def job_calibration_id(self, job_id: str, scanner: str) -> str | None:
        """The calibration of ``scanner`` a job filed, or None (a cell job files each
        scanner's once, as it finishes)."""
        rows = self._query(
            "SELECT id FROM calibrations WHERE job_id = ? AND scanner = ? ORDER BY created_utc LIMIT 1",
            (job_id, scanner),
        )
        return str(rows[0]["id"]) if rows else None

    def mark_bad(self, calibration_id: str, by: str, reason: str) -> str:
        """Record that ``by`` found the calibration bad, and why; returns the time."""
        time_utc = utc_now()
        self._execute(
            "UPDATE calibrations SET bad_utc = ?, bad_by = ?, bad_reason = ? WHERE id = ?",
            (time_utc, by, reason, calibration_id),
        )
        return time_utc

    def activate(self, calibration_id: str, reason: str) -> None:
        """Record an activation: the calibration becomes the active one."""
        self._execute(
            "INSERT INTO activations (calibration_id, time_utc, reason) VALUES (?, ?, ?)",
            (calibration_id, utc_now(), reason),
        )

    def active_calibration_id(self, scanner: str | None = None) -> str | None:
        """The id of the newest activation's calibration (of ``scanner``; None: of any scanner,
        a one-scanner daemon's one); None when there is none or it was marked bad since
        (marking the active one bad deactivates it)."""
        where, params = ("WHERE c.scanner = ? ", (scanner,)) if scanner is not None else ("", ())
        rows = self._query(
            "SELECT a.calibration_id, c.bad_utc FROM activations a "
            f"JOIN calibrations c ON c.id = a.calibration_id {where}ORDER BY a.id DESC LIMIT 1",
            params,
        )
        return str(rows[0]["calibration_id"]) if rows and rows[0]["bad_utc"] is None else None

    def active_calibration(self, scanner: str | None = None) -> tuple[str, Path] | None:
        """The active calibration's (of ``scanner``, as ``active_calibration_id``) id and folder,
        or None."""
        calibration_id = self.active_calibration_id(scanner)
        found = self.calibration(calibration_id) if calibration_id is not None else None
        return (calibration_id, found[1]) if calibration_id is not None and found is not None else None

    def activations(self) -> list[dict[str, Any]]:
        """The activation log, newest first."""
        return [dict(r) for r in self._query("SELECT * FROM activations ORDER BY id DESC")]

    # -- verifies --------------------------------------------------------------------------------

    def add_verify(self, verify_id: str, job_id: str | None, document: dict[str, Any]) -> None:
        """Store a verify result."""
        self._execute(
            "INSERT INTO verifies (id, created_utc, calibration_id, job_id, document) VALUES (?, ?, ?, ?, ?)",
            (
                verify_id,
                document["created_utc"],
                document.get("calibration_id"),
                job_id,
                json.dumps(document, allow_nan=False),
            ),
        )

    def verifies(self) -> list[dict[str, Any]]:
        """Every verify document, newest first."""
        return [
            json.loads(r["document"])
            for r in self._query("SELECT document FROM verifies ORDER BY created_utc DESC, id DESC")
        ]


_CALIBRATION_COLUMNS = "summary, scanner, bad_utc, bad_by, bad_reason"


def _calibration_dict(row: sqlite3.Row) -> dict[str, Any]:
    summary: dict[str, Any] = json.loads(row["summary"]) | {"scanner": row["scanner"]}
    if row["bad_utc"] is None:
        return summary | {"bad": None}
    return summary | {"bad": {"time_utc": row["bad_utc"], "by": row["bad_by"], "reason": row["bad_reason"]}}


def _job_dict(row: sqlite3.Row) -> dict[str, Any]:
    job = dict(row)
    for column in _JSON_COLUMNS:
        if job[column] is not None:
            job[column] = json.loads(job[column])
    return job
