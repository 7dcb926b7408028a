"""The accuracy benchmarks' noise streams, waypoint file and the drill job's information limit."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from benchmarks.accuracy_conditions import cases, noise_rng, with_waypoints_file
from benchmarks.dry_run_accuracy import world_with
from benchmarks.error_budget import VARIANTS, bound_p95, bound_rows, case_job
from fakes.scene import load_scene
from lasercal_hw.config import with_overrides
from lasercal_hw.run.waypoints import listed_waypoints, planned_waypoints

ROOT = Path(__file__).resolve().parents[2]


def _case(name: str):
    return next(c for c in cases() if c.name == name)


def test_noise_stream_zero_is_the_published_draws() -> None:
    assert np.array_equal(noise_rng(7).normal(size=5), np.random.default_rng(7).normal(size=5))
    assert np.array_equal(noise_rng(7, 0).normal(size=5), np.random.default_rng(7).normal(size=5))


def test_other_noise_streams_are_new_draws_and_repeat() -> None:
    zero, one, two = (noise_rng(7, k).normal(size=5) for k in (0, 1, 2))
    assert not np.allclose(one, zero) and not np.allclose(two, one)
    assert np.array_equal(noise_rng(7, 1).normal(size=5), one)
    assert not np.allclose(noise_rng(8, 1).normal(size=5), one)  # the seed still counts


def test_a_negative_noise_stream_is_refused() -> None:
    with pytest.raises(ValueError, match="noise stream -1"):
        noise_rng(0, -1)


def test_the_drill_bound_counts_the_axis_its_job_estimates() -> None:
    # Four more unknowns on the same waypoints can only widen the bound: a bound that left the
    # axis out (as before) would give the same figures both ways.
    fluted = _case("drill-fluted")
    assert fluted.job.rod.estimate_axis
    told = dataclasses.replace(fluted, job=with_overrides(fluted.job, {"rod.estimate_axis": False}))
    waypoints = planned_waypoints(fluted.job)
    truth = world_with(load_scene(fluted.scene_path), fluted.true_rod, 0).ground_truth_T_base_laser
    with_axis = bound_p95(fluted, waypoints, truth, 0.0005, 0.00058, 2)
    without = bound_p95(told, waypoints, truth, 0.0005, 0.00058, 2)
    assert with_axis[0] > without[0] * 1.02 and with_axis[1] > without[1]


def test_a_twist_drills_bound_has_a_row_with_the_flute_allowance() -> None:
    fluted = bound_rows(_case("drill-fluted").job)
    assert len(fluted) == 4 and fluted[-1][1] == pytest.approx(np.hypot(0.0005, 0.25 * 0.005))
    assert len(bound_rows(_case("default-3s").job)) == 3


def test_the_waypoints_file_replaces_a_drill_cases_file_only(tmp_path: Path) -> None:
    listed = (ROOT / "examples" / "drill-waypoints.csv").read_text().splitlines()
    short = tmp_path / "short.csv"
    short.write_text("\n".join(listed[:7]) + "\n")
    drill = with_waypoints_file(_case("drill-fluted"), short)
    assert len(listed_waypoints(drill.job)) == 6
    default = _case("default-3s")
    assert with_waypoints_file(default, short) is default  # a preset's case keeps its preset
    with pytest.raises(FileNotFoundError, match=r"missing\.csv"):
        with_waypoints_file(_case("drill-fluted"), tmp_path / "missing.csv")


def test_axis_known_tells_the_solver_the_real_bit() -> None:
    case = _case("drill-fluted")
    variant = next(v for v in VARIANTS if v.name == "axis-known")
    job = case_job(case, variant)
    assert job.rod.estimate_axis is False
    assert np.allclose(job.rod.rod_line().origin_m, case.true_rod.origin_m)
    assert np.allclose(job.rod.rod_line().unit_direction(), case.true_rod.unit_direction())
    assert not np.allclose(case.job.rod.rod_line().origin_m, case.true_rod.origin_m)
