"""The calibration's error budget: what each source of error contributes to the pose error.

Run from the repository root::

    .venv/bin/python -m benchmarks.error_budget [--seeds 20] [--first-seed 0]
        [--cases default-3s,designed-1s] [--variants all,robot-off,...]

Offline, the chain of ``benchmarks.accuracy_conditions`` (the sequencer's dwell, extraction
and two-pass solve on the fake world, physical scanner model) for a case, once as it is and
once per *variant* that switches one source of error off (or changes what the solver is
told), on the same seeds: the same scan noise draws and robot error fields, so a variant's
difference to ``as-is`` is that source's share and not a new draw. Variants:

* ``as-is``: everything on (the case as ``accuracy_conditions`` runs it);
* ``robot-off``: the robot's absolute-accuracy error field off (the job still states 1 mm);
* ``bias-off``: the physical scanner's range bias off (near-range term, the unit's curve,
  range walk with intensity), the curve still estimated as the job says;
* ``bias-off-fixed``: the same, and the solver told the truth: no curve estimated (what
  estimating the curve costs is ``bias-off`` against this);
* ``noise/10``: the per-reading range noise a tenth (noise floor and shot noise);
* ``dwell-x4``: four times the dwell;
* ``axis-estimated``: the rod's axis estimated (``rod.estimate_axis = true``; the rod is
  where the job says);
* ``robot-stated-0.58``: the job states the robot's accuracy as the dry run's field has it
  (0.58 mm per axis, ``robot.position_accuracy_mm``) instead of 1 mm;
* ``robot-only``: the robot's error field alone (bias off, noise/10, no curve estimated);
* ``floor``: all of those off (bias, robot, noise/10, no curve): what is left is the
  footprint's mixed pixels and the extraction's own geometry.

Printed per case and variant: translation (mm) and rotation (deg) error median, 95th
percentile and RMS over the seeds, and the share of the as-is mean squared error that goes
away with the variant (``1 - RMS^2 / RMS^2(as-is)``; negative: the variant is worse).
First, per case, the trajectory's own limit: the 95th percentile of the pose error an
efficient estimator would reach (the Cramér-Rao bound, the solver's Fisher information at
the truth) with the robot's error alone (0.58 mm per axis, taken independent per waypoint),
the centres' alone (0.5 mm per axis) and both, for 0 to 4 terms of the range error curve; for
a job that estimates the rod's axis (the drill cases) with the axis's 4 parameters unknown too,
and for a twist drill (``rod.fluted``) also with the flute phase pass's allowance in every
centre (0.25 r per axis, ``run/flute_phase``). ``--waypoints-file``: the drill cases on another
waypoint file, its bound and variants (a design's, before it is shipped). Variant ``axis-known``
(the drill cases): the solver told the real bit's axis, not estimating it.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.accuracy_conditions import (
    ROBOT_ERROR_SEED_BASE,
    Case,
    cases,
    designed_waypoints,
    with_waypoints_file,
)
from benchmarks.dry_run_accuracy import Trial, simulate, world_with
from fakes.scene import Scene, load_scene
from lasercal_hw.calibration.model import extended_fisher_information
from lasercal_hw.config import JobConfig, with_overrides
from lasercal_hw.errors import LasercalError
from lasercal_hw.geometry import pose_to_matrix
from lasercal_hw.models import RodLine
from lasercal_hw.run.flute_phase import MODEL_ALLOWANCE_RADIUS_FRACTION
from lasercal_hw.run.waypoints import job_waypoints, planned_waypoints

#: The dry run's robot error field per axis (``NoiseSettings.robot_position_error_m``), in mm.
FIELD_PER_AXIS_MM = 0.58
#: Centre noise per axis of the bound's rows (a 3 s dwell's centres: 0.3-0.9 mm), in m.
BOUND_CENTRE_SIGMA_M = 0.0005


@dataclass(frozen=True)
class Variant:
    """One switch: how it changes the scene, the job and the dwell."""

    name: str
    scene: Callable[[Scene], Scene] = lambda s: s
    job: Callable[[JobConfig], JobConfig] = lambda j: j
    dwell_factor: float = 1.0
    #: The job told the case's real rod as its axis (not estimating it), before ``job``.
    tells_axis: bool = False


def _robot_off(scene: Scene) -> Scene:
    noise = scene.noise.model_copy(update={"robot_position_error_m": 0.0, "robot_rotation_error_deg": 0.0})
    return scene.model_copy(update={"noise": noise})


def _bias_off(scene: Scene) -> Scene:
    off = {"near_bias_m": 0.0, "unit_bias_m": 0.0, "walk_m_per_efold": 0.0}
    physics = scene.physics.model_copy(update=off)
    return scene.model_copy(update={"physics": physics})


def _quiet(scene: Scene) -> Scene:
    p = scene.physics
    tenth = {"noise_floor_m": p.noise_floor_m / 10.0, "noise_at_reference_m": p.noise_at_reference_m / 10.0}
    physics = p.model_copy(update=tenth)
    return scene.model_copy(update={"physics": physics})


def _no_curve(job: JobConfig) -> JobConfig:
    return with_overrides(job, {"scanner.estimate_range_offset": False})


def _all(*changes: Callable) -> Callable:
    def apply(value):  # a scene or a job
        for change in changes:
            value = change(value)
        return value

    return apply


def _told(rod: RodLine) -> Callable[[JobConfig], JobConfig]:
    """The job told ``rod`` (the real bit) as its rod's axis, not estimating it."""

    def change(job: JobConfig) -> JobConfig:
        told = {
            "rod.origin_m": np.asarray(rod.origin_m, dtype=float).tolist(),
            "rod.direction": np.asarray(rod.direction, dtype=float).tolist(),
            "rod.estimate_axis": False,
        }
        return with_overrides(job, told)

    return change


