"""Trajectory design over scanner placements unlike the default scene (not collected by pytest).

Run from the repository root::

    .venv/bin/python -m benchmarks.trajectory_design [--seeds 2] [--waypoints 20] [--no-paper]

For each placement (left and right of the robot, lower and higher, 0.45 to 1.2 m from the
base, turned towards and away from it, one on its side at 90 degrees roll; the default
scene as the reference), the waypoints are designed from a rough pose 5 cm and 5 degrees
off the truth (``trajectories.design``, job gates 1.5 mm and 0.25 deg, workspace floor
at the table, z = 0). Printed per placement:

- the predicted std per axis (the CRB at the rough pose the design saw) and what stays
  weak when the gates cannot be met;
- the check results: ``trajectory check`` (UR5 model, workspace box, rod ends) and, at
  the *true* pose, how many rods cross the scan plane between their ends with the margin;
- the dry run: the offline measurement chain of ``benchmarks.dry_run_accuracy`` on a
  scene with that placement (range noise, mixed pixels, the robot's 1 mm error field,
  extraction with the rough pose as the hint, the run's two-pass solve), per seed: rods
  found, error against the truth, reported std;
- for comparison, the ``paper`` preset (laid out for the default scene) on the same scene.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.dry_run_accuracy import simulate, world_for
from lasercal_hw.calibration.model import extended_fisher_information, fisher_information, rod_lines_in_base
from lasercal_hw.config import JobConfig, with_overrides
from lasercal_hw.errors import LasercalError
from lasercal_hw.geometry import (
    euler_zyx_to_matrix,
    make_transform,
    matrix_to_euler_zyx,
    pose_to_matrix,
    rotvec_to_matrix,
)
from lasercal_hw.run.waypoints import job_waypoints
from lasercal_hw.ur_kinematics import UR5, inverse_kinematics_pose
from trajectories.candidates import END_MARGIN_M
from trajectories.checks import check_waypoints
from trajectories.design import NoiseModel, design, request_for_job, std_of
from trajectories.plane_crossing import rod_plane_crossings

ROUGH_TRANSLATION_M = 0.05
ROUGH_ROTATION_DEG = 5.0


@dataclass(frozen=True)
class Placement:
    """A scanner placement: its name and true pose (m; ZYX deg)."""

    name: str
    translation_m: tuple[float, float, float]
    euler_zyx_deg: tuple[float, float, float]

    def matrix(self) -> np.ndarray:
        """The true ``T_base_laser``."""
        return make_transform(euler_zyx_to_matrix(*np.radians(self.euler_zyx_deg)), self.translation_m)


PLACEMENTS = [
    Placement("default scene (reference)", (0.30, 0.50, 0.20), (5.0, 7.0, 3.0)),
    Placement("right, lower (the issue's cell)", (0.35, -0.55, 0.15), (10.0, -3.0, 2.0)),
    Placement("left, near (0.45 m), turned towards", (0.20, 0.40, 0.18), (-40.0, 0.0, 0.0)),
    Placement("right, higher, turned towards", (0.50, -0.60, 0.45), (120.0, 5.0, 0.0)),
    Placement("in front (0.9 m), turned away", (0.90, 0.00, 0.15), (0.0, 2.0, -2.0)),
    Placement("left, far (1.2 m), higher, turned towards", (-0.20, 1.15, 0.50), (-90.0, 0.0, 3.0)),
    Placement("on its side (90 deg roll)", (0.55, 0.45, 0.30), (0.0, 0.0, 90.0)),
    Placement("behind left, lower", (-0.40, 0.50, 0.15), (-45.0, 0.0, 0.0)),
]


def rough_pose(truth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The truth moved by exactly 5 cm and turned by exactly 5 deg, in random directions."""
    shift, axis = rng.normal(size=3), rng.normal(size=3)
    rough = truth.copy()
    rough[:3, 3] += ROUGH_TRANSLATION_M * shift / np.linalg.norm(shift)
    turn = rotvec_to_matrix(np.radians(ROUGH_ROTATION_DEG) * axis / np.linalg.norm(axis))
    rough[:3, :3] = turn @ truth[:3, :3]
    return rough


def scene_file(folder: Path, placement: Placement, index: int) -> Path:
    """A scene: the default one with the scanner at the placement."""
    path = folder / f"placement_{index}.toml"
    path.write_text(
        f"[scanner]\ntranslation_m = {list(placement.translation_m)}\n"
        f"euler_zyx_deg = {list(placement.euler_zyx_deg)}\n",
        encoding="utf-8",
    )
    return path


def nominal_job(base: JobConfig, rough: np.ndarray) -> JobConfig:
    """The job with the rough pose as its nominal scanner pose."""
    euler = np.degrees(matrix_to_euler_zyx(rough[:3, :3]))
    return with_overrides(
        base, {"scanner.nominal": {"translation_m": rough[:3, 3].tolist(), "euler_zyx_deg": euler.tolist()}}
    )


def crossings_on_rod(poses: np.ndarray, job: JobConfig, truth: np.ndarray) -> int:
    """Waypoints whose rod crosses the true scan plane with the end margin to spare."""
    rod = job.rod.rod_line()
    along = rod_plane_crossings(pose_to_matrix(poses), rod, truth).along_rod_m
    return int(np.sum((along >= END_MARGIN_M) & (along <= rod.length_m - END_MARGIN_M)))


