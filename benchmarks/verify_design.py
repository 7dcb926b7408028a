"""What a verify's waypoints can see, computed before any dry run (offline; not collected by pytest).

Run from the repository root::

    .venv/bin/python -m benchmarks.verify_design [--config FILE] [--scene FILE] [--bit-off] [--any-turn]
        [--seeds 20] [--first-seed 100] [--waypoints 4] [--slack-dwell]

Per seed, as ``benchmarks.verify_rates`` does (``benchmarks.verify_trials``, the same job, scene
and world): a calibration simulated in the fake world (the job's trajectory, the two-pass solve),
the verify planned from it (``plan_verify``, the time budget), then one verify dwell at every job
waypoint with the scanner unmoved, each centre re-fitted as the calibration's second pass fitted
its own (``SecondPassRefit``): the centre covariance the drift test states at each.

For a subset of waypoints the test's information is ``F = J^T S^-1 J``
(``drift.residual_covariance``). Where the calibration's flute phase pass was kept (a twist
drill), a move also changes the section's offsets at every crossing (``verify.helix``): ``J``
then carries that change, for a positive and for a negative move apart (the weaker counted, as
``test.detectable`` does), and the share of random moves flagged takes each move's exact change
(``helix.offset_change_m``: the non-centrality ``|J x + h(x)|^2`` over ``S``). Printed per rule,
each inside the time budget: the smallest shift
/ turn flagged 90 % of the time in the direction the test sees least (``test.detectable``'s
``weakest_*``, what the verdict weighs) and how many seeds' unmoved verify would say ``ok`` there
(both under the job's tolerances), the same along the weakest base axis, the turn about each base
axis, and the predicted share of random 3 mm shifts and 0.3 deg turns flagged (the
non-central chi-square averaged over directions; what ``verify_rates`` measures) and that share
again if the noise is as large as the unmoved dwells at those waypoints show (their chi-square's
mean over its dof ``k``: the statistic is then ``k`` times a non-central chi-square of ``lambda /
k``; a noise stated too large costs power). Also printed per rule: the estimated move's largest
std of a shift and of a turn component at the verify dwell's noise. Rules: the verify's choice
(``plan_verify``: with the centre covariance the calibration's solver weighed each waypoint with,
as ``result.json`` records it, exchanges that raise what the verdict weighs,
``selection.tolerance_noncentrality``, up to its aim, ``VERDICT_MARGIN`` times what the test
needs, then the determinant), the same with the other aims of ``AIM_MARGINS`` (``inf``: the
verdict's figure alone), the D-optimal choice on that record (the verify's before 2026-11-29) and
with one assumed 0.5 mm centre noise at every waypoint (before 2026-11-27, and that of an older
``result.json``), and, over every subset of the verify's size, the verify's aim (what its
exchanges should find), the one best for the verdict and the one that flags the most random 0.3
deg turns, on the centre covariance the calibration recorded (what the verify knows when it
chooses) and on the verify dwell's own noise (known only after it).
``--slack-dwell``: also the verify's choice with its dwell lengthened until the verify takes its
whole time budget, measured at that dwell: the test then counts that dwell's noise and the
calibration's recorded one (``noise_covariance_uv_mm2``) where it counts the verify's twice, and
its mean squared whitened residual (2 where honest) is printed beside the 3 s dwell's at the same
waypoints.

Verify-only poses: a pose the calibration did not measure is compared with the calibration's
prediction, whose error has the calibration's covariance, so its information about a turn about
base axis k is at most ``(Sigma_cal^-1)_kk``, however steep its rod and with no robot error at
all. Printed per rule: the weakest-axis turn its subset plus that bound would reach.

Last, per waypoint over the seeds: its mean squared whitened residual of the unmoved scanner (2
where the test's stated noise is right) and the turn about base x, y and z it alone would see 9
times in 10 in a 4-waypoint test (median; which waypoints see which turn).
"""

from __future__ import annotations

import argparse
import itertools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.stats import chi2, ncx2

