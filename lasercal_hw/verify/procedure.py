"""``verify(request, calibration) -> VerifyReport``: the drift check on the run's own
machinery (``run.engine.open_sequencer``: fake cell, devices, recording, events, cancel;
``Sequencer.measure``: preflight, background, move-settle-dwell, centres), then the
re-fit, the identity check, the drift test, the verdict and the outputs.

The CLI (``lasercal verify``) and the daemon call this; it never prints and never asks.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from lasercal_hw.calibration.model import RANGE_CURVE_BASIS
from lasercal_hw.calibration.result import RangeOffset, WaypointResidual
from lasercal_hw.config import JobConfig, with_overrides
from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import matrix_to_euler_zyx
from lasercal_hw.models import FloatArray, RodLine
from lasercal_hw.run.cancel import CancelToken
from lasercal_hw.run.engine import MotionPlan, ProcedureReport, RunRequest, open_sequencer
from lasercal_hw.run.events import EventSink, RunEvent, Stage
from lasercal_hw.run.records import Measured, Timings, WaypointMeasurement
from lasercal_hw.run.resume import Procedure
from lasercal_hw.run.timing import visit_time_s
from lasercal_hw.run.two_pass import SecondPassRefit
from lasercal_hw.run.waypoints import job_waypoints, without_spin
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.verify.across_kind import placed_alike
from lasercal_hw.verify.active import (
    ActiveCalibration,
    load_active_calibration,
    recorded_centre_covariances,
    recorded_echo_middle_moves,
    recorded_echo_middles,
    recorded_residuals,
    repeated_poses,
    unusable_waypoints,
)
from lasercal_hw.verify.drift import DriftModel, DriftTest, predictions, run_drift_test
from lasercal_hw.verify.echo_reference import at_echo_middles
from lasercal_hw.verify.identity import IdentityCheck, check_identity, robot_calibration_check
from lasercal_hw.verify.outputs import VerifyOutcome, verify_document, write_verify_outputs
from lasercal_hw.verify.selection import Selection, VerdictAim, select_waypoints
from lasercal_hw.verify.verdict import CLI_MORE_DATA, Verdict, decide, with_time_note

MIN_MEASURED = 2


@dataclass(frozen=True)
class VerifyRequest:
    """What to check and where. ``job`` None: the job recorded with the calibration;
    ``robot_host`` None: the job's ``robot.host`` (``recorded_job``'s without a ``job``);
    ``waypoints`` None: the job's ``verify.waypoints``."""

    out_dir: Path
    job: JobConfig | None = None
    robot_host: str | None = None
    scanner_url: str | None = None
    waypoints: int | None = None
    dry_run: bool = False
    scene: Path | None = None
    #: What an inconclusive verdict advises (the CLI's options by default; a daemon gives its own).
    more_data: str = CLI_MORE_DATA


@dataclass(frozen=True)
class VerifyReport(ProcedureReport[VerifyOutcome]):
    """A finished verify: the outcome, the files, and the dry run's ground truth."""

    @property
    def verdict(self) -> Verdict:
        """ok, inconclusive, degraded or recalibrate, with the reason."""
        return self.outcome.verdict

    def document(self) -> dict[str, Any]:
        """What ``lasercal verify --json`` prints (``verify.json`` plus the file list)."""
        document = self.with_outputs(verify_document(self.outcome, ground_truth=self.ground_truth))
        document["timings"]["command_s"] = self.command_s
        return document


def verify_job(job: JobConfig, T_base_laser: FloatArray) -> JobConfig:
    """The job with the calibration as the scanner's nominal pose, so that the extraction
    looks for the rod where the calibration predicts it, and its waypoints as listed (a twist
    drill's spin before them, ``trajectory.flute_phase_deg``, is the calibration's, not verify's)."""
    T = np.asarray(T_base_laser, dtype=float)
    euler_deg = np.degrees(matrix_to_euler_zyx(T[:3, :3]))
    nominal = {"translation_m": T[:3, 3].tolist(), "euler_zyx_deg": euler_deg.tolist()}
    return without_spin(with_overrides(job, {"scanner.nominal": nominal}, source="verify job"))


