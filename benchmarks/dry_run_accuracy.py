"""Offline accuracy of the whole dry-run measurement chain (not collected by pytest).

Run from the repository root::

    .venv/bin/python -m benchmarks.dry_run_accuracy [--config examples/drill.toml] [--seeds 20]
        [--dwell 3] [--crb-only]

No devices and no sockets: for the job's waypoints (``lasercal_hw.run.waypoints.job_waypoints``)
and the fake world (``fakes.world``, default scene, the rod replaced by the job's rod),
each waypoint gets ``dwell_s / scan_period`` noisy scans cast at the pose the controller
would report (the world applies its robot absolute-accuracy error field), which are
averaged (``average_scans``) and searched for the rod (``find_rod_centre``, background
from the sequencer's retract pose), then solved with the sequencer's own two passes
(``solve_two_pass``: second pass on centres re-extracted with the rod axis the first
solution predicts). Each seed draws new range noise and a new robot error field.

Printed: the Cramér-Rao bound of the trajectory (the solver's Fisher information with
the job's noise model), then per seed the error against the ground truth and the
reported std, and the percentiles of the errors and of the coverage
``|error| / reported std`` per component (honest std: >= 95 % of components within 2.5).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fakes.scene import Scene, load_scene
from fakes.world import World
from lasercal_hw.calibration.model import fisher_information, rod_lines_in_base
from lasercal_hw.calibration.result import CalibrationResult
from lasercal_hw.config import JobConfig, load_job
from lasercal_hw.errors import ConfigError, LasercalError
from lasercal_hw.geometry import matrix_to_rotvec, pose_to_matrix
from lasercal_hw.models import LaserScan, Observation, RodLine
from lasercal_hw.run.flute_spin import turn_waypoints
from lasercal_hw.run.records import WaypointMeasurement
from lasercal_hw.run.retract import retract_candidates
from lasercal_hw.run.two_pass import SecondPassRefit, predict_rod, solve_two_pass
from lasercal_hw.run.waypoints import job_waypoints, planned_waypoints
from lasercal_hw.scan.average import AveragedScan, average_scans
from lasercal_hw.scan.extraction import RodNotFoundError, find_rod_centre
from lasercal_hw.ur_kinematics import inverse_kinematics_pose
from trajectories.checks import check_pose

#: Centre noise assumed by the quick CRB (a 20 mm rod, 120 scans: about 0.5 mm per axis).
CRB_SIGMA_UV_M = 0.0005


@dataclass(frozen=True)
class Trial:
    """One simulated run: its result and its error against the truth."""

    result: CalibrationResult
    error_translation_mm: np.ndarray
    error_rotation_deg: np.ndarray
    found: int
    #: How its second pass fitted the centres (a verify of it fits its own so).
    refit: SecondPassRefit
    #: The centres the final solve took (``benchmarks.waypoint_errors`` judges them one by one).
    observations: tuple[Observation, ...]
    #: Every waypoint the run visited (UR poses (N, 6), by the residuals' index: a spun job's
    #: spin, then its turned waypoints), as ``result.json``'s ``run.waypoints`` records them.
    waypoints: np.ndarray


def world_for(job: JobConfig, scene_path: Path | None, robot_error_seed: int) -> World:
    """The fake world of a scene with the job's rod in the gripper and the given error field."""
    return world_with(load_scene(scene_path), job.rod.rod_line(), robot_error_seed)


def world_with(
    scene: Scene, rod: RodLine, robot_error_seed: int, scanner: str | None = None, **noise: float
) -> World:
    """The fake world of ``scene`` as ``scanner`` sees it (default: the first) with ``rod`` in
    the gripper, the given robot error field and other ``[noise]`` settings (e.g.
    ``bias_offset_m``)."""
    scene = scene.model_copy(
        update={
            "rod": scene.rod.model_copy(
                update={
                    "origin_m": np.asarray(rod.origin_m, dtype=float).tolist(),
                    "direction": np.asarray(rod.direction, dtype=float).tolist(),
                    "radius_m": rod.radius_m,
                    "length_m": rod.length_m,
                }
            ),
            "noise": scene.noise.model_copy(update={"robot_error_seed": robot_error_seed, **noise}),
        }
    )
    return World(scene, scanner)


