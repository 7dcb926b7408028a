"""From a run's measurements to its outcome: the two-pass solve, the quality gates, and the
events that say so in the recording. No motion: the sequencer measured before this runs.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from lasercal_hw.calibration.quality import evaluate_gates
from lasercal_hw.calibration.result import CalibrationResult
from lasercal_hw.config import JobConfig
from lasercal_hw.errors import InterruptedRunError
from lasercal_hw.run.cancel import CancelToken
from lasercal_hw.run.records import (
    Measured,
    Progress,
    ProgressCallback,
    RunOutcome,
    RunRecorder,
    record_event,
)
from lasercal_hw.run.two_pass import solve_two_pass


def solve_run(
    measured: Measured,
    job: JobConfig,
    recorder: RunRecorder,
    *,
    on_progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
    clock: Callable[[], float] = time.time,
) -> RunOutcome:
    """Solve what ``Sequencer.measure`` gathered, grade it, and record the solve, the verdict
    and the run's end. A cancel or Ctrl-C while solving raises InterruptedRunError (nothing
    moves any more; the recording holds every waypoint, so the run can be solved again)."""
    cancel = cancel or CancelToken()
    waypoint_count = len(measured.waypoints)
    done = len(measured.measurements) + len(measured.skipped)
    started_s = clock()

    def progress(stage: str, message: str) -> None:
        cancel.raise_if_cancelled()
        if on_progress is not None:
            step = Progress(stage, message, waypoint_count=waypoint_count, completed=done, time_left_s=0.0)
            on_progress(step)

    try:
        progress("solve", f"solving from {len(measured.measurements)} observations")
        solution = solve_two_pass(
            measured.measurements, job, measured.background,
            on_second_pass=lambda: progress("refine", "second pass: centres from the solved rod axes"),
        )
    except (KeyboardInterrupt, InterruptedRunError) as exc:
        reason = str(exc) or "Ctrl-C"
        record_event(recorder, clock(), "abort", cause="interrupted", index=None, message=reason)
        raise InterruptedRunError(
            f"run interrupted while solving ({reason}): every waypoint is recorded; "
            "solve this run again from its recording"
        ) from None
    except BaseException as exc:
        message = f"{type(exc).__name__}: {exc}"
        record_event(recorder, clock(), "abort", cause="error", index=None, message=message)
        raise
    record_event(recorder, clock(), "solve", pass_number=1, result=_summary(solution.first_pass))
    for index, reason in solution.kept_first_pass:
        record_event(recorder, clock(), "refine_kept_first_pass", index=index, reason=reason)
    second = _summary(solution.result)
    record_event(recorder, clock(), "solve", pass_number=2, result=second, refinement=solution.refinement)
    verdict = evaluate_gates(solution.result, job.quality, waypoint_count)
    for index, warning in solution.centre_warnings:
        record_event(recorder, clock(), "centre_warning", index=index, warning=warning)
    record_event(recorder, clock(), "verdict", **verdict.as_dict())
    warned = len({index for index, _ in solution.centre_warnings})
    doubt = f" ({warned} centres carry a warning: result.json run.centre_warnings)" if warned else ""
    progress("done", ("passed" if verdict.passed else "quality gate failed") + doubt)
    timings = measured.timings
    timings.wall_s += clock() - started_s
    record_event(
        recorder, clock(), "run_end",
        passed=verdict.passed,
        wall_s=timings.wall_s,
        motion_s=timings.motion_s,
        dwell_s=timings.dwell_s,
        overhead_fraction=timings.overhead_fraction,
    )
    return RunOutcome(
        preflight=measured.preflight,
        measurements=list(measured.measurements),
        skipped=list(measured.skipped),
        observations=solution.observations,
        first_pass=solution.first_pass,
        result=solution.result,
        refinement=solution.refinement,
        verdict=verdict,
        timings=timings,
        resumed_from=measured.resumed_from,
        background=measured.background,
        solve_settings=solution.settings,
        centre_warnings=solution.centre_warnings,
        refit=solution.refit,
        waypoints=measured.waypoints,
    )


def _summary(result: CalibrationResult) -> dict[str, Any]:
    return {
        "T_base_laser": result.T_base_laser,
        "rms_residual_mm": result.rms_residual_mm,
        "std_translation_mm": result.std_translation_mm,
        "std_rotation_deg": result.std_rotation_deg,
        "outliers": len(result.outliers),
    }
