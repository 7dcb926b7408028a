"""The verify fits its centres as the calibration's second pass fitted its own, so that the same
averaged scans give the calibration's centres and its residuals back (offline: the fake world's
scanner model, no devices)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from benchmarks.accuracy_conditions import DRILL_JOB, real_bit
from benchmarks.dry_run_accuracy import measure_waypoints, world_with
from fakes.scene import load_scene
from lasercal_hw.config import JobConfig, load_job, with_overrides
from lasercal_hw.errors import ConfigError
from lasercal_hw.models import RodLine
from lasercal_hw.run.outputs import first_pass_record
from lasercal_hw.run.records import WaypointMeasurement
from lasercal_hw.run.two_pass import TwoPassSolution, solve_two_pass
from lasercal_hw.run.waypoints import job_waypoints
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.verify.active import load_active_calibration
from lasercal_hw.verify.procedure import plan_active, refit_and_test

SCANS = 40


@dataclass(frozen=True)
class Calibrated:
    """A calibration solved offline, what it measured, and its result.json."""

    solution: TwoPassSolution
    measurements: list[WaypointMeasurement]
    background: AveragedScan
    path: Path


def calibrate(job: JobConfig, true_rod: RodLine, seed: int, folder: Path) -> Calibrated:
    """``job`` calibrated in the default scene's fake world holding ``true_rod``, and its
    result.json with what ``lasercal run`` records of the run (the first pass, the job)."""
    rng = np.random.default_rng(seed)
    world = world_with(load_scene(None), true_rod, robot_error_seed=1000 + seed)
    measurements, background = measure_waypoints(job, job_waypoints(job), world, SCANS, rng)
    solution = solve_two_pass(measurements, job, background)
    document = solution.result.to_json_dict()
    document["run"] = {
        "first_pass": first_pass_record(solution.first_pass, job),
        "job": job.model_dump(mode="json"),
    }
    path = folder / "result.json"
    path.write_text(json.dumps(document), encoding="utf-8")
    return Calibrated(solution, measurements, background, path)


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> Calibrated:
    """The default job calibrated (seed 100: its near waypoints 17 and 18, 0.32-0.34 m, are
    where the two processings differed by 0.7-0.9 mm)."""
    job = load_job(None)
    calibration = calibrate(job, job.rod.rod_line(), 100, tmp_path_factory.mktemp("default"))
    solution = calibration.solution
    assert solution.result.range_offset is not None and solution.refit.range_offset_m > 0.002
    return calibration


@pytest.fixture(scope="module")
def drill_calibrated(tmp_path_factory: pytest.TempPathFactory) -> Calibrated:
    """The drill job with a plain 10 mm rod whose axis it estimates, the true rod 2 mm off its
    nominal axis and tilted 1 deg (``benchmarks.accuracy_conditions.real_bit``)."""
    job = with_overrides(load_job(DRILL_JOB), {"rod.fluted": False}, source="test")
    assert job.rod.estimate_axis
    true_rod = real_bit(job.rod.rod_line())
    return calibrate(job, true_rod, 100, tmp_path_factory.mktemp("drill"))


def assert_verify_gives_the_calibration_back(calibration: Calibrated) -> None:
    """The calibration's averaged scans through the verify's processing (the recorded second
    pass: its transform, its rod line, the range offset out of every range; the prediction
    with the estimated rod and the rest of the curve) give the calibration's centres, and the
    drift test's residual ``m - (p + b)`` is zero at every waypoint."""
    solution, measurements, background = (
        calibration.solution, calibration.measurements, calibration.background
    )
    active = load_active_calibration(calibration.path)
    assert active.refit(active.job.rod.rod_line()).range_offset_m == solution.refit.range_offset_m
    plan = plan_active(active, active.job, count=len(measurements))
    assert plan.selection.indices == [m.index for m in measurements]
    chosen = [WaypointMeasurement(k, m.tcp_pose, m.averaged, m.centre) for k, m in enumerate(measurements)]
    refitted, kept = plan.refit.centres(chosen, background)
    assert kept == solution.kept_first_pass
    np.testing.assert_allclose(
        [m.centre.centre_uv_m for m in refitted], [o.centre_uv_m for o in solution.observations], atol=1e-9
    )
    test, _ = refit_and_test(plan, chosen, background)
    assert test is not None
    np.testing.assert_allclose(test.residual_mm, 0.0, atol=1e-3)  # 1e-6 m
    assert test.chi_square == pytest.approx(0.0, abs=1e-6)


def test_the_verify_fits_the_calibrations_own_scans_to_its_centres_and_residuals(
    calibrated: Calibrated,
) -> None:
    """The default job: the near waypoints included."""
    assert_verify_gives_the_calibration_back(calibrated)


def test_a_job_that_estimates_the_rod_axis_is_verified_with_the_rod_it_estimated(
    drill_calibrated: Calibrated,
) -> None:
    """A rod 2 mm off its nominal axis: the verify fits with the first pass's estimate of the rod
    (as the second pass did) and predicts with the final one (against which ``b`` was taken);
    with the nominal rod every residual kept about 2 mm (main: 1.4-2.6 mm)."""
    axis = drill_calibrated.solution.result.rod_axis
    assert axis is not None and axis.estimated and np.linalg.norm(axis.crossing_offset_mm) > 1.0
    assert "run.first_pass.rod" in load_active_calibration(drill_calibrated.path).rod_note()
    assert_verify_gives_the_calibration_back(drill_calibrated)


def test_a_calibration_without_a_recorded_first_pass_is_refitted_with_its_own_transform(
    drill_calibrated: Calibrated, tmp_path: Path
) -> None:
    """A result.json that does not record its first pass (an older one): the calibrated
    transform, the job's nominal rod and the raw ranges, as the verify did before; its note
    says so."""
    document = json.loads(drill_calibrated.path.read_text(encoding="utf-8"))
    del document["run"]["first_pass"]
    document["provenance"]["solver_options"].pop("range_offset_applied_m")
    older = tmp_path / "result.json"
    older.write_text(json.dumps(document), encoding="utf-8")
    active = load_active_calibration(older)
    nominal = active.job.rod.rod_line()
    refit = active.refit(nominal)
    np.testing.assert_array_equal(refit.T_base_laser, active.T_base_laser)
    assert refit.rod == nominal
    assert refit.range_offset_m == 0.0
    assert "does not record the rod line" in active.rod_note()


def test_a_malformed_recorded_rod_is_refused_naming_the_field(
    drill_calibrated: Calibrated, tmp_path: Path
) -> None:
    """A ``run.first_pass.rod`` that is not a line: a one-line error naming the field."""
    document = json.loads(drill_calibrated.path.read_text(encoding="utf-8"))
    document["run"]["first_pass"]["rod"]["direction"] = [0.0, 1.0]
    broken = tmp_path / "result.json"
    broken.write_text(json.dumps(document), encoding="utf-8")
    active = load_active_calibration(broken)
    with pytest.raises(ConfigError, match=r"run\.first_pass\.rod is not a rod line"):
        active.refit(active.job.rod.rod_line())
