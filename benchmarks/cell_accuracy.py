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

Every other scanner with a nominal pose watches each scanner's waypoints as a cell job's
watchers do (``run/watchers``: where its nominal pose puts the rod in its view, the same dwell
averaged, the rod found without a background), each centre is fitted again as the watcher's
second pass once the watcher's own run is solved (``run/watchers.second_pass_centre``, as the
cell job's replay does), and each pair's agreement is tested as the cell job tests it
(``run/cell.pair_agreement``): with the solved poses, and with the second scanner's solved pose
moved by ``--moved-mm`` along base x and turned ``--moved-deg`` about base z (a scanner knocked
after its calibration: the test should say ``disagree``; its watcher centres keep the second
pass with the solved pose: with the moved pose instead, rear's centres at front's waypoints move
by 0.006 mm median, 0.05 mm at the 95th percentile, 0.34 mm at most over seeds 0-39).

Printed: per seed each scanner's error against the truth, the front-to-rear (each pair's)
error in its combined std and the agreement verdicts (solved, moved); then the
distributions: each scanner's translation and rotation error (median, 95th percentile, max,
share within 2 mm and 0.3 deg), each pair's largest std, its largest axis error in its own
std and its Mahalanobis distance (6 dof; share within 2.5 std), the same for ``joint`` (the
pair's transform with the shared centres used jointly, where the two agree: ``cell.json``'s
``joint``, ``run/cell.pair_document``), and how often each verdict came.
"""

from __future__ import annotations

import argparse
import time
from collections import Counter, defaultdict
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks.dry_run_accuracy import dwell, errors, measure_waypoints, world_with
from fakes.scene import load_scene, with_model_override
from fakes.world import World
from lasercal_hw.config import JobConfig, load_job
from lasercal_hw.errors import LasercalError
from lasercal_hw.geometry import euler_zyx_to_matrix, make_transform
from lasercal_hw.run.cell import (
    RecordedCentres,
    ScannerOutcome,
    applied_range_offset_m,
    first_pass_scatter_uv_m2,
    pair_agreement,
    pair_document,
)
from lasercal_hw.run.two_pass import solve_two_pass
from lasercal_hw.run.watchers import (
    SolvedWatcher,
    Watcher,
    expected_crossing,
    second_pass_centre,
    watcher_centre,
)
from lasercal_hw.run.waypoints import job_waypoints

REPO = Path(__file__).resolve().parents[1]


def _summary(name: str, values: np.ndarray, unit: str) -> str:
    p50, p95 = np.percentile(values, [50, 95])
    return f"{name} median {p50:.3f} {unit}, 95th percentile {p95:.3f} {unit}, max {values.max():.3f} {unit}"


class _ViewOf:
    """What ``expected_crossing`` asks of a watcher's scanner: its beam geometry."""

    def __init__(self, world: World) -> None:
        self._world = world

    def geometry(self):
        return self._world.geometry


def _watched(
    job: JobConfig, name: str, waypoints: np.ndarray, world: World, scans: int, rng: np.random.Generator
) -> dict[int, tuple]:
    """The centres the watcher ``name`` (in ``world``) finds at another scanner's waypoints:
    ``(tcp_pose, averaged scan, first-pass centre)`` by waypoint."""
    nominal = job.for_scanner(name).scanner.nominal
    if nominal is None:
        return {}
    watcher = Watcher(name, _ViewOf(world), nominal.matrix())  # type: ignore[arg-type]
    rod = job.rod.rod_line()
    found = {}
    for index, pose in enumerate(waypoints):
        expected = expected_crossing(watcher, pose, rod)
        if expected is None:
            continue
        averaged = dwell(world, pose, scans, rng)
        try:
            centre = watcher_centre(averaged, expected, rod)
        except LasercalError:
            continue
        found[index] = (pose, averaged, centre)
    return found