def dwell(
    world: World, tcp_pose: np.ndarray, scans: int, rng: np.random.Generator, *, intensities: bool = True
) -> AveragedScan:
    """Average ``scans`` noisy scans of the world with the TCP at ``tcp_pose`` (UR vector);
    ``intensities`` False: ranges alone, as a job with ``[scanner] intensities = false`` streams
    them (SCIP MD)."""
    T = pose_to_matrix(np.asarray(tcp_pose, dtype=float))
    period_s = world.geometry.scan_period_s
    batch = []
    for k in range(scans):
        mm, levels = world.scan_mm(T, rng)
        ranges_m = np.where(mm >= 23, mm / 1000.0, np.nan)
        batch.append(
            LaserScan(
                k, world.geometry, ranges_m, mm, levels if intensities else None,
                period_s * k, period_s * k,
            )
        )
    return average_scans(batch)


def errors(result: CalibrationResult, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translation error (mm, base axes) and rotation error (deg, small rotation about base axes)."""
    T = result.matrix()
    dt_mm = (T[:3, 3] - truth[:3, 3]) * 1e3
    de_deg = np.degrees(matrix_to_rotvec(T[:3, :3] @ truth[:3, :3].T))
    return dt_mm, de_deg


def measure(
    job: JobConfig,
    waypoints: np.ndarray,
    world: World,
    scans: int,
    rng: np.random.Generator,
    background: AveragedScan,
    first_index: int = 0,
) -> list[WaypointMeasurement]:
    """The sequencer's dwell and extraction at each waypoint (indices from ``first_index``);
    waypoints whose rod is not found are left out."""
    rod = job.rod.rod_line()
    nominal = job.scanner.nominal
    measurements: list[WaypointMeasurement] = []
    for index, pose in enumerate(waypoints, start=first_index):
        averaged = dwell(world, pose, scans, rng, intensities=job.scanner.intensities)
        expected = None if nominal is None else predict_rod(nominal.matrix(), pose, rod).expected_uv_m
        try:
            centre = find_rod_centre(
                averaged, radius_m=rod.radius_m, background=background, expected_uv_m=expected,
                fluted=rod.fluted,
            )
        except RodNotFoundError:
            continue
        measurements.append(WaypointMeasurement(index, pose, averaged, centre))
    return measurements



def measure_waypoints(
    job: JobConfig, waypoints: np.ndarray, world: World, scans: int, rng: np.random.Generator
) -> tuple[list[WaypointMeasurement], AveragedScan]:
    """The whole chain offline: the background at the retract pose, then ``measure``."""
    background = dwell(
        world, retract_candidates(job, waypoints)[0], job.background.scans, rng,
        intensities=job.scanner.intensities,
    )
    return measure(job, waypoints, world, scans, rng, background), background


def simulate(
    job: JobConfig, waypoints: np.ndarray, world: World, scans: int, rng: np.random.Generator
) -> Trial:
    """One offline run of the sequencer's measurement chain and its two-pass solve; a
    ``flute_phase_deg`` job's ``waypoints`` are its spin, then its waypoints are turned to the
    phase the spin tells (``run/flute_spin``) and measured, as the run does."""
    measurements, background = measure_waypoints(job, waypoints, world, scans, rng)
    visited = np.asarray(waypoints, dtype=float).reshape(-1, 6)
    if job.trajectory.flute_phase_deg is not None:
        turned = turn_waypoints(job, measurements, background, reachable_on_ur5(job))
        if turned.out_of_reach:
            refused = [len(waypoints) + k for k in turned.out_of_reach]
            raise ConfigError(f"the preflight would refuse turned waypoints {refused}: out of reach")
        rest = turned.waypoints
        measurements += measure(job, rest, world, scans, rng, background, first_index=len(waypoints))
        visited = np.vstack([visited, rest])
    solution = solve_two_pass(measurements, job, background)
    dt_mm, de_deg = errors(solution.result, world.ground_truth_T_base_laser)
    observations = tuple(solution.observations)
    return Trial(solution.result, dt_mm, de_deg, len(measurements), solution.refit, observations, visited)


def reachable_on_ur5(job: JobConfig) -> Callable[[np.ndarray], bool]:
    """Whether a pose passes the preflight's pose checks (``trajectories.checks.check_pose``),
    the UR5 model standing in for the controller."""
    rod = job.rod.rod_line()
    return lambda pose: not check_pose(
        pose, inverse_kinematics=inverse_kinematics_pose, workspace=job.workspace, rod=rod
    )[0]


def job_robot_sigma_m(job: JobConfig) -> float:
    """The robot position noise the run gives the solver (the job's stated accuracy)."""
    return job.robot.position_accuracy_mm / 1000.0


def crb_std(
    waypoints: np.ndarray,
    rod: RodLine,
    T_base_laser: np.ndarray,
    sigma_uv_m: float = CRB_SIGMA_UV_M,
    robot_sigma_m: float = 0.001,
) -> tuple[np.ndarray, np.ndarray]:
    """Cramér-Rao std of the translation (mm) and rotation about base axes (deg)."""
    origins, directions = rod_lines_in_base(np.asarray(waypoints, dtype=float), rod)
    covariance = np.broadcast_to(np.eye(2) * sigma_uv_m**2, (len(origins), 2, 2)).copy()
    fisher = fisher_information(
        T_base_laser[:3, :3], T_base_laser[:3, 3], origins, directions, covariance, robot_sigma_m
    )
    crb = np.linalg.inv(fisher)
    std = np.sqrt(np.diag(crb))
    return std[:3] * 1e3, np.degrees(std[3:])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=None, help="job file (default: built-in defaults)")
    parser.add_argument("--scene", type=Path, default=None, help="scene file (default: packaged default)")
    parser.add_argument("--preset", default=None, help="trajectory preset instead of the job's")
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--dwell", type=float, default=None, help="dwell (s); default: the job's")
    parser.add_argument(
        "--robot-error-seed-base", type=int, default=1000, help="error field seed of the first run"
    )
    parser.add_argument(
        "--same-robot-error", action="store_true", help="one error field for all runs (the scene's is seed 0)"
    )
    parser.add_argument("--crb-only", action="store_true")
    args = parser.parse_args()

    job = load_job(args.config)
    if args.preset is not None:
        job = job.model_copy(update={"trajectory": job.trajectory.model_copy(update={"preset": args.preset})})
    dwell_s = job.dwell_s if args.dwell is None else args.dwell
    waypoints = job_waypoints(job)
    rod = job.rod.rod_line()
    truth = World.from_scene(args.scene).ground_truth_T_base_laser
    sigma_robot_m = job_robot_sigma_m(job)
    planned = planned_waypoints(job)
    crb_t, crb_r = crb_std(planned, rod, truth, robot_sigma_m=sigma_robot_m)
    print(
        f"{len(planned)} waypoints, rod r {rod.radius_m * 1e3:.0f} mm, "
        f"robot sigma {sigma_robot_m * 1e3:.2f} mm"
    )
    print(
        f"CRB (centre sigma {CRB_SIGMA_UV_M * 1e3:.1f} mm): translation {np.round(crb_t, 2)} mm, "
        f"rotation {np.round(crb_r, 3)} deg"
    )
    if args.crb_only:
        return

    scans = round(dwell_s / World.from_scene(args.scene).geometry.scan_period_s)
    trials: list[Trial] = []
    started = time.perf_counter()
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        world = world_for(
            job,
            args.scene,
            robot_error_seed=args.robot_error_seed_base + (0 if args.same_robot_error else seed),
        )
        try:
            trial = simulate(job, waypoints, world, scans, np.random.default_rng(seed))
        except LasercalError as exc:
            print(f"seed {seed}: failed: {exc}")
            continue
        trials.append(trial)
        r = trial.result
        print(
            f"seed {seed:3d}: {trial.found}/{len(waypoints)} found, error "
            f"{np.linalg.norm(trial.error_translation_mm):5.2f} mm "
            f"{np.linalg.norm(trial.error_rotation_deg):5.3f} deg"
            f" | std t {np.round(r.std_translation_mm, 2)} mm r {np.round(r.std_rotation_deg, 3)} deg"
            f" | rms {r.rms_residual_mm:.2f} mm chi2 {r.reduced_chi_square:.2f}"
        )
    if not trials:
        return
    t_err = np.array([np.linalg.norm(t.error_translation_mm) for t in trials])
    r_err = np.array([np.linalg.norm(t.error_rotation_deg) for t in trials])
    coverage = np.concatenate(
        [
            np.concatenate(
                [
                    np.abs(t.error_translation_mm) / np.asarray(t.result.std_translation_mm),
                    np.abs(t.error_rotation_deg) / np.asarray(t.result.std_rotation_deg),
                ]
            )
            for t in trials
        ]
    )
    print(f"\n{len(trials)} runs, {scans} scans per waypoint, {time.perf_counter() - started:.0f} s")
    for name, values, unit in (("translation", t_err, "mm"), ("rotation", r_err, "deg")):
        p50, p95 = np.percentile(values, [50, 95])
        print(
            f"  {name} error: median {p50:.3f} {unit}, 95th percentile {p95:.3f} {unit}, "
            f"max {values.max():.3f}"
        )
    print(
        f"  coverage |error|/std per component: median {np.median(coverage):.2f}, "
        f"within 2.5 sigma {np.mean(coverage < 2.5):.1%}, within 2 sigma {np.mean(coverage < 2.0):.1%}"
    )


if __name__ == "__main__":
    main()