from benchmarks.dry_run_accuracy import measure_waypoints
from benchmarks.verify_trials import CalibratedSeed, VerifyBench, add_job_arguments
from fakes.world import World
from lasercal_hw.errors import LasercalError
from lasercal_hw.models import FloatArray
from lasercal_hw.run.timing import visit_time_s
from lasercal_hw.verify.active import recorded_centre_covariances
from lasercal_hw.verify.drift import (
    DriftModel,
    needed_noncentrality,
    noise_blocks,
    predictions,
    residual_covariance,
    weakest_moves,
)
from lasercal_hw.verify.helix import HelixChange, offset_change_m
from lasercal_hw.verify.procedure import VerifyPlan
from lasercal_hw.verify.selection import (
    VERDICT_MARGIN,
    VerdictAim,
    select_waypoints,
    tolerance_noncentrality,
    waypoint_information,
)

SHIFT_M = 0.003
TURN_RAD = float(np.radians(0.3))
DIRECTIONS = 2000
#: Random turn axes the subset search scores with (the printed share takes ``DIRECTIONS``).
SEARCH_DIRECTIONS = 200
SEARCH_CHUNK = 20000
#: The choice's aims compared (``selection.VerdictAim.margin``; the verify's own is printed as its choice).
AIM_MARGINS = (1.0, 1.2, 1.5, np.inf)
#: The per-waypoint table's turns are those a test of this many waypoints would see.
TABLE_WAYPOINTS = 4


def unit_directions(count: int, seed: int) -> FloatArray:
    """``count`` random unit vectors (3,)."""
    drawn = np.random.default_rng(seed).normal(size=(count, 3))
    return drawn / np.linalg.norm(drawn, axis=1)[:, None]


