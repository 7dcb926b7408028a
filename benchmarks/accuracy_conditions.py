"""Accuracy under real conditions (issue 13): short dwell, a drill bit off its nominal
axis, a scanner range offset. Offline, through the fake cell's world; not collected by pytest.

Run from the repository root::

    .venv/bin/python -m benchmarks.accuracy_conditions [--seeds 20] [--cases default-3s,drill-estimated]

Each case runs the sequencer's measurement chain (``benchmarks.dry_run_accuracy.simulate``:
noisy scans of the world at every waypoint, averaging, extraction with the background,
the two-pass solve) once per seed; every seed draws new scan noise and a new robot
absolute-accuracy error field. Cases:

* ``default-3s``, ``default-1s``, ``default-0.5s``: the default job (``paper`` preset, 20 mm
  rod) on the default scene with 3, 1 and 0.5 s dwell;
* ``drill-fixed``, ``drill-estimated``: the drill job (``examples/drill.toml``) whose real bit is
  2 mm off and tilted 1 degree from the job file's axis, solved with the job's axis and
  with ``rod.estimate_axis = true``;
* ``drill-varied-fixed``, ``drill-varied-estimated``: the same with the tool also turned about
  its axis and moved in height between waypoints (``with_varied_tool``): the drill preset
  keeps the tool's turn and the crossing's place on the bit nearly constant, which leaves
  the bit's axis nearly unobservable;
* ``offset-fixed``, ``offset-estimated``: the default job on a scanner reading 20 mm long,
  without and with ``scanner.estimate_range_offset``.

Printed per case: waypoints found, the translation (mm) and rotation (deg) error against
the truth (median, 95th percentile, max), the share of error components within 2.5
reported std, and the estimated axis / range offset against the truth in reported std.
The default (5 seeds) is a quick look; the figures in docs/solver.md use ``--seeds 20``.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.dry_run_accuracy import Trial, simulate, world_with
from fakes.scene import load_scene
from lasercal_hw.calibration.model import axis_basis, moved_rod
from lasercal_hw.config import JobConfig, load_job, with_overrides
from lasercal_hw.errors import LasercalError
from lasercal_hw.geometry import euler_zyx_to_matrix, matrix_to_pose, pose_to_matrix
from lasercal_hw.models import RodLine
from lasercal_hw.run.waypoints import job_waypoints

DRILL_JOB = Path(__file__).resolve().parent.parent / "examples" / "drill.toml"
#: The real bit against the job file's axis: 2 mm across it and 1 degree of tilt, both at 45 deg.
BIT_OFFSET_M = 0.002
BIT_TILT_DEG = 1.0
RANGE_OFFSET_M = 0.020
ROBOT_ERROR_SEED_BASE = 1000


@dataclass(frozen=True)
class Case:
    """One condition: the job solved, the rod in the world, and the world's range offset."""

    name: str
    job: JobConfig
    true_rod: RodLine
    dwell_s: float
    range_offset_m: float = 0.0
    varied_tool: bool = False


def real_bit(nominal: RodLine) -> RodLine:
    """The drill bit as it really sits: off and tilted from the job file's axis."""
    c = np.sqrt(0.5)
    step = np.array(
        [BIT_OFFSET_M * c, BIT_OFFSET_M * c, np.radians(BIT_TILT_DEG) * c, np.radians(BIT_TILT_DEG) * c]
    )
    return moved_rod(nominal, step)


def cases() -> list[Case]:
    """Every case of the module docstring."""
    default = load_job(None)
    drill = load_job(DRILL_JOB)
    bit = real_bit(drill.rod.rod_line())
    offset = with_overrides(default, {"scanner.estimate_range_offset": True})
    return [
        Case("default-3s", default, default.rod.rod_line(), 3.0),
        Case("default-1s", default, default.rod.rod_line(), 1.0),
        Case("default-0.5s", default, default.rod.rod_line(), 0.5),
        Case("drill-fixed", drill, bit, drill.dwell_s),
        Case("drill-estimated", with_overrides(drill, {"rod.estimate_axis": True}), bit, drill.dwell_s),
        Case("drill-varied-fixed", drill, bit, drill.dwell_s, varied_tool=True),
        Case(
            "drill-varied-estimated",
            with_overrides(drill, {"rod.estimate_axis": True}),
            bit,
            drill.dwell_s,
            varied_tool=True,
        ),
        Case("offset-fixed", default, default.rod.rod_line(), 3.0, RANGE_OFFSET_M),
        Case("offset-estimated", offset, default.rod.rod_line(), 3.0, RANGE_OFFSET_M),
    ]


def with_varied_tool(waypoints: np.ndarray) -> np.ndarray:
    """The waypoints with the tool turned about its z axis (-90, -30, 30, 90 deg in turn) and
    the TCP moved -2, 0, +2 cm in height in turn: the two tool motions that make the bit's
    axis observable (turning separates its offset from the scanner's position, crossing the
    plane at different points along the bit separates its tilt from its offset)."""
    varied = []
    for i, pose in enumerate(np.asarray(waypoints, dtype=float)):
        T = pose_to_matrix(pose)
        spin = np.radians((-90.0, -30.0, 30.0, 90.0)[i % 4])
        T[:3, :3] = T[:3, :3] @ euler_zyx_to_matrix(spin, 0.0, 0.0)
        T[2, 3] += 0.02 * (i % 3 - 1)
        varied.append(matrix_to_pose(T))
    return np.array(varied)


