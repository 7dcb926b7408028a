"""The job, world and calibration the verify benchmarks draw per seed (``verify_rates``,
``verify_design``): one place for their ``--config``, ``--scene``, ``--bit-off`` and
``--any-turn`` and for how a seed's calibration and verify plan are made (offline; not
collected by pytest)."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.accuracy_conditions import chuck_turned, real_bit
from benchmarks.dry_run_accuracy import Trial, simulate, world_with
from fakes.scene import load_scene
from fakes.world import World
from lasercal_hw.config import JobConfig, load_job
from lasercal_hw.models import FloatArray
from lasercal_hw.run.timing import visit_time_s
from lasercal_hw.run.waypoints import job_waypoints
from lasercal_hw.verify.procedure import VerifyPlan, plan_verify


def add_job_arguments(parser: argparse.ArgumentParser) -> None:
    """``--config``, ``--scene``, ``--bit-off``, ``--any-turn`` and ``--waypoints`` of a verify
    benchmark."""
    parser.add_argument("--config", type=Path, default=None, help="job file (default: built-in defaults)")
    parser.add_argument("--scene", type=Path, default=None, help="scene file (default: packaged default)")
    parser.add_argument(
        "--bit-off", action="store_true", help="the world's rod 2 mm off and 1 deg tilted from the job's axis"
    )
    parser.add_argument(
        "--any-turn",
        action="store_true",
        help="the scene's bit turned in its chuck by an angle drawn per seed (0-180 deg), not the scene's",
    )
    parser.add_argument("--waypoints", type=int, default=None, help="default: the job's verify.waypoints")


@dataclass(frozen=True)
class VerifyBench:
    """A verify benchmark's job and world settings, the same for every seed."""

    job: JobConfig
    scene_path: Path | None
    bit_off: bool
    #: The scene's bit turned in its chuck by an angle drawn per seed.
    any_turn: bool
    #: The waypoints the calibration visits first (``job_waypoints``: a spun job's spin).
    poses: FloatArray
    #: Verify waypoints.
    count: int
    #: Scans per dwell (the job's dwell at the scene's scan period).
    scans: int

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> VerifyBench:
        """The bench of ``add_job_arguments``' options."""
        job = load_job(args.config)
        return cls(
            job=job,
            scene_path=args.scene,
            bit_off=args.bit_off,
            any_turn=args.any_turn,
            poses=job_waypoints(job),
            count=args.waypoints or job.verify.waypoints,
            scans=round(job.dwell_s / World.from_scene(args.scene).geometry.scan_period_s),
        )

    def world(self, seed: int) -> World:
        """The seed's world: the scene (``any_turn``: its bit turned in its chuck as drawn for
        the seed) with the job's rod (``bit_off``: as the bit really sits) and the seed's robot
        error field."""
        nominal = self.job.rod.rod_line()
        rod = real_bit(nominal) if self.bit_off else nominal
        scene = load_scene(self.scene_path)
        if self.any_turn:
            scene = chuck_turned(scene, seed)
        return world_with(scene, rod, robot_error_seed=1000 + seed)

    def calibrate_and_plan(
        self, world: World, rng: np.random.Generator, *, reference: bool = True
    ) -> CalibratedSeed:
        """A calibration simulated in ``world`` (``dry_run_accuracy.simulate``) and the verify
        planned from it (``plan_verify``, the time budget, choosing among the poses the calibration
        visited as ``lasercal verify`` does from ``run.waypoints``); ``reference`` False: the plan
        ignores the calibration's residuals at its own waypoints. Raises ``LasercalError`` when
        the calibration fails."""
        trial = simulate(self.job, self.poses, world, self.scans, rng)
        calibration = trial.result
        estimate_s = visit_time_s(self.job, trial.waypoints)
        calibration_s = np.nan if estimate_s is None else estimate_s
        budget_s = None if estimate_s is None else self.job.verify.max_time_fraction * estimate_s
        plan = plan_verify(
            self.job,
            calibration.matrix(),
            np.asarray(calibration.covariance),
            calibration.residuals,
            trial.waypoints if reference else None,
            count=self.count,
            budget_s=budget_s,
            range_error=calibration.range_offset,
            refit=trial.refit,
            rod=calibration.estimated_rod(self.job.rod.rod_line()),
            candidates=trial.waypoints,  # as from a result.json that records the poses its run visited
        )
        return CalibratedSeed(trial, plan, calibration_s, budget_s)


@dataclass(frozen=True)
class CalibratedSeed:
    """A seed's simulated calibration and the verify planned from it."""

    trial: Trial
    plan: VerifyPlan
    #: The calibration's motion and dwell over every waypoint it visited (``run.timing``; NaN:
    #: a pose out of reach): a spun job's spin and turned waypoints, the latter per seed.
    calibration_s: float
    #: The verify's time budget (``verify.max_time_fraction`` of ``calibration_s``; None: unknown).
    budget_s: float | None