def random_moves(directions: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The moves (D, 6 each: m, rad) of a 3 mm shift and of a 0.3 deg turn along each of
    ``directions`` (D, 3)."""
    zeros = np.zeros_like(directions)
    return np.hstack([SHIFT_M * directions, zeros]), np.hstack([zeros, TURN_RAD * directions])


@dataclass(frozen=True)
class Judged:
    """One rule's subset judged by the test's information (mm, deg, shares, time share)."""

    name: str
    waypoints: list[int]
    weakest_shift_mm: float
    turn_deg: FloatArray
    #: The smallest shift / turn flagged 90 % in the direction the test sees least (the verdict's).
    direction_shift_mm: float
    direction_turn_deg: float
    #: Both under the job's tolerances: an unmoved verify there says ``ok``.
    ok: bool
    #: The estimated move's largest std of a shift component (mm) and of a turn one (deg).
    estimate_std_mm: float
    estimate_std_deg: float
    flagged_shift: float
    flagged_turn: float
    time_share: float
    with_verify_only_deg: float
    #: The non-centrality of each random 0.3 deg turn (D,), the test's degrees of freedom and threshold.
    turn_noncentrality: FloatArray
    dof: int
    threshold: float
    #: The unmoved verify dwell's chi-square at these waypoints.
    unmoved_chi_square: float


def judge(
    name: str,
    candidates: Candidates,
    waypoints: list[int],
    moves: tuple[FloatArray, FloatArray],
    time_share: float,
    unmoved_chi_square: float,
    noise: FloatArray | None = None,
) -> Judged:
    """The test at the job's ``waypoints`` judged as the module docstring says, with the random
    ``moves`` (shifts, turns) and the verify dwell's ``noise`` there (None: the candidates')
    (``unmoved_chi_square``: of the unmoved verify dwell at those waypoints)."""
    model, dof = candidates.plan.model, 2 * len(waypoints)
    threshold = float(chi2.ppf(1.0 - model.false_alarm_rate, dof))
    needed = needed_noncentrality(model, dof)
    sides = candidates.information_of(waypoints, noise)
    diagonal = np.min([np.diag(side) for side in sides], axis=0)
    weakest = np.sqrt(needed / diagonal)
    least = weakest_moves(sides, needed)
    direction_shift_mm, direction_turn_deg = least.shift_mm, least.turn_deg
    tolerance = candidates.plan.job.verify
    estimate = np.sqrt(np.diag(np.linalg.inv(sides[0] + np.linalg.inv(model.prior()))))
    shift, turn = (candidates.noncentrality(waypoints, move, noise) for move in moves)
    bound = np.sqrt(needed / (diagonal[3:] + np.diag(np.linalg.inv(model.covariance))[3:]))
    return Judged(
        name,
        sorted(waypoints),
        float(weakest[:3].max() * 1e3),
        np.degrees(weakest[3:]),
        float(direction_shift_mm),
        float(direction_turn_deg),
        bool(direction_shift_mm <= tolerance.tolerance_mm and direction_turn_deg <= tolerance.tolerance_deg),
        float(estimate[:3].max() * 1e3),
        float(np.degrees(estimate[3:].max())),
        float(ncx2.sf(threshold, dof, shift).mean()),
        float(ncx2.sf(threshold, dof, turn).mean()),
        time_share,
        float(np.degrees(bound.max())),
        turn,
        dof,
        threshold,
        unmoved_chi_square,
    )


def scaled_turn_share(outcomes: list[Judged]) -> tuple[float, float]:
    """The unmoved chi-square's mean over its dof (``k``, 1 where the stated noise is right)
    and the predicted share of 0.3 deg turns flagged if the noise is ``k`` times the stated
    variance: the statistic is then ``k`` times a non-central chi-square of ``lambda / k``."""
    k = float(np.mean([o.unmoved_chi_square for o in outcomes]) / np.mean([o.dof for o in outcomes]))
    shares = [float(ncx2.sf(o.threshold / k, o.dof, o.turn_noncentrality / k).mean()) for o in outcomes]
    return k, float(np.mean(shares))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_job_arguments(parser)
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=100)
    parser.add_argument(
        "--slack-dwell", action="store_true", help="also the verify's choice at a dwell that fills the budget"
    )
    args = parser.parse_args()

    bench = VerifyBench.from_args(args)
    moves = random_moves(unit_directions(DIRECTIONS, 0))
    judged: dict[str, list[Judged]] = {}
    whitened: list[FloatArray] = []
    alone_turns: list[FloatArray] = []
    honesty: dict[str, list[float]] = {"job": [], "slack": [], "ratio": [], "dwell": []}
    started = time.perf_counter()
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        rng = np.random.default_rng(seed)
        world = bench.world(seed)
        try:
            calibrated = bench.calibrate_and_plan(world, rng)
        except LasercalError as exc:
            print(f"seed {seed}: calibration failed: {exc}")
            continue
        plan = calibrated.plan
        seen, background = measure_waypoints(plan.job, plan.waypoints, world, bench.scans, rng)
        refitted, _ = plan.refit.centres(seen, background)
        found = [m.index for m in refitted]
        if not set(plan.selection.indices) <= set(found):
            print(f"seed {seed}: the rod was not found at every chosen waypoint; left out")
            continue
        centres = np.array([m.centre.centre_uv_m for m in refitted])
        stated = np.array([m.centre.covariance_uv_m2 for m in refitted])
        noise = np.array([m.centre.dwell_noise_covariance_uv_m2() for m in refitted])
        candidates = Candidates.of(plan, found, centres, stated, noise)
        line = [f"seed {seed:3d}"]
        residuals, visited = calibrated.trial.result.residuals, calibrated.trial.waypoints
        whole, drawn = recorded_centre_covariances(residuals, visited, plan.waypoints)
        for name, subset in rules(plan, candidates, (whole, drawn), bench.count, calibrated.budget_s):
            share = (visit_time_s(plan.job, plan.waypoints[subset]) or np.nan) / calibrated.calibration_s
            unmoved = float(candidates.whitened_squares()[[found.index(i) for i in subset]].sum())
            outcome = judge(name, candidates, subset, moves, share, unmoved)
            judged.setdefault(name, []).append(outcome)
            line.append(f"{name}: {outcome.waypoints} {outcome.direction_turn_deg:.3f} deg")
        if args.slack_dwell:
            slack = slack_dwell(calibrated, world, rng, candidates, moves)
            if slack is not None:
                outcome, dwell_s, white_3s, white_slack, ratio = slack
                judged.setdefault(outcome.name, []).append(outcome)
                honesty["job"].extend(white_3s)
                honesty["slack"].extend(white_slack)
                honesty["ratio"].extend(ratio)
                honesty["dwell"].append(dwell_s)
                line.append(f"{outcome.name} ({dwell_s:.1f} s): {outcome.turn_deg.max():.3f} deg")
        print(" | ".join(line), flush=True)
        per_waypoint = np.full(len(plan.waypoints), np.nan)
        per_waypoint[found] = candidates.whitened_squares()
        whitened.append(per_waypoint)
        turns = np.full((len(plan.waypoints), 3), np.nan)
        needed = needed_noncentrality(plan.model, 2 * TABLE_WAYPOINTS)
        turns[found] = np.degrees(np.sqrt(needed / np.einsum("nkk->nk", candidates.alone)[:, 3:]))
        alone_turns.append(turns)

    print(f"\n{len(whitened)} seeds in {time.perf_counter() - started:.0f} s, {bench.count} verify waypoints")
    for name, outcomes in judged.items():
        turn = np.array([o.turn_deg for o in outcomes])
        weakest = turn.max(axis=1)
        shift = np.array([o.weakest_shift_mm for o in outcomes])
        shares = np.array([o.time_share for o in outcomes])
        axis = np.median(turn, axis=0)
        k, scaled = scaled_turn_share(outcomes)
        direction = np.array([[o.direction_shift_mm, o.direction_turn_deg] for o in outcomes])
        print(
            f"  {name}: weakest direction: shift median {np.median(direction[:, 0]):.2f} mm, turn median "
            f"{np.median(direction[:, 1]):.3f} deg (max {direction[:, 1].max():.3f}); an unmoved verify "
            f"says ok at {sum(o.ok for o in outcomes)} / {len(outcomes)} seeds; the move's estimate: largest "
            f"std median {np.median([o.estimate_std_mm for o in outcomes]):.2f} mm, "
            f"{np.median([o.estimate_std_deg for o in outcomes]):.3f} deg"
        )
        print(
            f"    weakest base axis: shift median {np.median(shift):.2f} mm, turn median "
            f"{np.median(weakest):.3f} deg (max {weakest.max():.3f}; about base x / y / z median "
            f"{axis[0]:.3f} / {axis[1]:.3f} / {axis[2]:.3f}); predicted flagged: 3 mm shift "
            f"{np.mean([o.flagged_shift for o in outcomes]):.1%}, 0.3 deg turn "
            f"{np.mean([o.flagged_turn for o in outcomes]):.1%} (unmoved chi-square / dof {k:.2f}, at that "
            f"noise {scaled:.1%}); time share median {np.median(shares):.3f} "
            f"(max {shares.max():.3f}); with any number of verify-only poses at best "
            f"{np.median([o.with_verify_only_deg for o in outcomes]):.3f} deg"
        )
    if honesty["slack"]:
        print(
            "  the verify's choice, unmoved, mean squared whitened residual per waypoint (2 if honest): "
            f"the job's dwell {np.mean(honesty['job']):.2f}, filling the budget "
            f"{np.mean(honesty['slack']):.2f} "
            f"({len(honesty['slack'])} waypoint visits); dwell median {np.median(honesty['dwell']):.1f} s, "
            f"its noise variance over the job's dwell's median {np.median(honesty['ratio']):.2f}"
        )
    means = np.nanmean(np.array(whitened), axis=0)
    print("  unmoved, mean squared whitened residual per waypoint (2 if the stated noise is right):")
    print("   ", " ".join(f"{i}:{m:.1f}" for i, m in enumerate(means)))
    table = np.nanmedian(np.array(alone_turns), axis=0)
    print(f"  turn (deg) about base x / y / z one waypoint alone sees in a {TABLE_WAYPOINTS}-waypoint test:")
    for row in range(0, len(table), 4):
        cells = enumerate(table[row : row + 4], row)
        print("   ", "  ".join(f"{i:2d}: {x:5.2f} {y:5.2f} {z:5.2f}" for i, (x, y, z) in cells))


@dataclass(frozen=True)
class Candidates:
    """The waypoints where the unmoved verify dwell found the rod (``found``: job indices), and
    the unmoved centres measured there and what the drift test states: each alone's information
    (n, 6, 6) on the crossings, as the verify's choice weighs it (``selection.waypoint_information``;
    the helix's change is in ``information_of`` and ``noncentrality``)."""

    plan: VerifyPlan
    found: list[int]
    centres: FloatArray
    stated: FloatArray
    noise: FloatArray
    alone: FloatArray

    @classmethod
    def of(
        cls, plan: VerifyPlan, found: list[int], centres: FloatArray, stated: FloatArray, noise: FloatArray
    ) -> Candidates:
        """The candidates of ``plan``: the verify dwell's ``centres`` (n, 2) at ``found``, their
        covariance ``stated`` and the part of it a dwell draws anew, ``noise`` (n, 2, 2)."""
        visited = np.isfinite(plan.reference[found]).all(axis=1)
        alone = waypoint_information(plan.model, plan.waypoints[found], visited, stated, noise)
        return cls(plan, found, centres, stated, noise, alone)

    def _test(
        self, subset: list[int], noise: FloatArray | None
    ) -> tuple[FloatArray, FloatArray, tuple[FloatArray, bool]]:
        """The job's waypoints ``subset``'s poses (n, 6), crossings' Jacobian (n, 2, 6) and the
        factored ``S`` of the test there, with the verify dwell's ``noise`` (None: the candidates')."""
        at = [self.found.index(i) for i in subset]
        poses = self.plan.waypoints[subset]
        _, jac, slope = predictions(self.plan.model, poses)
        visited = np.isfinite(self.plan.reference[subset]).all(axis=1)
        drawn = self.noise[at] if noise is None else noise
        total = residual_covariance(self.plan.model, jac, slope, self.stated[at], visited, drawn)
        return poses, jac, cho_factor(total)

    def information_of(self, subset: list[int], noise: FloatArray | None = None) -> list[FloatArray]:
        """The test's information (6, 6) from the job's waypoints ``subset`` (all candidates), with
        the verify dwell's ``noise`` there (None: the candidates'): one, or with flutes one for a
        positive and one for a negative move (``move_jacobians``)."""
        poses, jac, total = self._test(subset, noise)
        sides = [side.reshape(-1, 6) for side in move_jacobians(self.plan.model, poses, jac)]
        return [j.T @ cho_solve(total, j) for j in sides]

    def centre_moves(self, subset: list[int], moves: FloatArray) -> FloatArray:
        """How far each of ``moves`` (D, 6) moves the centres (D, n, 2) at the job's waypoints
        ``subset``: the crossings' move and, with flutes, the section offsets' exact change
        (``helix.offset_change_m``)."""
        poses = self.plan.waypoints[subset]
        _, jac, _ = predictions(self.plan.model, poses)
        shift = np.einsum("nij,dj->dni", jac, moves)
        if self.plan.model.flutes is not None:
            shift += np.stack([offset_change_m(self.plan.model.flutes, poses, x) for x in moves])
        return shift

    def noncentrality(
        self, subset: list[int], moves: FloatArray, noise: FloatArray | None = None
    ) -> FloatArray:
        """The test's non-centrality (D,) at the job's waypoints ``subset`` for each of ``moves``
        (D, 6) (``centre_moves``), with the verify dwell's ``noise`` there (None: the candidates')."""
        _, _, total = self._test(subset, noise)
        flat = self.centre_moves(subset, moves).reshape(len(moves), -1)
        return np.einsum("dk,kd->d", flat, cho_solve(total, flat.T))

    def alone_noncentrality(self, moves: FloatArray) -> FloatArray:
        """Each candidate's non-centrality alone (n, D) for each of ``moves`` (D, 6)
        (``centre_moves``), the calibration's covariance left out as the choice leaves it out (the
        waypoints it compares with the calibration's own are independent)."""
        _, _, slope = predictions(self.plan.model, self.plan.waypoints[self.found])
        visited = np.isfinite(self.plan.reference[self.found]).all(axis=1)
        blocks = noise_blocks(self.plan.model, slope, self.stated, visited, self.noise)
        shift = self.centre_moves(self.found, moves)
        return np.einsum("dni,nij,dnj->nd", shift, np.linalg.inv(blocks), shift)

    def whitened_squares(self) -> FloatArray:
        """Each candidate's squared whitened residual (n,) of the unmoved verify."""
        return squared_residuals(self.plan, self.found, self.centres, self.stated, self.noise)


