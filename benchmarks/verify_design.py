"""What a verify's waypoints can see, computed before any dry run (offline; not collected by pytest).

Run from the repository root::

    .venv/bin/python -m benchmarks.verify_design [--seeds 20] [--first-seed 100] [--waypoints 4]

Per seed, as ``benchmarks.verify_rates`` does: a calibration simulated in the fake world (the
job's trajectory, the two-pass solve), the verify planned from it (``plan_verify``, the time
budget), then one verify dwell at every job waypoint with the scanner unmoved, each centre
re-fitted as the calibration's second pass fitted its own (``SecondPassRefit``): the centre
covariance the drift test states at each.

For a subset of waypoints the test's information is ``F = J^T S^-1 J`` (``drift.residual_covariance``).
Printed per rule, each inside the time budget: the smallest shift / turn flagged 90 % of the
time along the weakest base axis (``test.detectable``), and the predicted share of random 3 mm
shifts and 0.3 deg turns flagged (the non-central chi-square averaged over directions; what
``verify_rates`` measures). Rules: the verify's choice (D-optimal with the centre covariance the
calibration's solver weighed each waypoint with, as ``result.json`` records it), the same with one
assumed 0.5 mm centre noise at every waypoint (the choice before 2026-11-27, and that of an older
``result.json``), and the subset with the smallest weakest-axis turn (exhaustive, the verify's own
noise).

Verify-only poses: a pose the calibration did not measure is compared with the calibration's
prediction, whose error has the calibration's covariance, so its information about a turn about
base axis k is at most ``(Sigma_cal^-1)_kk``, however steep its rod and with no robot error at
all. Printed per rule: the weakest-axis turn its subset plus that bound would reach.

Last, each waypoint's mean squared whitened residual of the unmoved scanner over the seeds
(2 where the test's stated noise is right).
"""

from __future__ import annotations

import argparse
import itertools
import time
from collections.abc import Callable

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.stats import chi2, ncx2

from benchmarks.dry_run_accuracy import measure_waypoints, world_for
from fakes.world import World
from lasercal_hw.calibration.model import whitening
from lasercal_hw.config import load_job
from lasercal_hw.errors import LasercalError
from lasercal_hw.models import FloatArray
from lasercal_hw.run.timing import visit_time_s
from lasercal_hw.run.two_pass import solve_two_pass
from lasercal_hw.run.waypoints import job_waypoints
from lasercal_hw.verify.drift import (
    DriftModel,
    detectable_moves,
    noise_blocks,
    predictions,
    residual_covariance,
)
from lasercal_hw.verify.procedure import VerifyPlan, plan_verify
from lasercal_hw.verify.selection import select_waypoints

SHIFT_M = 0.003
TURN_RAD = float(np.radians(0.3))
DIRECTIONS = 2000


def needed_noncentrality(dof: int, model: DriftModel) -> float:
    """The non-centrality at which the test on ``dof`` values flags with its detection
    probability (``detectable_moves`` for a unit information on every parameter)."""
    threshold = float(chi2.ppf(1.0 - model.false_alarm_rate, dof))
    unit = np.eye(6).reshape(1, 6, 6)
    return float(
        detectable_moves(unit, cho_factor(np.eye(6)), threshold, dof, model.detection_probability)[0] ** 2
    )


