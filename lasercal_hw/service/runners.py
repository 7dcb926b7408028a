"""The runners a job's kind dispatches to (``JobManager(runners=...)``): the shared engine
for ``calibrate`` and ``dry_run``. ``verify`` joins here once ``lasercal_hw.verify`` has its
entry point; until then the daemon answers 501 for it."""

from __future__ import annotations

from collections.abc import Callable

from lasercal_hw.service.jobs import RunContext, Runner, RunResult

Devices = Callable[[], dict[str, str | None]]


def run_engine(ctx: RunContext, *, dry_run: bool, devices: dict[str, str | None]) -> RunResult:
    """One calibration through ``lasercal_hw.run.engine.calibrate`` (blocking)."""
    from lasercal_hw.run.engine import RunRequest, calibrate

    request = RunRequest(
        job=ctx.job,
        out_dir=ctx.out_dir,
        robot_host=devices.get("robot.host"),
        scanner_url=devices.get("scanner.url"),
        dry_run=dry_run,
        scene=ctx.scene_file if dry_run else None,
        resume=ctx.resume_from,
        title=f"lasercal {'dry run' if dry_run else 'calibration'} (job {ctx.job_id})",
    )
    report = calibrate(
        request,
        on_event=lambda event: ctx.on_event(event.kind, event.message, event.data),
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


def build_runners(devices: Devices) -> dict[str, Runner]:
    """The runners by kind; ``devices()`` gives the daemon's current robot host and scanner
    URL (``{"robot.host": ..., "scanner.url": ...}``), asked again on every start and resume
    (a restarted dry-run daemon's fake cell has a new address)."""
    return {
        "calibrate": lambda ctx: run_engine(ctx, dry_run=False, devices=devices()),
        "dry_run": lambda ctx: run_engine(ctx, dry_run=True, devices={}),
    }