def move_jacobians(model: DriftModel, tcp_poses: FloatArray, jac: FloatArray) -> list[FloatArray]:
    """The Jacobians (n, 2, 6 each) of the centres in the move, as ``test.detectable`` takes them:
    the crossings' ``jac`` alone without flutes; with them, ``jac`` plus the helix's change for a
    positive and for a negative move (the offsets jump on one side only)."""
    if model.flutes is None:
        return [jac]
    helix = HelixChange.of(model.flutes, tcp_poses)
    return [jac + helix.forward, jac + helix.backward]


def squared_residuals(
    plan: VerifyPlan, indices: list[int], centres: FloatArray, stated: FloatArray, noise: FloatArray
) -> FloatArray:
    """``d_i^T (C_i + R_i)^-1 d_i`` at the job's waypoints ``indices`` for ``centres`` (n, 2)
    measured with the centre covariance ``stated`` and the part a dwell draws anew ``noise``."""
    crossing, _, slope = predictions(plan.model, plan.waypoints[indices])
    reference = plan.reference[indices]
    visited = np.isfinite(reference).all(axis=1)
    residual = centres - crossing - np.where(visited[:, None], reference, 0.0)
    blocks = noise_blocks(plan.model, slope, stated, visited, noise)
    return np.array([float(r @ np.linalg.solve(b, r)) for r, b in zip(residual, blocks, strict=True)])