VARIANTS = (
    Variant("as-is"),
    Variant("robot-off", scene=_robot_off),
    Variant("bias-off", scene=_bias_off),
    Variant("bias-off-fixed", scene=_bias_off, job=_no_curve),
    Variant("noise/10", scene=_quiet),
    Variant("dwell-x4", dwell_factor=4.0),
    Variant("axis-estimated", job=lambda j: with_overrides(j, {"rod.estimate_axis": True})),
    Variant(
        "robot-stated-0.58",
        job=lambda j: with_overrides(j, {"robot.position_accuracy_mm": FIELD_PER_AXIS_MM}),
    ),
    Variant("robot-only", scene=_all(_bias_off, _quiet), job=_no_curve),
    Variant("floor", scene=_all(_bias_off, _quiet, _robot_off), job=_no_curve),
    Variant("axis-known", tells_axis=True),
)


def case_job(case: Case, variant: Variant) -> JobConfig:
    """The job ``variant`` solves on ``case`` (told the case's real rod where it ``tells_axis``)."""
    job = _told(case.true_rod)(case.job) if variant.tells_axis else case.job
    return variant.job(job)


def run_variant(case: Case, variant: Variant, seeds: range) -> tuple[np.ndarray, np.ndarray, int]:
    """Translation (mm) and rotation (deg) error norms over ``seeds``, and the runs refused."""
    scene = variant.scene(load_scene(case.scene_path).model_copy(update={"model": "physical"}))
    job = case_job(case, variant)
    waypoints = designed_waypoints(case.job, scene) if case.designed else job_waypoints(case.job)
    scans = round(case.dwell_s * variant.dwell_factor / scene.scanner.scan_period_s)
    trials: list[Trial] = []
    refused = 0
    for seed in seeds:
        world = world_with(scene, case.true_rod, ROBOT_ERROR_SEED_BASE + seed)
        try:
            trials.append(simulate(job, waypoints, world, scans, np.random.default_rng(seed)))
        except LasercalError:
            refused += 1
    t_err = np.array([np.linalg.norm(t.error_translation_mm) for t in trials])
    r_err = np.array([np.linalg.norm(t.error_rotation_deg) for t in trials])
    return t_err, r_err, refused


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if values.size else float("nan")


def bound_p95(
    case: Case, waypoints: np.ndarray, T_base_laser: np.ndarray, centre_m: float, robot_m: float, terms: int
) -> tuple[float, float]:
    """95th percentile of the translation (mm) and rotation (deg) error norms under the
    Cramér-Rao bound of ``waypoints`` with ``terms`` range curve terms and, when the case's job
    estimates it, the rod's axis unknown too (at the case's real rod; sampled: 200000 draws)."""
    tcp = pose_to_matrix(np.asarray(waypoints, dtype=float))
    covariance = np.broadcast_to(np.eye(2) * max(centre_m, 1e-6) ** 2, (len(tcp), 2, 2)).copy()
    fisher = extended_fisher_information(
        T_base_laser[:3, :3], T_base_laser[:3, 3], tcp, case.true_rod, covariance, robot_m,
        np.zeros(max(terms, 1)) if terms else 0.0, with_axis=estimates_axis(case.job), with_offset=terms,
    )
    pose = np.linalg.inv(fisher)[:6, :6]
    draws = np.random.default_rng(0).normal(size=(200_000, 3))
    t = np.linalg.norm(draws @ np.linalg.cholesky(pose[:3, :3]).T, axis=1)
    r = np.linalg.norm(draws @ np.linalg.cholesky(pose[3:, 3:]).T, axis=1)
    return float(np.percentile(t, 95)) * 1e3, float(np.degrees(np.percentile(r, 95)))


def estimates_axis(job: JobConfig) -> bool:
    """Whether the job estimates the rod's axis with the pose (``rod.estimate_axis``)."""
    return job.rod.estimate_axis is not False


