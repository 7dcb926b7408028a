"""The runners a job's kind dispatches to (``JobManager(runners=...)``): the shared engine
for ``calibrate`` and ``dry_run``. ``verify`` joins here once ``lasercal_hw.verify`` has its
entry point; until then the daemon answers 501 for it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING

from lasercal_hw.config import with_overrides
from lasercal_hw.errors import ConfigError
from lasercal_hw.service.jobs import RunContext, Runner, RunResult

if TYPE_CHECKING:
    from lasercal_hw.live.foxglove import FoxgloveLiveView

Devices = Callable[[], dict[str, str | None]]


def run_engine(ctx: RunContext, *, dry_run: bool, live: FoxgloveLiveView | None = None) -> RunResult:
    """One calibration through ``lasercal_hw.run.engine.calibrate`` (blocking), shown in the
    Foxglove ``live`` view if there is one."""
    from lasercal_hw.run.engine import CancelToken, RunEvent, RunRequest, calibrate

    token = CancelToken()
    ctx.cancel.listen(token.cancel)
    request = RunRequest(
        job=ctx.job,
        out_dir=ctx.out_dir,
        dry_run=dry_run,
        scene=ctx.scene_file if dry_run else None,
        resume=ctx.resume_from,
        title=f"lasercal {'dry run' if dry_run else 'calibration'} (job {ctx.job_id})",
    )
    def on_event(e: RunEvent) -> None:
        ctx.on_event(e.kind, e.message, e.data)

    listener = live.watch(request, on_event) if live else on_event
    report = calibrate(request, on_event=listener, cancel=token, confirm=ctx.confirm)
    document = report.document()
    return RunResult(
        document=document,
        passed=bool(document["passed"]),
        verdict=document["verdict"],
        calibration_dir=report.out_dir,
    )


def build_runners(devices: Devices, live: FoxgloveLiveView | None = None) -> dict[str, Runner]:
    """The runners by kind; ``devices()`` gives the daemon's current robot host and scanner URL
    (``{"robot.host": ..., "scanner.url": ...}``), applied again on every start and resume."""

    def calibrate(ctx: RunContext) -> RunResult:
        job = with_overrides(ctx.job, devices(), source="daemon configuration")
        if job.robot.host is None:
            raise ConfigError("no robot configured: set robot_host in the daemon configuration")
        return run_engine(replace(ctx, job=job), dry_run=False, live=live)

    return {"calibrate": calibrate, "dry_run": lambda ctx: run_engine(ctx, dry_run=True, live=live)}