def rules(
    plan: VerifyPlan,
    candidates: Candidates,
    covariances: tuple[FloatArray, FloatArray],
    count: int,
    budget_s: float | None,
) -> list[tuple[str, list[int]]]:
    """(name, job waypoint indices) per rule of the module docstring, each inside the budget; the
    searches take the waypoints where the calibration used its centre (an outlier or a waypoint
    without a rod is no candidate of the verify's either). ``covariances`` (N, 2, 2 each; NaN:
    none): the centre covariance the calibration recorded at each job waypoint and the part of it
    a dwell draws anew, which is what the verify knows when it chooses (the other searches know
    the verify dwell's own noise, which a verify learns only after its dwells)."""
    model, found = plan.model, candidates.found
    whole, drawn = covariances
    recorded = Candidates.of(plan, found, candidates.centres, whole[found], drawn[found])
    usable = [k for k, i in enumerate(found) if np.isfinite(plan.reference[i]).all()]
    subsets = np.fromiter(
        itertools.chain.from_iterable(itertools.combinations(usable, count)),
        dtype=np.int16,
        count=math.comb(len(usable), count) * count,
    ).reshape(-1, count)

    def first_in_budget(order: FloatArray) -> list[int]:
        for k in order:
            chosen = [found[i] for i in subsets[k]]
            seconds = visit_time_s(plan.job, plan.waypoints[chosen])
            if seconds is not None and (budget_s is None or seconds <= budget_s):
                return chosen
        raise LasercalError("no subset of the job's waypoints fits the verify's time budget")

    tolerance = plan.job.verify.tolerance_mm * 1e-3, float(np.radians(plan.job.verify.tolerance_deg))

    def chosen_by(aim: VerdictAim | None, recorded_noise: bool = True) -> list[int]:
        return select_waypoints(
            model,
            plan.waypoints,
            count,
            np.isfinite(plan.reference).all(axis=1),
            time_of=lambda indices: visit_time_s(plan.job, plan.waypoints[indices]),
            budget_s=budget_s,
            centre_covariance_uv_m2=whole if recorded_noise else None,
            noise_covariance_uv_m2=drawn if recorded_noise else None,
            unusable=~np.isin(np.arange(len(plan.waypoints)), found),
            aim=aim,
        ).indices

    named = [
        ("verify's choice", plan.selection.indices),
        *(
            (f"aim {margin:g} by the record", chosen_by(VerdictAim(*tolerance, margin)))
            for margin in AIM_MARGINS
            if margin != VERDICT_MARGIN
        ),
        ("D-optimal by the record", chosen_by(None)),
        ("D-optimal, 0.5 mm assumed", chosen_by(None, recorded_noise=False)),
    ]
    aim = VERDICT_MARGIN * needed_noncentrality(model, 2 * count)
    aim_of = tolerance, model.prior()
    seen, determinant = aimed(recorded, subsets, *aim_of)
    return [
        *((name, list(chosen)) for name, chosen in named if set(chosen) <= set(found)),
        (
            f"aim {VERDICT_MARGIN:g} by the record, every subset",
            first_in_budget(np.lexsort((-determinant, -np.minimum(seen, aim)))),
        ),
        ("the verdict's best by the record", first_in_budget(np.argsort(-seen, kind="stable"))),
        ("the verdict's best", first_in_budget(np.argsort(-aimed(candidates, subsets, *aim_of)[0]))),
        ("most 0.3 deg turns", first_in_budget(np.argsort(-turns_flagged(candidates, subsets, model)))),
        (
            "most 0.3 deg turns by the record",
            first_in_budget(np.argsort(-turns_flagged(recorded, subsets, model), kind="stable")),
        ),
    ]


