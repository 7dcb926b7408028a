"""The verify fits its centres as the calibration's second pass fitted its own, so that the same
averaged scans give the calibration's centres and its residuals back (offline: the fake world's
scanner model, no devices)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from benchmarks.dry_run_accuracy import measure_waypoints, world_for
from lasercal_hw.config import load_job
from lasercal_hw.run.records import WaypointMeasurement
from lasercal_hw.run.two_pass import TwoPassSolution, solve_two_pass
from lasercal_hw.run.waypoints import job_waypoints
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.verify.active import load_active_calibration
from lasercal_hw.verify.procedure import plan_active, refit_and_test

SCANS = 40


@pytest.fixture(scope="module")
def calibrated(
    tmp_path_factory: pytest.TempPathFactory,
) -> tuple[TwoPassSolution, list[WaypointMeasurement], AveragedScan, Path]:
    """The default job calibrated in the fake world (seed 100: its near waypoints 17 and 18,
    0.32-0.34 m, are where the two processings differed by 0.7-0.9 mm), and its result.json
    with what ``lasercal run`` records of the run (the first pass, the job)."""
    job = load_job(None)
    rng = np.random.default_rng(100)
    world = world_for(job, None, robot_error_seed=1100)
    measurements, background = measure_waypoints(job, job_waypoints(job), world, SCANS, rng)
    solution = solve_two_pass(measurements, job, background)
    assert solution.result.range_offset is not None and solution.refit.range_offset_m > 0.002
    document = solution.result.to_json_dict()
    document["run"] = {
        "first_pass": {"T_base_laser": solution.first_pass.T_base_laser},
        "job": job.model_dump(mode="json"),
    }
    path = tmp_path_factory.mktemp("calibration") / "result.json"
    path.write_text(json.dumps(document), encoding="utf-8")
    return solution, measurements, background, path


def test_the_verify_fits_the_calibrations_own_scans_to_its_centres_and_residuals(
    calibrated: tuple[TwoPassSolution, list[WaypointMeasurement], AveragedScan, Path],
) -> None:
    """The calibration's averaged scans through the verify's processing (the recorded second
    pass: its transform, the range offset out of every range, the rest of the curve in the
    prediction) give the calibration's centres, and the drift test's residual ``m - (p + b)``
    is zero at every waypoint, the near ones included."""
    solution, measurements, background, path = calibrated
    active = load_active_calibration(path)
    assert active.refit().range_offset_m == solution.refit.range_offset_m
    plan = plan_active(active, active.job, count=len(measurements))
    assert plan.selection.indices == [m.index for m in measurements]
    chosen = [WaypointMeasurement(k, m.tcp_pose, m.averaged, m.centre) for k, m in enumerate(measurements)]
    refitted, kept = plan.refit.centres(chosen, plan.job.rod.rod_line(), background)
    assert kept == solution.kept_first_pass
    np.testing.assert_allclose(
        [m.centre.centre_uv_m for m in refitted], [o.centre_uv_m for o in solution.observations], atol=1e-9
    )
    test, _ = refit_and_test(plan, chosen, background)
    assert test is not None
    np.testing.assert_allclose(test.residual_mm, 0.0, atol=1e-3)  # 1e-6 m
    assert test.chi_square == pytest.approx(0.0, abs=1e-6)


def test_a_calibration_without_a_recorded_first_pass_is_refitted_with_its_own_transform(
    calibrated: tuple[TwoPassSolution, list[WaypointMeasurement], AveragedScan, Path], tmp_path: Path
) -> None:
    """A result.json that does not record its first pass (an older one): the calibrated
    transform and the raw ranges, as the verify did before."""
    _, _, _, path = calibrated
    document = json.loads(path.read_text(encoding="utf-8"))
    del document["run"]["first_pass"]
    document["provenance"]["solver_options"].pop("range_offset_applied_m")
    older = tmp_path / "result.json"
    older.write_text(json.dumps(document), encoding="utf-8")
    refit = load_active_calibration(older).refit()
    np.testing.assert_array_equal(refit.T_base_laser, load_active_calibration(older).T_base_laser)
    assert refit.range_offset_m == 0.0
