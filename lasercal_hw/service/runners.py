"""The runners a job's kind dispatches to (``JobManager(runners=...)``): the shared engine
for ``calibrate`` and ``dry_run``. ``verify`` joins here once ``lasercal_hw.verify`` has its
entry point; until then the daemon answers 501 for it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

from lasercal_hw.config import with_overrides
from lasercal_hw.errors import ConfigError
from lasercal_hw.service.jobs import RunContext, Runner, RunResult

Devices = Callable[[], dict[str, str | None]]


def run_engine(ctx: RunContext, *, dry_run: bool) -> RunResult:
    """One calibration through ``lasercal_hw.run.engine.calibrate`` (blocking)."""
    from lasercal_hw.run.engine import CancelToken, RunRequest, calibrate

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
    report = calibrate(
        request, on_event=lambda e: ctx.on_event(e.kind, e.message, e.data), cancel=token, confirm=ctx.confirm
    )
    document = report.document()
    return RunResult(
        document=document,
        passed=bool(document["passed"]),
        verdict=document["verdict"],
        calibration_dir=report.out_dir,
    )


def build_runners(devices: Devices) -> dict[str, Runner]:
    """The runners by kind; ``devices()`` gives the daemon's current robot host and scanner URL
    (``{"robot.host": ..., "scanner.url": ...}``), applied again on every start and resume."""

    def calibrate(ctx: RunContext) -> RunResult:
        job = with_overrides(ctx.job, devices(), source="daemon configuration")
        if job.robot.host is None:
            raise ConfigError("no robot configured: set robot_host in the daemon configuration")
        return run_engine(replace(ctx, job=job), dry_run=False)

    return {"calibrate": calibrate, "dry_run": lambda ctx: run_engine(ctx, dry_run=True)}
