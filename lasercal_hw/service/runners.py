"""The runners a job's kind dispatches to (``JobManager(runners=...)``): the shared engine
for ``calibrate`` and ``dry_run``. ``verify`` joins here once ``lasercal_hw.verify`` has its
entry point; until then the daemon answers 501 for it."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from lasercal_hw.service.jobs import RunContext, Runner, RunResult

if TYPE_CHECKING:
    from lasercal_hw.live.foxglove import FoxgloveLiveView

Devices = Callable[[], dict[str, str | None]]


def run_engine(
    ctx: RunContext, *, dry_run: bool, devices: dict[str, str | None], live: FoxgloveLiveView | None = None
) -> RunResult:
    """One calibration through ``lasercal_hw.run.engine.calibrate`` (blocking), shown in the
    Foxglove ``live`` view if there is one."""
    from lasercal_hw.run.engine import RunEvent, RunRequest, calibrate

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

    def on_event(event: RunEvent) -> None:
        ctx.on_event(event.kind, event.message, event.data)

    report = calibrate(
        request,
        on_event=live.watch(request, on_event) if live else on_event,
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


def build_runners(devices: Devices, live: FoxgloveLiveView | None = None) -> dict[str, Runner]:
    """The runners by kind; ``devices()`` gives the daemon's current robot host and scanner
    URL (``{"robot.host": ..., "scanner.url": ...}``), asked again on every start and resume
    (a restarted dry-run daemon's fake cell has a new address); ``live``: the Foxglove view."""
    return {
        "calibrate": lambda ctx: run_engine(ctx, dry_run=False, devices=devices(), live=live),
        "dry_run": lambda ctx: run_engine(ctx, dry_run=True, devices={}, live=live),
    }
