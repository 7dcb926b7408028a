"""Offline accuracy of a cell job: every scanner and every scanner-to-scanner transform
(not collected by pytest).

Run from the repository root::

    .venv/bin/python -m benchmarks.cell_accuracy [--config examples/cell.toml]
        [--scene fakes/scenes/two_scanners.toml] [--seeds 20]

``benchmarks/dry_run_accuracy.py``'s offline chain (no devices, no sockets: the fake world
cast, scans averaged, the rod found, the two-pass solve) run for each scanner of the job on
its own waypoints (``JobConfig.for_scanner``), every scanner of one seed seeing the same
robot (one absolute-accuracy error field). The scene's scanner model unless
``$LASERCAL_FAKE_SCANNER_MODEL`` says otherwise.

Printed: per seed each scanner's error against the truth and the front-to-rear (each pair's)
error in its combined std; then the distributions: each scanner's translation and rotation
error (median, 95th percentile, max, share within 2 mm and 0.3 deg), and each pair's largest
axis error in its own std and its Mahalanobis distance (6 dof; share within 2.5 std).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from benchmarks.dry_run_accuracy import simulate, world_with
from fakes.scene import load_scene, with_model_override
from lasercal_hw.calibration.pairs import error_in_std, relative_pose
from lasercal_hw.config import load_job
from lasercal_hw.errors import LasercalError
from lasercal_hw.run.waypoints import job_waypoints

REPO = Path(__file__).resolve().parents[1]


def _summary(name: str, values: np.ndarray, unit: str) -> str:
    p50, p95 = np.percentile(values, [50, 95])
    return f"{name} median {p50:.3f} {unit}, 95th percentile {p95:.3f} {unit}, max {values.max():.3f} {unit}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=REPO / "examples" / "cell.toml")
    parser.add_argument("--scene", type=Path, default=REPO / "fakes" / "scenes" / "two_scanners.toml")
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--robot-error-seed-base", type=int, default=1000)
    args = parser.parse_args()

    job = load_job(args.config)
    scene = with_model_override(load_scene(args.scene))
    names = job.scanner_names()
    jobs = {name: job.for_scanner(name) for name in names}
    waypoints = {name: job_waypoints(jobs[name]) for name in names}
    period_s = scene.for_scanner(names[0]).scanner.scan_period_s
    scans = round(job.dwell_s / period_s)
    print(
        f"{scene.model} scanner model, {scans} scans per waypoint; "
        + ", ".join(f"{name}: {len(waypoints[name])} waypoints" for name in names)
    )
    errors: dict[str, list[tuple[float, float]]] = {name: [] for name in names}
    pairs: dict[tuple[str, str], list[dict[str, float]]] = {}
    started = time.perf_counter()
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        robot_error_seed = args.robot_error_seed_base + seed
        results, truths, line = {}, {}, [f"seed {seed:3d}:"]
        for index, name in enumerate(names):
            world = world_with(scene, jobs[name].rod.rod_line(), robot_error_seed, name)
            try:
                rng = np.random.default_rng([seed, index])
                trial = simulate(jobs[name], waypoints[name], world, scans, rng)
            except LasercalError as exc:
                line.append(f"{name} failed: {exc}")
                continue
            results[name], truths[name] = trial.result, world.ground_truth_T_base_laser
            error = (float(np.linalg.norm(trial.error_translation_mm)),
                     float(np.linalg.norm(trial.error_rotation_deg)))
            errors[name].append(error)
            found = f"{trial.found}/{len(waypoints[name])}"
            line.append(f"{name} {error[0]:5.2f} mm {error[1]:5.3f} deg ({found})")
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                if a not in results or b not in results:
                    continue
                T_ab, covariance = relative_pose(
                    results[a].matrix(), np.asarray(results[a].covariance),
                    results[b].matrix(), np.asarray(results[b].covariance),
                )
                truth = np.linalg.inv(truths[a]) @ truths[b]
                pair = error_in_std(T_ab, covariance, truth)
                pairs.setdefault((a, b), []).append(pair)
                line.append(
                    f"| {a}->{b} {pair['translation_mm']:5.2f} mm {pair['rotation_deg']:5.3f} deg, "
                    f"largest axis {pair['max_axis_in_std']:.2f} std"
                )
        print(" ".join(line))
    print(f"\n{args.seeds} seeds, {time.perf_counter() - started:.0f} s")
    for name in names:
        values = np.array(errors[name]).reshape(-1, 2)
        if not len(values):
            continue
        within = np.mean((values[:, 0] <= 2.0) & (values[:, 1] <= 0.3))
        print(
            f"  {name} ({len(values)} runs): {_summary('translation', values[:, 0], 'mm')}; "
            f"{_summary('rotation', values[:, 1], 'deg')}; within 2 mm and 0.3 deg {within:.0%}"
        )
    for (a, b), values in pairs.items():
        largest = np.array([v["max_axis_in_std"] for v in values])
        mahalanobis = np.array([v["mahalanobis"] for v in values])
        translation = np.array([v["translation_mm"] for v in values])
        rotation = np.array([v["rotation_deg"] for v in values])
        print(
            f"  {a}->{b} ({len(values)} runs): {_summary('translation', translation, 'mm')}; "
            f"{_summary('rotation', rotation, 'deg')}; largest axis error in its std: median "
            f"{np.median(largest):.2f}, max {largest.max():.2f}, "
            f"within 2.5 std {np.mean(largest <= 2.5):.0%}; "
            f"Mahalanobis (6 dof, median {np.sqrt(5.35):.2f} expected): median {np.median(mahalanobis):.2f}"
        )


if __name__ == "__main__":
    main()