def axis_truth(case: Case) -> tuple[np.ndarray, np.ndarray]:
    """The true bit's offset (mm) and tilt (deg) along the nominal axis basis."""
    nominal = case.job.rod.rod_line()
    basis = axis_basis(nominal.direction)
    direction = case.true_rod.unit_direction()
    offset = (np.asarray(case.true_rod.origin_m) - np.asarray(nominal.origin_m)) @ basis
    tilt = np.arctan2(direction @ basis, direction @ nominal.unit_direction())
    return offset * 1e3, np.degrees(tilt)


def run_case(case: Case, seeds: int) -> None:
    """Run one case over ``seeds`` seeds and print its distributions."""
    waypoints = job_waypoints(case.job)
    if case.varied_tool:
        waypoints = with_varied_tool(waypoints)
    scene = load_scene(None)
    scans = round(case.dwell_s / scene.scanner.scan_period_s)
    trials: list[Trial] = []
    failures = 0
    started = time.perf_counter()
    for seed in range(seeds):
        world = world_with(
            scene, case.true_rod, ROBOT_ERROR_SEED_BASE + seed, bias_offset_m=case.range_offset_m
        )
        try:
            trials.append(simulate(case.job, waypoints, world, scans, np.random.default_rng(seed)))
        except LasercalError as exc:
            failures += 1
            print(f"  seed {seed}: failed: {exc}")
    print(
        f"{case.name}: {len(waypoints)} waypoints, {scans} scans each, {time.perf_counter() - started:.0f} s"
    )
    if not trials:
        return
    found = np.array([t.found for t in trials])
    print(
        f"  found: all {len(waypoints)} in {int(np.sum(found == len(waypoints)))} of {len(trials)} runs "
        f"(min {found.min()}, median {np.median(found):.0f}); {failures} runs failed"
    )
    t_err = np.array([np.linalg.norm(t.error_translation_mm) for t in trials])
    r_err = np.array([np.linalg.norm(t.error_rotation_deg) for t in trials])
    for name, values, unit in (("translation", t_err, "mm"), ("rotation", r_err, "deg")):
        p50, p95 = np.percentile(values, [50, 95])
        print(
            f"  {name} error: median {p50:.3f} {unit}, 95th percentile {p95:.3f} {unit}, "
            f"max {values.max():.3f}"
        )
    coverage = np.concatenate(
        [
            np.abs(np.concatenate([t.error_translation_mm, t.error_rotation_deg]))
            / np.concatenate([t.result.std_translation_mm, t.result.std_rotation_deg])
            for t in trials
        ]
    )
    print(
        f"  error components within 2.5 reported std: {np.mean(coverage < 2.5):.1%} "
        f"(worst {coverage.max():.2f})"
    )
    axes = [
        t.result.rod_axis for t in trials if t.result.rod_axis is not None and t.result.rod_axis.estimated
    ]
    if axes:
        offset, tilt = axis_truth(case)
        z = np.array(
            [
                np.concatenate(
                    [
                        (np.asarray(a.offset_mm) - offset) / np.asarray(a.offset_std_mm),
                        (np.asarray(a.tilt_deg) - tilt) / np.asarray(a.tilt_std_deg),
                    ]
                )
                for a in axes
            ]
        )
        errors_mm = np.array([np.linalg.norm(np.asarray(a.offset_mm) - offset) for a in axes])
        errors_deg = np.array([np.linalg.norm(np.asarray(a.tilt_deg) - tilt) for a in axes])
        print(
            f"  axis: truth offset {np.round(offset, 2)} mm tilt {np.round(tilt, 3)} deg; estimate off by "
            f"median {np.median(errors_mm):.2f} mm / {np.median(errors_deg):.3f} deg; components within "
            f"2.5 std "
            f"{np.mean(np.abs(z) < 2.5):.1%} (worst {np.abs(z).max():.2f})"
        )
    offsets = [t.result.range_offset for t in trials if t.result.range_offset is not None]
    if offsets:
        z = np.array([(o.offset_mm - case.range_offset_m * 1e3) / o.std_mm for o in offsets])
        values = np.array([o.offset_mm for o in offsets])
        print(
            f"  range offset: truth {case.range_offset_m * 1e3:.1f} mm, estimated median "
            f"{np.median(values):.2f} mm (std reported {np.median([o.std_mm for o in offsets]):.2f} mm), "
            f"within 2.5 std {np.mean(np.abs(z) < 2.5):.1%}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--seeds", type=int, default=5, help="seeds per case (the issue's figures: 20 or more)"
    )
    parser.add_argument("--cases", default=None, help="comma-separated case names (default: all)")
    args = parser.parse_args()
    chosen = cases()
    if args.cases:
        names = set(args.cases.split(","))
        unknown = names - {c.name for c in chosen}
        if unknown:
            parser.error(
                f"unknown case(s) {', '.join(sorted(unknown))}; known: {', '.join(c.name for c in chosen)}"
            )
        chosen = [c for c in chosen if c.name in names]
    for case in chosen:
        run_case(case, args.seeds)


if __name__ == "__main__":
    main()
