"""The runners a job's kind dispatches to (``JobManager(runners=...)``): the shared engine
for ``calibrate`` and ``dry_run``, ``lasercal_hw.verify`` for ``verify`` (against the active
calibration). The job's devices reach the library once, on its request."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from lasercal_hw.config import DEFAULT_SCANNER_NAME
from lasercal_hw.errors import ConfigError
from lasercal_hw.service.job_record import verify_verdict
from lasercal_hw.service.job_request import DAEMON_VERIFY_JOB, nothing_to_verify
from lasercal_hw.service.jobs import RunContext, Runner, RunResult
from lasercal_hw.service.store import utc_now

if TYPE_CHECKING:
    from lasercal_hw.live.foxglove import FoxgloveLiveView

#: ``folder(calibration_id)`` -> the folder of that calibration in the history, or None.
CalibrationFolder = Callable[[str], Path | None]


def run_engine(ctx: RunContext, *, dry_run: bool, live: FoxgloveLiveView | None = None) -> RunResult:
    """One calibration through ``lasercal_hw.run.engine.calibrate`` (blocking), shown in the
    Foxglove ``live`` view if there is one."""
    from lasercal_hw.run.engine import RunRequest, calibrate

    if ctx.job.scanners:
        return _run_cell(ctx, dry_run=dry_run, live=live)
    request = RunRequest(
        job=ctx.job,
        out_dir=ctx.out_dir,
        robot_host=ctx.devices.robot_host,
        scanner_url=ctx.devices.scanner_url,
        dry_run=dry_run,
        scene=ctx.scene_file if dry_run else None,
        resume=ctx.resume_from,
        title=f"lasercal {'dry run' if dry_run else 'calibration'} (job {ctx.job_id})",
    )
    report = calibrate(
        request,
        on_event=live.watch(request, ctx.on_event) if live else ctx.on_event,
        cancel=ctx.cancel,
        confirm=ctx.confirm,
    )
    document = report.document()
    return RunResult(
        document=document,
        passed=bool(document["passed"]),
        verdict=document["verdict"],
        calibration_dir=report.out_dir,
    )


def _run_cell(ctx: RunContext, *, dry_run: bool, live: FoxgloveLiveView | None) -> RunResult:
    """A cell job (``[scanners.NAME]``): every scanner through ``run/cell.calibrate_cell``, each
    scanner's calibration filed on its own, all shown in the Foxglove ``live`` view if there is
    one; a resumed one continues the job's folder."""
    from lasercal_hw.run.cell import CellRunRequest, calibrate_cell

    request = CellRunRequest(
        job=ctx.devices.applied_to(ctx.job),  # each scanner at daemon.toml's [scanners.NAME] url
        out_dir=ctx.out_dir,
        robot_host=ctx.devices.robot_host,
        dry_run=dry_run,
        scene=ctx.scene_file if dry_run else None,
        resume=ctx.out_dir if ctx.resume_from is not None else None,
        title=f"lasercal {'dry run' if dry_run else 'calibration'} (job {ctx.job_id})",
    )
    on_event = live.watch_cell(request, ctx.on_event) if live else ctx.on_event
    report = calibrate_cell(request, on_event=on_event, cancel=ctx.cancel, confirm=ctx.confirm)
    document = report.document()
    return RunResult(
        document=document,
        passed=report.passed,
        verdict={"passed": report.passed,
                 "scanners": {name: entry["passed"] for name, entry in document["scanners"].items()}},
        calibration_dirs={name: outcome.result_path.parent for name, outcome in report.scanners.items()},
    )


DAEMON_MORE_DATA = (
    f"{DAEMON_VERIFY_JOB}, so calibrate again with a job whose verify.waypoints (up to 20) or dwell_s "
    "is larger, or run 'lasercal verify' on the cell with more waypoints"
)
"""What an inconclusive verify advises here: a verify job takes no waypoint count or dwell of its own."""


def run_verify(ctx: RunContext, *, folder_of: CalibrationFolder) -> RunResult:
    """Check the calibration that was active when the verify was requested
    (``ctx.calibration_id``; ``lasercal_hw.verify``) with the job recorded with it; the result is
    filed in the verify history with the calibration it checked."""
    from lasercal_hw.run.cell import events_of_scanner
    from lasercal_hw.run.outputs import RESULT_FILE, read_result_file
    from lasercal_hw.verify.procedure import VerifyRequest, verify

    calibration_id = ctx.calibration_id
    if calibration_id is None:
        raise ConfigError(nothing_to_verify(ctx.scanner))
    folder = folder_of(calibration_id)
    if folder is None:
        raise ConfigError(
            f"the calibration {calibration_id} this verify was asked to check is no longer in the "
            "history: request the verify again to check the calibration active now"
        )
    named = dict(ctx.devices.scanner_urls)
    scanner_name = read_result_file(folder / RESULT_FILE).scanner_name
    # a cell scanner at daemon.toml's [scanners.NAME] url, else the recorded job's; one scanner at scanner_url
    scanner_url = named.get(scanner_name) if scanner_name is not None else ctx.devices.scanner_url
    report = verify(
        VerifyRequest(
            out_dir=ctx.out_dir,
            robot_host=ctx.devices.robot_host,
            scanner_url=scanner_url,
            more_data=DAEMON_MORE_DATA,
        ),
        folder / RESULT_FILE,
        # a cell scanner's events name it, as its calibration's did
        on_event=ctx.on_event if scanner_name is None else events_of_scanner(ctx.on_event, scanner_name),
        cancel=ctx.cancel,
        confirm=ctx.confirm,
    )
    document = report.document()
    correction = (document.get("test") or {}).get("correction") or {}
    summary = {
        "created_utc": utc_now(),
        "calibration_id": calibration_id,
        "scanner": scanner_name or DEFAULT_SCANNER_NAME,
        "verdict": document["verdict"],
        "reason": document["reason"],
        "shift_translation_mm": correction.get("shift_mm"),
        "shift_rotation_deg": correction.get("turn_deg"),
        "shift_std_translation_mm": correction.get("std_shift_mm"),
        "shift_std_rotation_deg": correction.get("std_turn_deg"),
        "out_dir": str(report.out_dir),
        "document": document,
    }
    verdict = verify_verdict(document)
    return RunResult(document=document, passed=verdict["passed"], verdict=verdict, verify=summary)


def build_runners(folder_of: CalibrationFolder, live: FoxgloveLiveView | None = None) -> dict[str, Runner]:
    """The runners by kind; ``folder_of(id)`` gives a calibration's folder, ``live`` is the
    Foxglove view."""
    return {
        "calibrate": lambda ctx: run_engine(ctx, dry_run=False, live=live),
        "dry_run": lambda ctx: run_engine(ctx, dry_run=True, live=live),
        "verify": lambda ctx: run_verify(ctx, folder_of=folder_of),
    }