def drift_model(
    T_base_laser: FloatArray,
    covariance: FloatArray,
    job: JobConfig,
    range_error: RangeOffset | None = None,
    range_offset_applied_m: float = 0.0,
    rod: RodLine | None = None,
) -> DriftModel:
    """The test's prior knowledge: the calibration, its range error curve ``range_error``
    less the ``range_offset_applied_m`` its second pass took out of every range (None: none),
    the rod it estimated (None: the job's) and the job's noise settings."""
    settings = job.verify
    curve_m = np.zeros(0) if range_error is None else np.array(range_error.coefficients_m())
    if curve_m.size:
        curve_m[0] -= range_offset_applied_m
    return DriftModel(
        T_base_laser=np.asarray(T_base_laser, dtype=float),
        covariance=np.asarray(covariance, dtype=float),
        rod=job.rod.rod_line() if rod is None else rod,
        robot_sigma_m=job.robot.position_accuracy_mm / 1000.0,
        repeatability_m=settings.repeatability_mm / 1000.0,
        false_alarm_rate=settings.false_alarm_rate,
        prior_shift_m=settings.prior_shift_mm / 1000.0,
        prior_turn_rad=float(np.radians(settings.prior_turn_deg)),
        range_curve_m=curve_m,
        range_curve_basis=RANGE_CURVE_BASIS if range_error is None else range_error.basis,
    )


def time_budget_s(active: ActiveCalibration, job: JobConfig) -> float | None:
    """``verify.max_time_fraction`` of the calibration's motion and dwell (estimated the
    same way as the verify's); None when its trajectory was not recorded or not reachable."""
    calibration_waypoints = active.waypoints()
    if active.job is None or calibration_waypoints is None:
        return None
    estimate_s = visit_time_s(active.job, calibration_waypoints)
    return None if estimate_s is None else job.verify.max_time_fraction * estimate_s


@dataclass(frozen=True)
class VerifyPlan:
    """A verify decided before anything moves: its job (the calibration as the scanner's
    nominal pose), the drift test's model, the job's waypoints, the calibration's residual
    at each of them (NaN where it has none) and the waypoints chosen."""

    job: JobConfig
    model: DriftModel
    waypoints: FloatArray
    reference: FloatArray
    selection: Selection
    #: How the calibration's second pass fitted its centres: the verify fits its own so.
    refit: SecondPassRefit
    #: A twist drill's echo middle the calibration recorded at each waypoint (``recorded_echo_middles``).
    echo_middles: FloatArray
    #: How far a plain rod's echo middle moved the calibration's centre at each waypoint
    #: (``recorded_echo_middle_moves``).
    echo_middle_moves: FloatArray


def plan_verify(
    job: JobConfig,
    T_base_laser: FloatArray,
    covariance: FloatArray,
    residuals: Sequence[WaypointResidual],
    recorded_waypoints: FloatArray | None,
    *,
    count: int | None = None,
    budget_s: float | None = None,
    range_error: RangeOffset | None = None,
    refit: SecondPassRefit | None = None,
    rod: RodLine | None = None,
    candidates: FloatArray | None = None,
) -> VerifyPlan:
    """How to check the calibration ``T_base_laser`` (with its ``covariance``, its range error
    curve ``range_error`` (None: none), its second pass's ``refit`` (None: none recorded; the
    calibrated transform, the job's rod and the raw ranges), the rod it estimated, which
    predicts the crossings (None: the job's), and its ``residuals`` at ``recorded_waypoints``,
    None: not recorded) with ``job``: ``count`` waypoints (None: the job's ``verify.waypoints``)
    chosen within ``budget_s`` among ``candidates`` (the calibration's own waypoints as its run
    recorded them; None: the job's), each weighed with the centre covariance the calibration
    recorded there."""
    checking = verify_job(job, T_base_laser)
    refit = refit or SecondPassRefit(np.asarray(T_base_laser, dtype=float), checking.rod.rod_line())
    model = replace(
        drift_model(T_base_laser, covariance, checking, range_error, refit.range_offset_m, rod),
        flutes=refit.flutes,
    )
    waypoints = job_waypoints(checking) if candidates is None else np.asarray(candidates, dtype=float)
    reference = recorded_residuals(residuals, recorded_waypoints, waypoints)
    centre_covariance, noise_covariance = recorded_centre_covariances(
        residuals, recorded_waypoints, waypoints
    )
    selection = select_waypoints(
        model,
        waypoints,
        count or checking.verify.waypoints,
        np.isfinite(reference).all(axis=1),
        time_of=lambda indices: visit_time_s(checking, waypoints[indices]),
        budget_s=budget_s,
        centre_covariance_uv_m2=centre_covariance,
        noise_covariance_uv_m2=noise_covariance,
        unusable=unusable_waypoints(residuals, recorded_waypoints, waypoints) | repeated_poses(waypoints),
        aim=VerdictAim(checking.verify.tolerance_mm * 1e-3, float(np.radians(checking.verify.tolerance_deg))),
    )
    middles = recorded_echo_middles(residuals, recorded_waypoints, waypoints)
    moves = recorded_echo_middle_moves(residuals, recorded_waypoints, waypoints)
    return VerifyPlan(checking, model, waypoints, reference, selection, refit, middles, moves)