def dry_runs(
    job: JobConfig, poses: np.ndarray, scene: Path, seeds: int, scans: int
) -> list[tuple[int, float, float, float, float]]:
    """Per seed: rods found, error (mm, deg), largest reported std (mm, deg); NaN when the solve failed."""
    rows = []
    for seed in range(seeds):
        world = world_for(job, scene, robot_error_seed=1000 + seed)
        try:
            trial = simulate(job, poses, world, scans, np.random.default_rng(seed))
        except LasercalError:
            rows.append((0, np.nan, np.nan, np.nan, np.nan))
            continue
        rows.append(
            (
                trial.found,
                float(np.linalg.norm(trial.error_translation_mm)),
                float(np.linalg.norm(trial.error_rotation_deg)),
                float(np.max(trial.result.std_translation_mm)),
                float(np.max(trial.result.std_rotation_deg)),
            )
        )
    return rows


def describe_runs(rows: list[tuple[int, float, float, float, float]], total: int) -> str:
    """One line for the dry runs of one trajectory."""
    parts = [
        f"{found}/{total} found, error {t:.2f} mm {r:.3f} deg (std {st:.2f} mm {sr:.3f} deg)"
        if np.isfinite(t)
        else "solve failed"
        for found, t, r, st, sr in rows
    ]
    return "; ".join(parts)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2, help="dry runs per placement")
    parser.add_argument("--waypoints", type=int, default=20)
    parser.add_argument("--no-paper", action="store_true", help="skip the paper preset's dry runs")
    args = parser.parse_args()

    base = with_overrides(
        JobConfig(),
        {
            "quality.max_std_translation_mm": 1.5,
            "quality.max_std_rotation_deg": 0.25,
            "workspace.min_m": [-0.95, -0.95, 0.0],
        },
    )
    scans = round(base.dwell_s / 0.025)
    paper = job_waypoints(base)
    rng = np.random.default_rng(2026)
    with tempfile.TemporaryDirectory() as folder:
        for index, placement in enumerate(PLACEMENTS):
            truth = placement.matrix()
            rough = rough_pose(truth, rng)
            job = nominal_job(base, rough)
            request = request_for_job(job, rough, UR5, waypoints=args.waypoints, seed=index)
            started = time.perf_counter()
            result = design(request, extended_fisher_information)
            design_s = time.perf_counter() - started
            poses = np.array([w.tcp_pose for w in result.waypoints]).reshape(-1, 6)
            print(
                f"\n== {placement.name}: truth {placement.translation_m} m, ZYX {placement.euler_zyx_deg} deg"
            )
            print(
                f"design: {len(poses)} waypoints in {design_s:.1f} s ({result.candidates_kept} of "
                f"{result.candidates_drawn} drawn poses keep every rule)"
            )
            print(
                f"  predicted std (rough pose): translation {np.round(result.std_translation_mm, 2)} mm, "
                f"rotation {np.round(result.std_rotation_deg, 3)} deg"
            )
            if len(poses):
                at_truth_t, at_truth_r = std_of(information_at(poses, job, truth, request.noise))
                print(
                    f"  predicted std (true pose):  translation {np.round(at_truth_t, 2)} mm, "
                    f"rotation {np.round(at_truth_r, 3)} deg"
                )
            for note in result.notes:
                print(f"  note: {note}")
            if result.weak_direction is not None:
                print(f"  weak: {result.weak_direction}")
            if not len(poses):
                continue
            report = check_waypoints(
                result.waypoints,
                inverse_kinematics=inverse_kinematics_pose,
                workspace=job.workspace,
                rod=job.rod.rod_line(),
            )
            print(
                f"check: trajectory check {report.checked - len(report.failing_indices)}/{report.checked} "
                "pass; "
                f"rod crosses the true plane with {END_MARGIN_M * 1e3:.0f} mm to spare at "
                f"{crossings_on_rod(poses, job, truth)}/{len(poses)}"
            )
            scene = scene_file(Path(folder), placement, index)
            designed_runs = dry_runs(job, poses, scene, args.seeds, scans)
            print(f"dry run, designed: {describe_runs(designed_runs, len(poses))}")
            if not args.no_paper:
                print(
                    f"dry run, paper:    {describe_runs(dry_runs(job, paper, scene, 1, scans), len(paper))} "
                    f"(rod on the true plane at {crossings_on_rod(paper, job, truth)}/{len(paper)})"
                )


def information_at(poses: np.ndarray, job: JobConfig, truth: np.ndarray, noise: NoiseModel) -> np.ndarray:
    """Fisher information of the waypoints at the true pose, with the design's noise model."""
    rod = job.rod.rod_line()
    origins, directions = rod_lines_in_base(poses, rod)
    ranges = np.linalg.norm(rod_plane_crossings(pose_to_matrix(poses), rod, truth).uv_m, axis=1)
    sigma = noise.centre_sigma_of(ranges, rod.radius_m)
    covariance = np.eye(2)[None] * (sigma**2)[:, None, None]
    rotation, translation = truth[:3, :3], truth[:3, 3]
    return fisher_information(rotation, translation, origins, directions, covariance, noise.robot_sigma_m)


if __name__ == "__main__":
    main()