def bound_rows(job: JobConfig) -> list[tuple[str, float, float]]:
    """The bound's noise rows: label, centre sigma per axis (m), robot sigma per axis (m)."""
    robot_m = FIELD_PER_AXIS_MM / 1e3
    rows = [
        ("robot 0.58 mm alone", 0.0, robot_m),
        ("centres 0.5 mm alone", BOUND_CENTRE_SIGMA_M, 0.0),
        ("both", BOUND_CENTRE_SIGMA_M, robot_m),
    ]
    if job.rod.fluted:
        allowance_m = MODEL_ALLOWANCE_RADIUS_FRACTION * job.rod.radius_m
        widened_m = float(np.hypot(BOUND_CENTRE_SIGMA_M, allowance_m))
        rows.append((f"both, centres {widened_m * 1e3:.2f} mm (the flute allowance)", widened_m, robot_m))
    return rows


def print_bound(case: Case) -> None:
    """The trajectory's Cramér-Rao limit (the module docstring) as a table."""
    scene = load_scene(case.scene_path)
    waypoints = designed_waypoints(case.job, scene) if case.designed else planned_waypoints(case.job)
    truth = world_with(scene, case.true_rod, 0).ground_truth_T_base_laser
    unknowns = "the pose and the rod's axis" if estimates_axis(case.job) else "the pose"
    source = case.job.trajectory.waypoints_file or ("designed" if case.designed else "the preset")
    print(
        f"\n{case.name}: Cramér-Rao 95th percentile of {len(waypoints)} waypoints ({source}), {unknowns} "
        "unknown, translation (mm) / rotation (deg), by curve terms"
    )
    print("| noise | " + " | ".join(f"{k} terms" for k in range(5)) + " |")
    print("| --- |" + " ---: |" * 5)
    for label, centre_m, robot in bound_rows(case.job):
        cells = [bound_p95(case, waypoints, truth, centre_m, robot, k) for k in range(5)]
        print(f"| {label} | " + " | ".join(f"{t:.2f} / {r:.3f}" for t, r in cells) + " |")


def print_budget(case: Case, variants: list[Variant], seeds: range) -> None:
    """Run every variant of ``case`` on ``seeds`` and print the table (as-is first)."""
    print(f"\n{case.name}: seeds {seeds.start}-{seeds.stop - 1}, physical scanner")
    print(
        "| variant | translation median / p95 / RMS (mm) | share of MSE | rotation median / p95 / RMS (deg) "
        "| share of MSE | refused | time |"
    )
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    reference: tuple[float, float] | None = None
    for variant in variants:
        started = time.perf_counter()
        t_err, r_err, refused = run_variant(case, variant, seeds)
        rms = (_rms(t_err), _rms(r_err))
        reference = reference or rms
        cells = []
        for values, value_rms, ref in ((t_err, rms[0], reference[0]), (r_err, rms[1], reference[1])):
            p50, p95 = np.percentile(values, [50, 95]) if values.size else (np.nan, np.nan)
            digits = 2 if values is t_err else 3
            cells.append(f"{p50:.{digits}f} / {p95:.{digits}f} / {value_rms:.{digits}f}")
            cells.append(f"{1.0 - (value_rms / ref) ** 2:+.0%}")
        print(
            f"| {variant.name} | {' | '.join(cells)} | {refused} | {time.perf_counter() - started:.0f} s |",
            flush=True,
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20, help="seeds per variant (default 20)")
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--cases", default="default-3s,designed-1s", help="accuracy_conditions case names")
    parser.add_argument("--variants", default=None, help="comma-separated variant names (default: all)")
    parser.add_argument("--bound-only", action="store_true", help="print the Cramér-Rao limit alone")
    parser.add_argument(
        "--waypoints-file", type=Path, default=None, help="the drill cases visit this file, not the job's"
    )
    args = parser.parse_args()
    if args.waypoints_file is not None and not args.waypoints_file.is_file():
        parser.error(f"--waypoints-file {args.waypoints_file} does not exist; give a CSV of waypoints")
    known_cases = {c.name: c for c in cases()}
    if args.waypoints_file is not None:
        known_cases = {n: with_waypoints_file(c, args.waypoints_file) for n, c in known_cases.items()}
    known_variants = {v.name: v for v in VARIANTS}
    names = args.cases.split(",")
    wanted = args.variants.split(",") if args.variants else list(known_variants)
    unknown = [n for n in names if n not in known_cases] + [v for v in wanted if v not in known_variants]
    if unknown:
        parser.error(
            f"unknown case or variant {', '.join(unknown)}; cases: {', '.join(known_cases)}; "
            f"variants: {', '.join(known_variants)}"
        )
    variants = [known_variants["as-is"]] + [known_variants[v] for v in wanted if v != "as-is"]
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    for name in names:
        print_bound(known_cases[name])
        if not args.bound_only:
            print_budget(known_cases[name], variants, seeds)


if __name__ == "__main__":
    main()
