"""False-alarm and detection rates of ``lasercal verify``, and its time against the
calibration's (offline; not collected by pytest).

Run from the repository root::

    .venv/bin/python -m benchmarks.verify_rates [--config FILE] [--scene FILE] [--bit-off] [--any-turn]
        [--seeds 50] [--waypoints 5]

Per seed, no devices and no sockets, all through the product's own code: a calibration is
simulated in the fake world (``benchmarks.dry_run_accuracy.simulate``: the job's
trajectory, averaged noisy scans, ``find_rod_centre``, the two-pass solve; a new robot
error field per seed; ``--bit-off``: the world's rod 2 mm off and 1 deg tilted from the job's
axis, ``benchmarks.accuracy_conditions.real_bit``, for a job that estimates it; ``--any-turn``:
the scene's bit turned in its chuck by an angle drawn per seed), then the verify's waypoints
are chosen among those the calibration visited (a spun drill job's spin and turned waypoints
too) as ``lasercal verify`` does (``verify.procedure.plan_verify``) and visited three times in
the same robot's world: scanner unmoved, scanner shifted 3 mm in a random direction, scanner
turned 0.3 deg about a random axis through its origin.  Each visit: a background at the
retract pose, new noisy scans, ``find_rod_centre``, the re-fit as the calibration's second
pass fitted its own centres and the drift test (``verify.procedure.refit_and_test``), and the verdict
(``verify.verdict.decide``, the job's tolerance).

Printed: per seed the chi-square values; the unmoved chi-square's median and mean against its
degrees of freedom; the false-alarm rate (unmoved scanner flagged,
with a 95 % Clopper-Pearson interval) against the stated rate; the detection rates (the
test flags the moved scanner); the smallest move the test detects 90 % of the time in
its weakest direction (its power, ``DriftTest.weakest``; above the tolerance the verdict is
``inconclusive``), and along its weakest base axis (the verdict's figure until 2026-11-29); the
seeds whose moved scanner was called ``ok``; the
coverage of the estimated move (|error| / std per component) and the verdict counts (a
``recalibrate`` because no rigid scanner move explains the residuals counted apart); and
the time of the verify (its motion and dwell as ``run.timing.visit_time_s`` estimates them: the
move from the UR home posture to the retract pose, the background, the moves' trapezoids at the
job's caps between UR5 inverse kinematics solutions, each waypoint's settle margin, dwell and
closing scan) against the calibration's, estimated the same way.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.stats import beta

from benchmarks.dry_run_accuracy import measure_waypoints
from benchmarks.verify_trials import VerifyBench, add_job_arguments
from fakes.world import World
from lasercal_hw.errors import LasercalError
from lasercal_hw.geometry import matrix_to_euler_zyx, matrix_to_rotvec, rotvec_to_matrix
from lasercal_hw.run.waypoints import planned_waypoints
from lasercal_hw.verify.drift import DriftTest
from lasercal_hw.verify.procedure import VerifyPlan, refit_and_test
from lasercal_hw.verify.verdict import decide

SHIFT_M = 0.003
TURN_DEG = 0.3


def move_between(T_from: np.ndarray, T_to: np.ndarray) -> np.ndarray:
    """The correction (dt m, e rad about base axes) that takes ``T_from`` to ``T_to``."""
    return np.concatenate([T_to[:3, 3] - T_from[:3, 3], matrix_to_rotvec(T_to[:3, :3] @ T_from[:3, :3].T)])


def moved_world(world: World, rng: np.random.Generator, shift_m: float, turn_deg: float) -> World:
    """The same world with the scanner shifted and turned about a random direction/axis
    through its origin."""
    T = world.ground_truth_T_base_laser
    direction = rng.normal(size=3)
    axis = rng.normal(size=3)
    dt = shift_m * direction / np.linalg.norm(direction)
    e = np.radians(turn_deg) * axis / np.linalg.norm(axis)
    rotation = rotvec_to_matrix(e) @ T[:3, :3]
    scanner = world.scene.scanner.model_copy(
        update={
            "translation_m": (T[:3, 3] + dt).tolist(),
            "euler_zyx_deg": np.degrees(matrix_to_euler_zyx(rotation)).tolist(),
        }
    )
    return World(world.scene.model_copy(update={"scanner": scanner}))


def visit(plan: VerifyPlan, world: World, scans: int, rng: np.random.Generator) -> DriftTest | None:
    """One offline verify: background, dwell at each chosen waypoint, extraction looking
    where the calibration predicts (the verify job's nominal pose), re-fit, test."""
    poses = plan.waypoints[plan.selection.indices]
    measurements, background = measure_waypoints(plan.job, poses, world, scans, rng)
    return refit_and_test(plan, measurements, background)[0]


def clopper_pearson(hits: int, trials: int) -> tuple[float, float]:
    """95 % confidence interval of a rate."""
    low = beta.ppf(0.025, hits, trials - hits + 1) if hits > 0 else 0.0
    high = beta.ppf(0.975, hits + 1, trials - hits) if hits < trials else 1.0
    return float(low), float(high)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_job_arguments(parser)
    parser.add_argument("--seeds", type=int, default=50)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument(
        "--no-reference",
        action="store_true",
        help="ignore the calibration's residuals at its own waypoints (model prediction only)",
    )
    args = parser.parse_args()

    bench = VerifyBench.from_args(args)
    job, poses, count, scans = bench.job, bench.poses, bench.count, bench.scans
    settings = job.verify
    visited = f"{len(planned_waypoints(job))} calibration waypoints"
    if job.trajectory.flute_phase_deg is not None:
        visited += f" (a spin of {len(poses)}, then the job's turned)"
    print(
        f"{visited}, verify with {count}, {scans} scans per waypoint, "
        f"false-alarm rate {settings.false_alarm_rate:.0%}, tolerance {settings.tolerance_mm:g} mm "
        f"{settings.tolerance_deg:g} deg, robot sigma {job.robot.position_accuracy_mm:g} mm"
    )
    outcomes: dict[str, list[DriftTest | None]] = {"unmoved": [], "shifted": [], "turned": []}
    truths: dict[str, list[np.ndarray]] = {name: [] for name in outcomes}
    verdicts: dict[str, dict[str, int]] = {name: {} for name in outcomes}
    ratios = []
    missed_ok: list[str] = []
    started = time.perf_counter()
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        rng = np.random.default_rng(seed)
        world = bench.world(seed)
        try:
            calibrated = bench.calibrate_and_plan(world, rng, reference=not args.no_reference)
        except LasercalError as exc:
            print(f"seed {seed}: calibration failed: {exc}")
            continue
        plan = calibrated.plan
        selection = plan.selection
        shifted = moved_world(world, rng, SHIFT_M, 0.0)
        turned = moved_world(world, rng, 0.0, TURN_DEG)
        line = [f"seed {seed:3d}: waypoints {selection.indices}"]
        for name, case_world in (("unmoved", world), ("shifted", shifted), ("turned", turned)):
            test = visit(plan, case_world, scans, rng)
            outcomes[name].append(test)
            verdict = decide([], test, settings.tolerance_mm, settings.tolerance_deg)
            rigid = "no rigid scanner move" not in verdict.reason
            kind = verdict.status + ("" if rigid else " (not a rigid move)")
            verdicts[name][kind] = verdicts[name].get(kind, 0) + 1
            # With the calibration's residuals the correction is the move since the calibration;
            # from the model alone it is the move away from the active (imperfect) transform.
            before = plan.model.T_base_laser if args.no_reference else world.ground_truth_T_base_laser
            truths[name].append(move_between(before, case_world.ground_truth_T_base_laser))
            line.append(f"{name} chi2 {test.chi_square:6.1f}" if test else f"{name} not measured")
            if name != "unmoved" and verdict.status == "ok":
                missed_ok.append(f"{seed} ({name})")
        ratios.append((selection.estimated_time_s or np.nan) / calibrated.calibration_s)
        print(" | ".join(line), f"| time ratio {ratios[-1]:.3f}")

    print(f"\n{len(outcomes['unmoved'])} seeds in {time.perf_counter() - started:.0f} s")
    for name in outcomes:
        tests = outcomes[name]
        flagged = sum(1 for t in tests if t is None or t.changed)
        low, high = clopper_pearson(flagged, len(tests))
        label = "false-alarm rate (unmoved)" if name == "unmoved" else f"detection rate ({name})"
        print(
            f"  {label}: {flagged}/{len(tests)} = {flagged / len(tests):.1%} (95 % CI {low:.1%}-{high:.1%})"
            f"; verdicts {verdicts[name]}"
        )
    measured = [t for t in outcomes["unmoved"] if t is not None]
    if measured:
        chi_square = np.array([t.chi_square for t in measured])
        print(
            f"  unmoved chi-square: median {np.median(chi_square):.2f}, mean {chi_square.mean():.2f}, max "
            f"{chi_square.max():.2f} on {measured[0].dof} dof (honest: mean {measured[0].dof})"
        )
        shift = np.array([t.weakest.shift_mm for t in measured])
        turn = np.array([t.weakest.turn_deg for t in measured])
        print(
            f"  smallest move detected {measured[0].detection_probability:.0%} of the time, weakest "
            f"direction: shift median {np.median(shift):.2f} mm (max {shift.max():.2f}), turn median "
            f"{np.median(turn):.3f} deg (max {turn.max():.3f}); tolerance {settings.tolerance_mm:g} mm "
            f"{settings.tolerance_deg:g} deg"
        )
        axis_shift = np.array([max(t.detectable_shift_mm) for t in measured])
        axis_turn = np.array([max(t.detectable_turn_deg) for t in measured])
        print(
            f"  the same along / about the weakest base axis (the verdict's figure before 2026-11-29): "
            f"shift median {np.median(axis_shift):.2f} mm (max {axis_shift.max():.2f}), turn median "
            f"{np.median(axis_turn):.3f} deg (max {axis_turn.max():.3f})"
        )
    print(f"  moved scanners called ok: {', '.join(missed_ok) or 'none'}")
    print("  estimated move against the true move:")
    for name, truth_list in truths.items():
        coverage = [
            np.abs(t.correction - truth) / np.sqrt(np.diag(t.correction_covariance))
            for t, truth in zip(outcomes[name], truth_list, strict=True)
            if t is not None
        ]
        errors = np.array(
            [
                [
                    np.linalg.norm(t.correction[:3] - truth[:3]) * 1e3,
                    np.degrees(
                        np.linalg.norm(
                            matrix_to_rotvec(
                                rotvec_to_matrix(t.correction[3:]).T @ rotvec_to_matrix(truth[3:])
                            )
                        )
                    ),
                ]
                for t, truth in zip(outcomes[name], truth_list, strict=True)
                if t is not None
            ]
        )
        values = np.concatenate(coverage)
        print(
            f"    {name}: error median {np.median(errors[:, 0]):.2f} mm "
            f"{np.median(errors[:, 1]):.3f} deg; |error|/std per component: median {np.median(values):.2f}, "
            f"within 2 std {np.mean(values < 2.0):.1%}"
        )
    ratio = np.array(ratios)
    print(
        f"  verify time / calibration time: median {np.median(ratio):.3f}, max {ratio.max():.3f} "
        "(target <= 0.25)"
    )


if __name__ == "__main__":
    main()
