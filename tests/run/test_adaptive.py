"""The adaptive run: a robust first design, a solve, the rest designed from the estimate,
one final solve over all; the designs are recorded so a resumed run knows every waypoint."""

from __future__ import annotations

import numpy as np
import pytest

from lasercal_hw.config import job_from_mapping
from lasercal_hw.errors import ConfigError
from lasercal_hw.run.adaptive import run_second_design
from lasercal_hw.run.resume import DESIGN_EVENT
from lasercal_hw.run.waypoints import job_waypoints
from tests.doubles import PAPER_T_BASE_LASER, MemoryRecorder, run_calibration
from tests.run.test_sequencer import FAST_JOB, make_cell, transform_error

ADAPTIVE = {
    **FAST_JOB,
    # 4 cm and 4 deg off the double's scanner.
    "scanner": {"nominal": {"translation_m": [0.33, 0.47, 0.22], "euler_zyx_deg": [8.0, 5.0, 5.0]}},
    "trajectory": {"adaptive": True, "first_waypoints": 6, "design_waypoints": 12},
}


def test_adaptive_run_designs_the_rest_from_its_first_estimate_and_solves_all() -> None:
    job = job_from_mapping(ADAPTIVE)
    first = job_waypoints(job)
    assert first.shape == (6, 6)
    clock, robot, scanner = make_cell(job)
    recorder = MemoryRecorder()
    outcome = run_calibration(robot, scanner, recorder, job, first, clock=clock)
    final = run_second_design(robot, scanner, recorder, job, first, outcome, clock=clock)

    designs = [fields for _, kind, fields in recorder.events if kind == DESIGN_EVENT]
    assert [d["phase"] for d in designs] == [1, 2]
    assert designs[1]["first_index"] == 6 and len(designs[1]["waypoints"]) == 6
    assert np.allclose(designs[1]["designed_from_T_base_laser"], outcome.result.matrix())
    assert sorted(m.index for m in final.measurements) == list(range(12))
    final_t, final_r = transform_error(final.result.matrix(), PAPER_T_BASE_LASER)
    assert final_t < 5.0 and final_r < 0.5
    assert max(final.result.std_rotation_deg) < max(outcome.result.std_rotation_deg)


def test_adaptive_run_needs_a_rough_scanner_pose() -> None:
    job = job_from_mapping({**ADAPTIVE, "scanner": {}})
    with pytest.raises(ConfigError, match=r"set \[scanner.nominal\]"):
        job_waypoints(job)


def test_adaptive_run_refuses_a_waypoint_file() -> None:
    with pytest.raises(ConfigError, match="designs its own waypoints"):
        job_from_mapping({"trajectory": {"adaptive": True, "waypoints_file": "w.csv"}})
