"""The history rebuilt from the job folders (``lasercal serve --rebuild-history``).

Each ``jobs/<id>/`` folder holds what its job left: ``result.json`` (a finished
calibration: filed again, the job ``succeeded``) or a recording (``session.mcap``: the job
``interrupted``, resumable from it), or neither (``failed``); a verify's, ``verify.json`` (the
job ``succeeded`` with its verdict; the verify history itself is not rebuilt), or only the
recording its meta names a verify's (``interrupted``, not resumable: a verify starts anew).
What lived only in the database is lost: the request as sent, the events, the activation log
(no calibration is active afterwards), verifies, the calibrations' ids (each is filed under a
new one) and who marked one bad (none is bad afterwards; the report line says so). A database
found in the way is kept beside it, renamed.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from lasercal_hw.errors import ConfigError, LasercalError
from lasercal_hw.run.cell import CELL_FILE
from lasercal_hw.run.outputs import RESULT_FILE, read_result_file
from lasercal_hw.run.resume import Procedure, recorded_job, recorded_procedure
from lasercal_hw.service.calibrations import CalibrationHistory
from lasercal_hw.service.events import EventBus
from lasercal_hw.service.folder_lock import DataFolderLock
from lasercal_hw.service.job_record import (
    Job,
    JobError,
    JobProgress,
    JobState,
    next_step_after_stop,
    verify_verdict,
)
from lasercal_hw.service.jobs import SESSION_FILE
from lasercal_hw.service.store import DB_FILE, HistoryStore
from lasercal_hw.session.reader import read_session
from lasercal_hw.verify.outputs import VERIFY_FILE

DRY_RUN_FILES = ("dry_run_scene.toml", "request_scene.toml")


@dataclass
class RebuildReport:
    """What the rebuild found: jobs by state, calibrations filed, the old database's new name."""

    jobs: dict[str, int] = field(default_factory=dict)
    calibrations: int = 0
    old_database: Path | None = None

    def line(self, database: Path) -> str:
        """One line for the terminal."""
        states = ", ".join(f"{count} {state}" for state, count in sorted(self.jobs.items())) or "no jobs"
        kept = f"; the old database is kept as {self.old_database}" if self.old_database else ""
        lost = (
            "; the job folders record neither calibration ids nor bad marks, so every calibration is "
            "filed under a new id and none is marked bad: mark bad again those that were (lasercal "
            "remote mark-bad)"
            if self.calibrations else ""
        )
        return (
            f"rebuilt {database} from the job folders: {states}, {self.calibrations} calibrations{kept}"
            f"{lost}; no calibration is active: activate one with lasercal remote activate <id>"
        )


def job_folders(data_dir: Path) -> list[Path]:
    """The job folders in ``data_dir/jobs``, oldest name first."""
    jobs_dir = data_dir / "jobs"
    return sorted(p for p in jobs_dir.iterdir() if p.is_dir()) if jobs_dir.is_dir() else []


def _move_aside(database: Path) -> Path | None:
    if not database.exists():
        return None
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S")
    moved = database.with_name(f"{database.name}.before-rebuild-{stamp}")
    for suffix in ("", "-wal", "-shm"):
        part = database.with_name(database.name + suffix)
        if part.exists():
            part.rename(moved.with_name(moved.name + suffix))
    return moved


def _mtime_utc(path: Path) -> str:
    return datetime.fromtimestamp(path.stat().st_mtime, UTC).isoformat(timespec="milliseconds")


def _rebuilt_cell(
    folder: Path, history: CalibrationHistory, report: RebuildReport, request: dict[str, Any],
    fields: dict[str, Any],
) -> JobState:
    """A cell job's folder (docs/cell.md): every scanner's calibration filed with its scanner;
    interrupted (resumable) while a scanner has none."""
    try:
        document = json.loads((folder / CELL_FILE).read_text(encoding="utf-8"))
        names = list(document["scanners_run"])
        dry_run = bool(document.get("request", {}).get("dry_run"))
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as exc:
        fields["error"] = JobError(code="rebuilt", message=f"{CELL_FILE} unreadable: {exc}")
        return JobState.FAILED
    request |= {"kind": "dry_run" if dry_run else "calibrate", "resolved_job": document.get("job")}
    filed = {}
    for name in names:
        result = folder / name / RESULT_FILE
        if result.exists():
            made_utc = _mtime_utc(result)
            filed[name] = history.record(folder.name, result.parent, dry_run, made_utc, scanner=name)
    report.calibrations += len(filed)
    if filed:
        fields["calibration_id"] = next(iter(filed.values()))
    if len(filed) == len(names):
        return JobState.SUCCEEDED
    fields["error"] = JobError(
        code="interrupted", message=f"rebuilt from its folder; {next_step_after_stop(request['kind'])}"
    )
    return JobState.INTERRUPTED


