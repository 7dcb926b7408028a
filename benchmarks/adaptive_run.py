"""The adaptive run against the ``paper`` preset on the default scene (not collected by pytest).

Run from the repository root::

    .venv/bin/python -m benchmarks.adaptive_run [--seeds 10] [--dwell 3]

Per seed, offline (the measurement chain of ``benchmarks.dry_run_accuracy``: range noise,
mixed pixels, the robot's 1 mm error field drawn anew per seed, extraction, the run's
two-pass solve):

- ``paper``: the preset laid out with the true pose (20 waypoints);
- adaptive: the first design (8 waypoints) from a rough pose 5 cm and 5 degrees off the
  truth (new random directions per seed), solved; the remaining 12 designed from that
  estimate (``lasercal_hw.run.adaptive.second_design``); one solve over all 20.

Printed: per seed the error against the truth and the reported std of both; then the
medians, the ratio of the adaptive run's reported std to paper's (target: within 10 %),
and the error percentiles (target: no worse).
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks.dry_run_accuracy import dwell, errors, measure, world_for
from benchmarks.trajectory_design import nominal_job, rough_pose
from fakes.world import World
from lasercal_hw.config import JobConfig, with_overrides
from lasercal_hw.run.adaptive import first_design, second_design
from lasercal_hw.run.retract import retract_candidates
from lasercal_hw.run.two_pass import solve_two_pass
from lasercal_hw.run.waypoints import job_waypoints


def run_fixed(
    job: JobConfig, poses: np.ndarray, world: World, scans: int, seed: int
) -> tuple[np.ndarray, ...]:
    """Errors (mm, deg) and largest reported std (mm, deg) of one fixed-trajectory run."""
    rng = np.random.default_rng(seed)
    background = dwell(world, retract_candidates(job, poses)[0], job.background.scans, rng)
    result = solve_two_pass(measure(job, poses, world, scans, rng, background), job, background).result
    return (*errors(result, world.ground_truth_T_base_laser), result)


def run_adaptive(job: JobConfig, world: World, scans: int, seed: int) -> tuple[np.ndarray, ...]:
    """The same for an adaptive run: first design, solve, second design, solve over all."""
    rng = np.random.default_rng(seed)
    first = np.array([w.tcp_pose for w in first_design(job).waypoints])
    background = dwell(world, retract_candidates(job, first)[0], job.background.scans, rng)
    measured = measure(job, first, world, scans, rng, background)
    estimate = solve_two_pass(measured, job, background).result
    rest = second_design(
        job,
        estimate.matrix(),
        (max(estimate.std_translation_mm), max(estimate.std_rotation_deg)),
        np.array([m.tcp_pose for m in measured]),
        len(first),
    )
    poses = np.array([w.tcp_pose for w in rest.waypoints]).reshape(-1, 6)
    measured += measure(job, poses, world, scans, rng, background, first_index=len(first))
    result = solve_two_pass(measured, job, background).result
    return (*errors(result, world.ground_truth_T_base_laser), result)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--dwell", type=float, default=3.0)
    args = parser.parse_args()

    base = with_overrides(
        JobConfig(),
        {"dwell_s": args.dwell, "workspace.min_m": [-0.95, -0.95, 0.0], "trajectory.adaptive": True},
    )
    paper = job_waypoints(with_overrides(base, {"trajectory.adaptive": False}))
    truth = World.from_scene(None).ground_truth_T_base_laser
    scans = round(args.dwell / 0.025)
    rows = []
    for seed in range(args.seeds):
        job = nominal_job(base, rough_pose(truth, np.random.default_rng(100 + seed)))
        world = world_for(job, None, robot_error_seed=1000 + seed)
        fixed = run_fixed(job, paper, world, scans, seed)
        adaptive = run_adaptive(job, world, scans, seed)
        row = []
        for name, (dt_mm, de_deg, result) in (("paper", fixed), ("adaptive", adaptive)):
            t, r = float(np.linalg.norm(dt_mm)), float(np.linalg.norm(de_deg))
            st, sr = max(result.std_translation_mm), max(result.std_rotation_deg)
            row += [t, r, st, sr]
            print(
                f"seed {seed:2d} {name:8s}: error {t:5.2f} mm {r:5.3f} deg | std {st:.2f} mm {sr:.3f} deg",
                flush=True,
            )
        rows.append(row)
    table = np.array(rows)
    median = np.median(table, axis=0)
    print(f"\n{args.seeds} seeds, {scans} scans per waypoint, 20 waypoints each")
    for k, name in ((0, "paper"), (4, "adaptive")):
        errors_t, errors_r = table[:, k], table[:, k + 1]
        print(
            f"  {name:8s}: error median {np.median(errors_t):.2f} mm {np.median(errors_r):.3f} deg, "
            f"95th percentile {np.percentile(errors_t, 95):.2f} mm {np.percentile(errors_r, 95):.3f} deg; "
            f"std median {median[k + 2]:.2f} mm {median[k + 3]:.3f} deg"
        )
    print(
        f"  adaptive / paper: std {median[6] / median[2]:.2f} (translation) {median[7] / median[3]:.2f} "
        f"(rotation); median error {np.median(table[:, 4]) / np.median(table[:, 0]):.2f} (translation) "
        f"{np.median(table[:, 5]) / np.median(table[:, 1]):.2f} (rotation)"
    )


if __name__ == "__main__":
    main()