def flagged_share(
    information: FloatArray, threshold: float, dof: int, directions: FloatArray
) -> tuple[float, float]:
    """Predicted share of random 3 mm shifts and 0.3 deg turns flagged."""
    shift = np.einsum("ni,ij,nj->n", directions, information[:3, :3], directions) * SHIFT_M**2
    turn = np.einsum("ni,ij,nj->n", directions, information[3:, 3:], directions) * TURN_RAD**2
    return float(ncx2.sf(threshold, dof, shift).mean()), float(ncx2.sf(threshold, dof, turn).mean())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=100)
    parser.add_argument("--waypoints", type=int, default=None, help="default: the job's verify.waypoints")
    args = parser.parse_args()

    job = load_job(None)
    poses = job_waypoints(job)
    count = args.waypoints or job.verify.waypoints
    scans = round(job.dwell_s / World.from_scene(None).geometry.scan_period_s)
    calibration_s = visit_time_s(job, poses) or np.nan
    budget_s = job.verify.max_time_fraction * calibration_s
    rng_directions = np.random.default_rng(0).normal(size=(DIRECTIONS, 3))
    directions = rng_directions / np.linalg.norm(rng_directions, axis=1)[:, None]
    rows: dict[str, list[list[float]]] = {}
    whitened: list[FloatArray] = []
    started = time.perf_counter()
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        rng = np.random.default_rng(seed)
        world = world_for(job, None, robot_error_seed=1000 + seed)
        measurements, background = measure_waypoints(job, poses, world, scans, rng)
        try:
            solution = solve_two_pass(measurements, job, background)
        except LasercalError as exc:
            print(f"seed {seed}: calibration failed: {exc}")
            continue
        result = solution.result
        plan = plan_verify(
            job,
            result.matrix(),
            np.asarray(result.covariance),
            result.residuals,
            poses,
            count=count,
            budget_s=budget_s,
            range_error=result.range_offset,
            refit=solution.refit,
            rod=result.estimated_rod(job.rod.rod_line()),
        )
        seen, background = measure_waypoints(plan.job, plan.waypoints, world, scans, rng)
        refitted, _ = plan.refit.centres(seen, background)
        found = [m.index for m in refitted]
        if not set(plan.selection.indices) <= set(found):
            print(f"seed {seed}: the rod was not found at every chosen waypoint; left out")
            continue
        centres = np.array([m.centre.centre_uv_m for m in refitted])
        stated = np.array([m.centre.covariance_uv_m2 for m in refitted])
        noise = np.array([m.centre.dwell_noise_covariance_uv_m2() for m in refitted])
        line = [f"seed {seed:3d}"]
        chosen, information_of = rules(plan, found, stated, noise, count, budget_s)
        for name, subset in chosen:
            information, dof = information_of(subset)
            threshold = float(chi2.ppf(1.0 - plan.model.false_alarm_rate, dof))
            needed = needed_noncentrality(dof, plan.model)
            weakest = np.sqrt(needed / np.diag(information))
            p_shift, p_turn = flagged_share(information, threshold, dof, directions)
            share = (
                visit_time_s(plan.job, plan.waypoints[[found[k] for k in subset]]) or np.nan
            ) / calibration_s
            bound = np.sqrt(
                needed / (np.diag(information)[3:] + np.diag(np.linalg.inv(plan.model.covariance))[3:])
            )
            rows.setdefault(name, []).append(
                [
                    weakest[:3].max() * 1e3,
                    np.degrees(weakest[3:].max()),
                    p_shift,
                    p_turn,
                    share,
                    np.degrees(bound.max()),
                ]
            )
            line.append(f"{name}: {sorted(found[k] for k in subset)} {np.degrees(weakest[3:].max()):.3f} deg")
        print(" | ".join(line), flush=True)
        crossing, _, slope = predictions(plan.model, plan.waypoints[found])
        reference = plan.reference[found]
        visited = np.isfinite(reference).all(axis=1)
        residual = centres - crossing - np.where(visited[:, None], reference, 0.0)
        blocks = noise_blocks(plan.model, slope, stated, visited, noise)
        per_waypoint = np.full(len(poses), np.nan)
        per_waypoint[found] = [
            float(r @ np.linalg.solve(b, r)) for r, b in zip(residual, blocks, strict=True)
        ]
        whitened.append(per_waypoint)

    print(f"\n{len(whitened)} seeds in {time.perf_counter() - started:.0f} s, {count} verify waypoints")
    for name, values in rows.items():
        a = np.array(values)
        print(
            f"  {name}: weakest shift median {np.median(a[:, 0]):.2f} mm, weakest turn median "
            f"{np.median(a[:, 1]):.3f} deg (max {a[:, 1].max():.3f}); predicted flagged: 3 mm shift "
            f"{a[:, 2].mean():.1%}, 0.3 deg turn {a[:, 3].mean():.1%}; time share median "
            f"{np.median(a[:, 4]):.3f} (max {a[:, 4].max():.3f}); with any number of verify-only poses "
            f"at best {np.median(a[:, 5]):.3f} deg"
        )
    means = np.nanmean(np.array(whitened), axis=0)
    print("  unmoved, mean squared whitened residual per waypoint (2 if the stated noise is right):")
    print("   ", " ".join(f"{i}:{m:.1f}" for i, m in enumerate(means)))


def rules(
    plan: VerifyPlan,
    found: list[int],
    stated: FloatArray,
    noise: FloatArray,
    count: int,
    budget_s: float,
) -> tuple[list[tuple[str, tuple[int, ...]]], Callable[[tuple[int, ...]], tuple[FloatArray, int]]]:
    """(name, subset as positions in ``found``) per rule, and a subset's information and dof."""
    model = plan.model
    poses = plan.waypoints[found]
    _, jac, slope = predictions(model, poses)
    visited = np.isfinite(plan.reference[found]).all(axis=1)

    def information_of(subset: tuple[int, ...]) -> tuple[FloatArray, int]:
        s = list(subset)
        total = cho_factor(residual_covariance(model, jac[s], slope[s], stated[s], visited[s], noise[s]))
        j = jac[s].reshape(-1, 6)
        return j.T @ cho_solve(total, j), 2 * len(s)

    def alone(centre: FloatArray, drawn: FloatArray) -> FloatArray:
        white = whitening(noise_blocks(model, slope, centre, visited, drawn)) @ jac
        return np.swapaxes(white, 1, 2) @ white

    subsets = list(itertools.combinations(range(len(found)), count))

    def first_in_budget(score: FloatArray) -> tuple[int, ...]:
        for k in np.argsort(score):
            seconds = visit_time_s(plan.job, poses[list(subsets[k])])
            if seconds is not None and seconds <= budget_s:
                return subsets[k]
        raise LasercalError("no subset of the job's waypoints fits the verify's time budget")

    noise_each = alone(stated, noise)
    by_noise = np.array([noise_each[list(s)].sum(axis=0) for s in subsets])
    weakest_turn = np.sqrt(1.0 / np.einsum("nkk->nk", by_noise)[:, 3:]).max(axis=1)
    assumed = select_waypoints(
        model,
        plan.waypoints,
        count,
        np.isfinite(plan.reference).all(axis=1),
        time_of=lambda indices: visit_time_s(plan.job, plan.waypoints[indices]),
        budget_s=budget_s,
    )
    named = [("verify's choice", plan.selection.indices), ("D-optimal, 0.5 mm assumed", assumed.indices)]
    return [
        *((name, tuple(map(found.index, chosen))) for name, chosen in named if set(chosen) <= set(found)),
        ("smallest weakest turn", first_in_budget(weakest_turn)),
    ], information_of


if __name__ == "__main__":
    main()