def plan_active(
    active: ActiveCalibration, job: JobConfig, *, count: int | None = None, budget_s: float | None = None
) -> VerifyPlan:
    """``plan_verify`` for the calibration ``active`` as its ``result.json`` records it (its
    transform, covariance, residuals, waypoints, range error curve, second pass and estimated
    rod) checked with ``job``'s rod, choosing among the waypoints its run recorded where it did."""
    nominal = job.rod.rod_line()
    return plan_verify(
        job,
        active.T_base_laser,
        active.covariance,
        active.result.residuals,
        active.waypoints(),
        count=count,
        budget_s=budget_s,
        range_error=active.result.range_offset,
        refit=active.refit(nominal),
        rod=active.result.estimated_rod(nominal),
        candidates=active.run_waypoints,
    )


def recorded_job(calibration_result_path: Path) -> JobConfig:
    """The job recorded with the calibration in ``calibration_result_path``: what a verify whose
    request gives no job runs, its ``robot.host`` the robot it connects to when the request
    names none. A missing or malformed file, or one that records no job: ConfigError."""
    active = load_active_calibration(calibration_result_path)
    if active.job is None:
        raise ConfigError(f"{active.path} does not record the job it was made with, which a verify runs")
    return active.job


def verify(
    request: VerifyRequest,
    calibration_result_path: Path,
    *,
    on_event: Callable[[RunEvent], None] | None = None,
    cancel: CancelToken | None = None,
    confirm: Callable[[MotionPlan], None] | None = None,
) -> VerifyReport:
    """Check the calibration in ``calibration_result_path`` (its ``result.json``).

    Blocking, any thread. Raises what ``calibrate`` raises (InterruptedRunError on cancel,
    DeviceError, ConfigError); a changed calibration is not an error: see
    ``report.verdict``. Events: those of a run, then ``verdict``.
    """
    sink = EventSink(on_event)
    active = load_active_calibration(calibration_result_path)
    chosen_job = request.job if request.job is not None else active.job
    if chosen_job is None:
        raise ConfigError(
            f"{active.path} does not record the job it was made with: give verify that job file"
        )
    chosen_job = _scanner_job(chosen_job, active)
    budget_s = time_budget_s(active, chosen_job)
    plan = plan_active(active, chosen_job, count=request.waypoints, budget_s=budget_s)
    job, waypoints, selection = plan.job, plan.waypoints, plan.selection
    blind = f" ({selection.choice})" if selection.vouches is False else ""
    sink.emit(
        "stage",
        f"verifying {active.path} at waypoints {selection.indices} of {len(waypoints)}{blind}",
        stage=Stage.SELECT,
        waypoints=selection.indices,
        expected_std_shift_mm=selection.expected_std_shift_mm,
        expected_std_turn_deg=selection.expected_std_turn_deg,
        estimated_time_s=selection.estimated_time_s,
        choice=selection.choice,
    )
    run_request = RunRequest(
        job=job,
        out_dir=request.out_dir,
        robot_host=request.robot_host,
        scanner_url=request.scanner_url,
        dry_run=request.dry_run,
        scene=request.scene,
        waypoints=waypoints[selection.indices],
        waypoint_names=tuple(selection.indices),
        title="lasercal verify",
        procedure=Procedure.VERIFY,  # recorded: a verify's recording is not resumed
        scanner_name=active.scanner_name,  # a dry run checks that scanner of the scene
    )
    started_s = time.monotonic()
    rod = job.rod.rod_line()
    found: dict[str, Any] = {}

    def before_motion(motion: MotionPlan) -> None:
        now = motion.preflight
        identity = [
            *check_identity(active.robot, active.scanner, active.rod, now.robot, now.scanner, rod),
            robot_calibration_check(active.robot_calibration, motion.robot_calibration),
        ]
        found["identity"] = identity
        if not all(check.matches for check in identity):
            raise _OtherDevicesError()  # the verdict is known: nothing moves
        if confirm is not None:
            confirm(motion)

    try:
        with open_sequencer(
            run_request, sink, cancel or CancelToken(), before_motion
        ) as session:
            found["session"] = session
            session.recorder.write_event(
                time.time(), "verify_start", calibration=str(active.path), waypoints=selection.indices
            )
            measured = session.sequencer.measure()
            outcome = _evaluate(active, plan, measured, found["identity"], request.more_data)
            session.recorder.write_event(
                time.time(), "verify_verdict", verdict=outcome.verdict.status, reason=outcome.verdict.reason
            )
    except _OtherDevicesError:
        session = found["session"]
        verdict = decide(found["identity"], None, job.verify.tolerance_mm, job.verify.tolerance_deg)
        outcome = VerifyOutcome(
            active, job, selection, found["identity"], None, verdict, [], [], [], Timings()
        )
    outcome = replace(outcome, robot_calibration=session.robot_calibration)
    sink.emit("stage", "writing the outputs", stage=Stage.OUTPUTS)
    files = {"session": session.session_path} | write_verify_outputs(
        session.out_dir, outcome, ground_truth=session.ground_truth
    )
    report = VerifyReport(
        outcome, files, session.out_dir, session.ground_truth, session.fake_cell, time.monotonic() - started_s
    )
    sink.emit(
        "verdict",
        f"{outcome.verdict.status}: {outcome.verdict.reason}",
        verdict=outcome.verdict.status,
        reason=outcome.verdict.reason,
        calibration=str(active.path),
    )
    return report