def _second_pass(found: dict[int, tuple], solved: SolvedWatcher) -> dict[int, tuple]:
    """A watcher's centres (``_watched``) fitted again as its second pass."""
    entries = {}
    for index, (pose, averaged, first) in found.items():
        centre, _ = second_pass_centre(averaged, pose, first, solved)
        entries[index] = (pose, centre.centre_uv_m, centre.covariance_uv_m2)
    return entries


def _moved(T_base_laser: list[list[float]], moved_mm: float, moved_deg: float) -> list[list[float]]:
    """``T_base_laser`` moved along base x and turned about base z about its own origin."""
    T = np.asarray(T_base_laser, dtype=float).copy()
    T[:3, :3] = euler_zyx_to_matrix(np.radians(moved_deg), 0.0, 0.0) @ T[:3, :3]
    return (make_transform(np.eye(3), [moved_mm / 1000.0, 0.0, 0.0]) @ T).tolist()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=REPO / "examples" / "cell.toml")
    parser.add_argument("--scene", type=Path, default=REPO / "fakes" / "scenes" / "two_scanners.toml")
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--robot-error-seed-base", type=int, default=1000)
    parser.add_argument("--moved-mm", type=float, default=5.0)
    parser.add_argument("--moved-deg", type=float, default=0.5)
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
    errors_of: dict[str, list[tuple[float, float]]] = {name: [] for name in names}
    pairs: dict[tuple[str, str], list[dict[str, float]]] = {}
    verdicts: dict[tuple[str, str], list[tuple[str, str, int]]] = {}
    joint: dict[tuple[str, str], list[dict[str, float]]] = defaultdict(list)
    started = time.perf_counter()
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        robot_error_seed = args.robot_error_seed_base + seed
        results, truths, line = {}, {}, [f"seed {seed:3d}:"]
        worlds = {
            name: world_with(scene, jobs[name].rod.rod_line(), robot_error_seed, name) for name in names
        }
        centres: dict[str, RecordedCentres] = {}
        outcomes: dict[str, ScannerOutcome] = {}
        solved_as_watcher: dict[str, SolvedWatcher] = {}
        watched: dict[tuple[str, str], dict[int, tuple]] = {}
        for index, name in enumerate(names):
            world = worlds[name]
            rng = np.random.default_rng([seed, index])
            try:
                measurements, background = measure_waypoints(jobs[name], waypoints[name], world, scans, rng)
                solution = solve_two_pass(measurements, jobs[name], background)
            except LasercalError as exc:
                line.append(f"{name} failed: {exc}")
                continue
            result = solution.result
            results[name], truths[name] = result, world.ground_truth_T_base_laser
            outcomes[name] = ScannerOutcome(
                name, Path(), True, result.T_base_laser, result.covariance,
                world.ground_truth_T_base_laser.tolist(), None,
                rod=result.estimated_rod(jobs[name].rod.rod_line()), range_offset=result.range_offset,
                range_offset_applied_m=applied_range_offset_m(result),
                reduced_chi_square=result.reduced_chi_square,
            )
            solved_as_watcher[name] = SolvedWatcher(
                result.matrix(), outcomes[name].rod, background,
                first_pass_scatter_uv_m2(
                    {m.index: m.centre.centre_uv_m for m in measurements},
                    {o.index: o.centre_uv_m for o in solution.observations}, outcomes[name]),
            )
            centres[name] = {None: {o.index: (o.tcp_pose, o.centre_uv_m, o.covariance_uv_m2)
                                    for o in solution.observations}}
            for other in names:
                if other != name:
                    watched[(name, other)] = _watched(job, other, waypoints[name], worlds[other], scans, rng)
            error_t, error_r = errors(result, world.ground_truth_T_base_laser)
            error = (float(np.linalg.norm(error_t)), float(np.linalg.norm(error_r)))
            errors_of[name].append(error)
            found = f"{len(measurements)}/{len(waypoints[name])}"
            line.append(f"{name} {error[0]:5.2f} mm {error[1]:5.3f} deg ({found})")
        for (owner, other), found in watched.items():
            if other in solved_as_watcher:
                centres[owner][other] = _second_pass(found, solved_as_watcher[other])
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                if a not in results or b not in results:
                    continue
                document = pair_document(a, b, outcomes, centres, job)
                pair = document["ground_truth_error"] | {
                    "std_mm": max(document["std_translation_mm"]),
                    "std_deg": max(document["std_rotation_deg"]),
                }
                pairs.setdefault((a, b), []).append(pair)
                if "joint" in document:
                    joint[(a, b)].append(document["joint"]["ground_truth_error"] | {
                        "std_mm": max(document["joint"]["std_translation_mm"]),
                        "std_deg": max(document["joint"]["std_rotation_deg"]),
                    })
                solved = document["agreement"]
                knocked = outcomes | {b: replace(outcomes[b], T_base_laser=_moved(
                    outcomes[b].T_base_laser, args.moved_mm, args.moved_deg))}
                _, moved = pair_agreement(a, b, knocked, centres, job)
                verdicts.setdefault((a, b), []).append(
                    (solved["verdict"], moved["verdict"], solved["shared_waypoints"])
                )
                line.append(
                    f"| {a}->{b} {pair['translation_mm']:5.2f} mm {pair['rotation_deg']:5.3f} deg, "
                    f"largest axis {pair['max_axis_in_std']:.2f} std | agreement "
                    f"({solved['shared_waypoints']} shared, {len(solved.get('left_out', []))} left out): "
                    f"{solved['verdict']} "
                    f"(chi-square {solved['chi_square'] or 0:.1f}), moved {moved['verdict']} "
                    f"({moved['chi_square'] or 0:.1f} > {moved['threshold'] or 0:.1f})"
                )
        print(" ".join(line))
    print(f"\n{args.seeds} seeds, {time.perf_counter() - started:.0f} s")
    for name in names:
        values = np.array(errors_of[name]).reshape(-1, 2)
        if not len(values):
            continue
        within = np.mean((values[:, 0] <= 2.0) & (values[:, 1] <= 0.3))
        print(
            f"  {name} ({len(values)} runs): {_summary('translation', values[:, 0], 'mm')}; "
            f"{_summary('rotation', values[:, 1], 'deg')}; within 2 mm and 0.3 deg {within:.0%}"
        )
    for (a, b), values in [*pairs.items(), *((("joint " + a, b), v) for (a, b), v in joint.items())]:
        largest = np.array([v["max_axis_in_std"] for v in values])
        mahalanobis = np.array([v["mahalanobis"] for v in values])
        translation = np.array([v["translation_mm"] for v in values])
        rotation = np.array([v["rotation_deg"] for v in values])
        std_mm, std_deg = np.array([v["std_mm"] for v in values]), np.array([v["std_deg"] for v in values])
        print(
            f"  {a}->{b} ({len(values)} runs): largest std median {np.median(std_mm):.2f} mm, "
            f"{np.median(std_deg):.3f} deg; {_summary('translation', translation, 'mm')}; "
            f"{_summary('rotation', rotation, 'deg')}; largest axis error in its std: median "
            f"{np.median(largest):.2f}, max {largest.max():.2f}, "
            f"within 2.5 std {np.mean(largest <= 2.5):.0%}; "
            f"Mahalanobis (6 dof, median {np.sqrt(5.35):.2f} expected): median {np.median(mahalanobis):.2f}"
        )

    for (a, b), values in verdicts.items():
        solved, moved = Counter(v[0] for v in values), Counter(v[1] for v in values)
        shared = np.array([v[2] for v in values])
        print(
            f"  {a}<->{b} agreement ({len(values)} runs, {shared.min()}-{shared.max()} shared waypoints "
            "tested): "
            f"solved {dict(solved)}; {b} moved {args.moved_mm:g} mm / {args.moved_deg:g} deg {dict(moved)}"
        )


if __name__ == "__main__":
    main()