def aimed(
    candidates: Candidates, subsets: FloatArray, tolerance: tuple[float, float], prior: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Each subset's (m, count) non-centrality of a move of the ``tolerance`` (m, rad) in its
    weakest direction (``selection.tolerance_noncentrality``: what the verdict weighs) and its
    ``log det(F + prior^-1)`` (the D-optimal choice's)."""
    per_waypoint = candidates.alone.reshape(len(candidates.alone), 36)
    base = np.linalg.inv(prior)
    seen = over_subsets(
        per_waypoint, subsets, lambda summed: tolerance_noncentrality(summed.reshape(-1, 6, 6), *tolerance)
    )
    determinant = over_subsets(
        per_waypoint, subsets, lambda summed: np.linalg.slogdet(base + summed.reshape(-1, 6, 6))[1]
    )
    return seen, determinant


def turns_flagged(candidates: Candidates, subsets: FloatArray, model: DriftModel) -> FloatArray:
    """Each subset's (m, count) predicted share of random 0.3 deg turns flagged
    (``SEARCH_DIRECTIONS`` axes; the waypoints' non-centralities alone added)."""
    dof = 2 * subsets.shape[1]
    threshold = float(chi2.ppf(1.0 - model.false_alarm_rate, dof))
    _, turns = random_moves(unit_directions(SEARCH_DIRECTIONS, 1))
    per_waypoint = np.nan_to_num(candidates.alone_noncentrality(turns)).astype(np.float32)
    grid = np.linspace(0.0, float(per_waypoint.max()) * subsets.shape[1], 4000)
    flagged = ncx2.sf(threshold, dof, grid)
    return over_subsets(per_waypoint, subsets, lambda summed: np.interp(summed, grid, flagged).mean(axis=1))


def over_subsets(
    per_waypoint: FloatArray, subsets: FloatArray, score: Callable[[FloatArray], FloatArray]
) -> FloatArray:
    """``score`` (chunk, k) -> (chunk,) of each subset's (m, count) sum of ``per_waypoint`` (n, k),
    in chunks of ``SEARCH_CHUNK`` subsets."""
    scores = np.empty(len(subsets))
    for first in range(0, len(subsets), SEARCH_CHUNK):
        chunk = subsets[first : first + SEARCH_CHUNK]
        scores[first : first + SEARCH_CHUNK] = score(per_waypoint[chunk].sum(axis=1))
    return scores


def slack_dwell(
    calibrated: CalibratedSeed,
    world: World,
    rng: np.random.Generator,
    candidates: Candidates,
    moves: tuple[FloatArray, FloatArray],
) -> tuple[Judged, float, FloatArray, FloatArray, FloatArray] | None:
    """The verify's choice at the longest dwell inside the budget, measured there: judged with that
    dwell's noise plus the calibration's recorded one at each waypoint, that dwell (s), and the
    unmoved residuals' squares (the job's dwell's, the long one's) whitened by the noise each is
    tested with, and each waypoint's noise variance at the long dwell over the job's (trace)."""
    plan, budget_s = calibrated.plan, calibrated.budget_s
    chosen = plan.selection.indices
    poses = plan.waypoints[chosen]
    base_s = visit_time_s(plan.job, poses)
    if base_s is None or budget_s is None:
        return None
    period_s = world.geometry.scan_period_s
    scans = int((plan.job.dwell_s + (budget_s - base_s) / len(chosen)) / period_s)
    job = plan.job.model_copy(update={"dwell_s": scans * period_s})
    measured, background = measure_waypoints(job, poses, world, scans, rng)
    refitted, _ = plan.refit.centres(measured, background)
    if len(refitted) < len(chosen):
        return None
    stated = np.array([m.centre.covariance_uv_m2 for m in refitted])
    noise = np.array([m.centre.dwell_noise_covariance_uv_m2() for m in refitted])
    residuals, visited = calibrated.trial.result.residuals, calibrated.trial.waypoints
    _, calibration_noise = recorded_centre_covariances(residuals, visited, plan.waypoints)
    # noise_blocks counts a revisited waypoint's drawn noise twice: half of the two dwells' sum.
    both = 0.5 * (noise + calibration_noise[chosen])
    share = (visit_time_s(job, poses) or np.nan) / calibrated.calibration_s
    centres = np.array([m.centre.centre_uv_m for m in refitted])
    at = [candidates.found.index(i) for i in chosen]
    squares = squared_residuals(plan, chosen, centres, stated, both)
    outcome = judge(
        "verify's choice, dwell filling the budget", candidates, chosen, moves, share, float(squares.sum()),
        both,
    )
    ratio = np.trace(noise, axis1=1, axis2=2) / np.trace(candidates.noise[at], axis1=1, axis2=2)
    return outcome, job.dwell_s, candidates.whitened_squares()[at], squares, ratio


if __name__ == "__main__":
    main()
