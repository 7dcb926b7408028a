"""A running visit's time left (``run.time_left``) where the UR5 model plans it and where it cannot."""

from __future__ import annotations

import numpy as np
import pytest

from lasercal_hw.config import job_from_mapping
from lasercal_hw.run.time_left import TimeLeft
from lasercal_hw.run.timing import background_s, dwell_each_s
from tests.doubles import semicircle_waypoints


def test_moves_ahead_keep_the_pace_of_the_moves_made_and_dwells_stay_planned() -> None:
    job = job_from_mapping({"dwell_s": 0.5})
    plan = TimeLeft.plan(job, semicircle_waypoints(4), [0, 1, 2, 3])
    assert plan.to_retract_s is not None and set(plan.move_s) == {0, 1, 2, 3}

    plan.moved(None, 3.0 * plan.to_retract_s)
    left_s = plan.seconds(retract_ahead=False, background_ahead=True, moves_ahead=[1, 2], dwells_ahead=3)
    expected_s = 3.0 * (plan.move_s[1] + plan.move_s[2]) + plan.background_s + 3 * plan.dwell_each_s
    assert left_s == pytest.approx(expected_s)


def test_a_visit_the_model_cannot_plan_counts_the_mean_move_so_far() -> None:
    job = job_from_mapping({"dwell_s": 0.5})
    out_of_reach = np.array([[5.0, 0.0, 0.3, np.pi, 0.0, 0.0], [5.0, 0.5, 0.3, np.pi, 0.0, 0.0]])
    plan = TimeLeft.plan(job, out_of_reach, [0, 1])
    assert plan.to_retract_s is None and plan.move_s == {}
    before_s = plan.seconds(retract_ahead=True, background_ahead=True, moves_ahead=[0, 1], dwells_ahead=2)
    assert before_s == pytest.approx(background_s(job) + 2 * dwell_each_s(job))  # no move known yet

    plan.moved(None, 4.0)
    plan.moved(0, 2.0)
    left_s = plan.seconds(retract_ahead=False, background_ahead=False, moves_ahead=[1], dwells_ahead=2)
    assert left_s == pytest.approx(3.0 + 2 * dwell_each_s(job))