def _rebuilt_verify(verify_file: Path, fields: dict[str, Any]) -> JobState:
    """A finished verify's job (its recording beside is the verify's, not a calibration to resume):
    ``succeeded`` with the verdict its ``verify.json`` gives, ``failed`` where that is unreadable."""
    try:
        fields["verdict"] = verify_verdict(json.loads(verify_file.read_text(encoding="utf-8")))
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError) as exc:
        fields["error"] = JobError(code="rebuilt", message=f"{VERIFY_FILE} unreadable: {exc}")
        return JobState.FAILED
    return JobState.SUCCEEDED


def _rebuilt_job(folder: Path, history: CalibrationHistory, report: RebuildReport) -> Job:
    """The job row a folder tells of (filing its calibration, if it has one)."""
    dry_run = any((folder / name).exists() for name in DRY_RUN_FILES)
    request: dict[str, Any] = {"kind": "dry_run" if dry_run else "calibrate", "rebuilt_from": str(folder)}
    fields: dict[str, Any] = {}
    result, session = folder / RESULT_FILE, folder / SESSION_FILE
    if (folder / CELL_FILE).exists():
        state = _rebuilt_cell(folder, history, report, request, fields)
    elif result.exists():
        try:
            read = read_result_file(result)
            fields["calibration_id"] = history.record(folder.name, folder, dry_run, _mtime_utc(result))
            fields["verdict"] = read.verdict
            state = JobState.SUCCEEDED
            report.calibrations += 1
        except LasercalError as exc:
            state, fields["error"] = JobState.FAILED, JobError(code="rebuilt", message=str(exc))
    elif (folder / VERIFY_FILE).exists():
        request["kind"] = "verify"
        state = _rebuilt_verify(folder / VERIFY_FILE, fields)
    elif session.exists():
        try:
            recording = read_session(session, include_scans=False)
            job, _waypoints = recorded_job(recording)
            request["resolved_job"] = job.model_dump(mode="json")
            state = JobState.INTERRUPTED
            if recorded_procedure(recording) is Procedure.VERIFY:
                request["kind"] = "verify"
            next_step = next_step_after_stop(request["kind"])
            fields["error"] = JobError(code="interrupted", message=f"rebuilt from its recording; {next_step}")
        except LasercalError as exc:
            state, fields["error"] = (
                JobState.FAILED,
                JobError(code="rebuilt", message=f"recording unreadable: {exc}"),
            )
    else:
        state = JobState.FAILED
        fields["error"] = JobError(code="rebuilt", message="the job left no recording and no result")
    report.jobs[state.value] = report.jobs.get(state.value, 0) + 1
    created = _mtime_utc(folder)
    return Job(
        id=folder.name,
        kind=request["kind"],
        state=state,
        created_utc=created,
        finished_utc=created,
        request=request,
        progress=JobProgress(message="rebuilt from the job folder"),
        out_dir=str(folder),
        **fields,
    )


def rebuild_history(data_dir: Path) -> RebuildReport:
    """A new history database from ``data_dir``'s job folders (the old one kept, renamed).
    Refused (ConfigError, nothing touched) when the folder does not exist or another process,
    a running daemon, holds it."""
    if not data_dir.is_dir():
        raise ConfigError(
            f"the data folder {data_dir} does not exist: nothing to rebuild; give the daemon's data "
            "folder with --data-dir (or data_dir in the --config file)"
        )
    lock = DataFolderLock(
        data_dir, "refusing to rebuild the history under a running daemon: stop the daemon first"
    ).acquire()
    try:
        database = data_dir / DB_FILE
        report = RebuildReport(old_database=_move_aside(database))
        store = HistoryStore(database)
        try:
            history = CalibrationHistory(store, EventBus(store))
            for folder in job_folders(data_dir):
                store.insert_job(_rebuilt_job(folder, history, report).as_json())
        finally:
            store.close()
    finally:
        lock.release()
    return report
