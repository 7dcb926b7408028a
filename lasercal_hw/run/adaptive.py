"""The adaptive run (``trajectory.adaptive``, ``lasercal run --adaptive``): a short design
robust to the rough pose's uncertainty, a solve, the rest designed from that estimate, and
one final solve over every waypoint.

The first design (``first_waypoints`` from ``scanner.nominal`` and ``pose_uncertainty``) is
what the run starts with: its waypoints are the run's recorded waypoints. Once they are
measured, the second design adds ``design_waypoints - first_waypoints`` waypoints around the
estimate (its uncertainty: three times the estimate's std, at least 5 mm and 0.5 deg),
scoring them together with what the first part already measured. The recording gets one
``trajectory_design`` event per design (phase, first index, waypoints, the pose it was
designed from, predicted std), so ``lasercal run --resume`` continues with both parts and
``lasercal solve session.mcap`` solves all observations as the live run's final solve did.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

import numpy as np

from lasercal_hw.calibration.model import extended_fisher_information
from lasercal_hw.config import JobConfig
from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import pose_to_matrix
from lasercal_hw.models import FloatArray
from lasercal_hw.run.cancel import CancelToken
from lasercal_hw.run.devices import Robot, Scanner
from lasercal_hw.run.outcome import solve_run
from lasercal_hw.run.records import ProgressCallback, ResumeState, RunOutcome, RunRecorder
from lasercal_hw.run.resume import DESIGN_EVENT
from lasercal_hw.run.sequencer import Sequencer
from lasercal_hw.ur_kinematics import URModel, inverse_kinematics_branches, robot_model
from trajectories.candidates import PoseUncertainty
from trajectories.design import Design, design, information_blocks, request_for_job, visited_crossings

#: The second design trusts the first estimate to this many of its std ...
ESTIMATE_SIGMAS = 3.0
#: ... but never closer than this.
LEAST_UNCERTAINTY = PoseUncertainty(translation_m=0.005, rotation_deg=0.5)


def design_model(job: JobConfig) -> URModel:
    """The offline kinematics both designs use: the job's ``robot.model``, else the UR5."""
    return robot_model(job.robot.model or "ur5")


def first_design(job: JobConfig) -> Design:
    """The short, robust first part, from the job's rough scanner pose."""
    nominal = job.scanner.nominal
    if nominal is None:
        raise ConfigError(
            "an adaptive run designs its waypoints from the scanner's rough pose: set [scanner.nominal] "
            "translation_m and euler_zyx_deg in the job (a tape measure is enough) and "
            "trajectory.pose_uncertainty = [metres, degrees] to say how rough it is"
        )
    request = request_for_job(
        job,
        nominal.matrix(),
        design_model(job),
        uncertainty=PoseUncertainty(*job.trajectory.pose_uncertainty),
        waypoints=job.trajectory.first_waypoints,
    )
    result = design(request, extended_fisher_information)
    if len(result.waypoints) < job.trajectory.first_waypoints:
        raise ConfigError(
            f"the adaptive run's first design found {len(result.waypoints)} of "
            f"{job.trajectory.first_waypoints} waypoints: "
            f"{result.weak_direction or '; '.join(result.notes)}; "
            "check [scanner.nominal] or lower trajectory.pose_uncertainty"
        )
    return result


def second_design(job: JobConfig, estimate: FloatArray, estimate_std: tuple[float, float],
                  measured_poses: FloatArray, first_index: int, model: URModel | None = None) -> Design:
    """The rest of the waypoints, designed around ``estimate`` (``T_base_laser``) together
    with the information of the waypoints already measured, starting near the last of them,
    on ``model`` (the robot's own kinematics when known; default ``design_model``)."""
    std_mm, std_deg = estimate_std
    uncertainty = PoseUncertainty(
        translation_m=max(LEAST_UNCERTAINTY.translation_m, ESTIMATE_SIGMAS * std_mm / 1000.0),
        rotation_deg=max(LEAST_UNCERTAINTY.rotation_deg, ESTIMATE_SIGMAS * std_deg),
    )
    request = request_for_job(
        job,
        estimate,
        model or design_model(job),
        uncertainty=uncertainty,
        waypoints=job.trajectory.design_waypoints - first_index,
        seed=1,
    )
    measured = pose_to_matrix(np.asarray(measured_poses, dtype=float).reshape(-1, 6))
    points_m, range_m = visited_crossings(measured, request)
    prior = information_blocks(measured, range_m, request, extended_fisher_information).sum(axis=0)
    last_q = inverse_kinematics_branches(measured[-1:], model=request.rules.model)[0, request.rules.branch]
    request = dataclasses.replace(
        request,
        prior_information=prior,
        visited_crossings_m=points_m,
        first_index=first_index,
        start_q_rad=last_q if np.all(np.isfinite(last_q)) else None,
    )
    return design(request, extended_fisher_information)


def _record_design(
    recorder: RunRecorder, clock: Callable[[], float], phase: int, first_index: int,
    waypoints: FloatArray, designed_from: FloatArray, predicted: Design | None,
) -> None:
    fields = {
        "phase": phase,
        "first_index": first_index,
        "waypoints": np.asarray(waypoints).tolist(),
        "designed_from_T_base_laser": np.asarray(designed_from).tolist(),
    }
    if predicted is not None:
        fields |= {
            "predicted_std_translation_mm": predicted.std_translation_mm.tolist(),
            "predicted_std_rotation_deg": predicted.std_rotation_deg.tolist(),
            "notes": predicted.notes,
        }
    recorder.write_event(clock(), DESIGN_EVENT, **fields)


def run_second_design(
    robot: Robot,
    scanner: Scanner,
    recorder: RunRecorder,
    job: JobConfig,
    waypoints: FloatArray,
    first: RunOutcome,
    *,
    on_progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
    clock: Callable[[], float] = time.time,
    model: URModel | None = None,
) -> RunOutcome:
    """After the first part's run: design the rest from its estimate (on ``model``, the
    robot's own kinematics when known), measure it, and solve over all waypoints. A run
    resumed after the second design already holds every waypoint and is returned as it is."""
    first_count = len(waypoints)
    if first_count >= job.trajectory.design_waypoints:
        return first
    assert job.scanner.nominal is not None
    _record_design(recorder, clock, 1, 0, waypoints, job.scanner.nominal.matrix(), None)
    estimate = first.result
    measured = np.array([m.tcp_pose for m in first.measurements]).reshape(-1, 6)
    result = second_design(
        job,
        estimate.matrix(),
        (max(estimate.std_translation_mm), max(estimate.std_rotation_deg)),
        measured,
        first_count,
        model,
    )
    poses = np.array([w.tcp_pose for w in result.waypoints]).reshape(-1, 6)
    _record_design(recorder, clock, 2, first_count, poses, estimate.matrix(), result)
    if len(poses) == 0:
        return first
    every_waypoint = np.vstack([waypoints, poses])
    sequencer = Sequencer(
        robot,
        scanner,
        recorder,
        job,
        every_waypoint,
        on_progress=on_progress,
        resume=ResumeState(first.measurements, first.skipped, first.background),
        cancel=cancel,
        clock=clock,
    )
    outcome = solve_run(
        sequencer.measure(), job, recorder,
        on_progress=on_progress, cancel=cancel, clock=clock,
    )
    outcome.timings.motion_s += first.timings.motion_s
    outcome.timings.dwell_s += first.timings.dwell_s
    outcome.timings.wall_s += first.timings.wall_s
    return outcome