def refit_and_test(
    plan: VerifyPlan, measurements: Sequence[WaypointMeasurement], background: AveragedScan | None
) -> tuple[DriftTest | None, list[tuple[int, str]]]:
    """The chosen waypoints' measurements (their ``index`` counts the chosen ones) fitted
    again as the calibration's second pass fitted its centres (``plan.refit``), their drift
    test (None with fewer than MIN_MEASURED), and the waypoints (index, reason) the re-fit could
    not fit again, left out of the test: their first centre is a fit of another kind than the
    calibration's centres and the model's prediction, which the second pass fitted."""
    refitted, kept = plan.refit.centres(measurements, background)
    not_refitted = {index for index, _ in kept}
    refitted = [m for m in refitted if m.index not in not_refitted]
    job_index = [plan.selection.indices[m.index] for m in refitted]
    refitted, reference, not_alike = placed_alike(
        plan.refit,
        measurements,
        refitted,
        plan.echo_middle_moves[job_index],
        plan.reference[job_index],
        background,
    )
    kept = kept + not_alike
    if len(refitted) < MIN_MEASURED:
        return None, kept
    job_index = [plan.selection.indices[m.index] for m in refitted]
    poses = np.array([m.tcp_pose for m in refitted])
    centres, reference, noise = at_echo_middles(
        plan.refit,
        refitted,
        predictions(plan.model, poses)[0],
        plan.echo_middles[job_index],
        reference,
        np.array([m.centre.dwell_noise_covariance_uv_m2() for m in refitted]),
    )
    test = run_drift_test(
        plan.model,
        job_index,
        poses,
        centres,
        np.array([m.centre.covariance_uv_m2 for m in refitted]),
        reference,
        noise,
    )
    return test, kept


def _scanner_job(job: JobConfig, active: ActiveCalibration) -> JobConfig:
    """``job`` for the calibrated scanner: a cell's job file narrowed to that scanner's job."""
    if not job.scanners:
        return job
    if active.scanner_name is None:
        raise ConfigError(
            f"{active.path} is a one-scanner calibration, but the job file describes a cell "
            f"(scanners {', '.join(job.scanners)}): give the job file it was made with"
        )
    return job.for_scanner(active.scanner_name)


class _OtherDevicesError(Exception):
    """Preflight met another scanner, robot or rod than the calibration's: stop before
    anything moves (not an error: the verdict is recalibrate)."""


def _evaluate(
    active: ActiveCalibration,
    plan: VerifyPlan,
    measured: Measured,
    identity: list[IdentityCheck],
    more_data: str,
) -> VerifyOutcome:
    """Re-fit, test and verdict for what the sequencer measured (its indices count the
    chosen waypoints; the outcome speaks of the job's waypoint numbers)."""
    job, selection, reference = plan.job, plan.selection, plan.reference
    test, not_refitted = refit_and_test(plan, measured.measurements, measured.background)
    missing = None
    if test is None:
        reasons = "; ".join(
            [f"waypoint {selection.indices[s.index]}: {s.reason}" for s in measured.skipped]
            + [f"waypoint {selection.indices[i]}: not fitted again ({reason})" for i, reason in not_refitted]
        )
        tested = len(measured.measurements) - len(not_refitted)
        missing = (
            f"the rod was found and fitted again at only {tested} of {len(selection.indices)} waypoints "
            f"where the calibration predicts it ({reasons})"
        )
    verdict = decide(identity, test, job.verify.tolerance_mm, job.verify.tolerance_deg, missing, more_data)
    outcome = VerifyOutcome(
        calibration=active,
        job=job,
        selection=selection,
        identity=identity,
        test=test,
        verdict=verdict,
        visited_by_calibration=[]
        if test is None
        else [bool(np.isfinite(reference[i]).all()) for i in test.indices],
        skipped=[(selection.indices[s.index], s.reason) for s in measured.skipped],
        not_refitted=[(selection.indices[i], reason) for i, reason in not_refitted],
        timings=measured.timings,
    )
    noted = with_time_note(verdict, outcome.time_fraction(), job.verify.max_time_fraction)
    return dataclasses.replace(outcome, verdict=noted)
