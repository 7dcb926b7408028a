"""The verify chooses among every waypoint the calibration visited: ``result.json`` records
them (``run.waypoints``), an adaptive run's second design and a spun drill's turned waypoints
included, and the residual at each is matched to its pose. A file without the record falls back
to the job's waypoints (an adaptive job's first design) and says so."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from lasercal_hw.config import job_from_mapping
from lasercal_hw.errors import ConfigError
from lasercal_hw.run import flute_spin
from lasercal_hw.run.adaptive import run_second_design
from lasercal_hw.run.flute_spin import SpinPhase, run_turned_waypoints, turned_about_bit
from lasercal_hw.run.outputs import result_document
from lasercal_hw.run.records import RunOutcome
from lasercal_hw.run.sequencer import Sequencer
from lasercal_hw.run.waypoints import job_waypoints, listed_waypoints
from lasercal_hw.verify.active import ActiveCalibration, load_active_calibration
from lasercal_hw.verify.procedure import plan_active, time_budget_s
from tests.doubles import MemoryRecorder, run_calibration
from tests.run.test_adaptive import ADAPTIVE
from tests.run.test_flute_spin import _spun_job
from tests.run.test_sequencer import make_cell

FIRST = ADAPTIVE["trajectory"]["first_waypoints"]
EVERY = ADAPTIVE["trajectory"]["design_waypoints"]


@pytest.fixture(scope="module")
def adaptive_run() -> tuple[RunOutcome, dict[str, Any]]:
    """An adaptive calibration on the doubles (6 waypoints designed first, 6 from its estimate)
    and the ``result.json`` document it writes."""
    job = job_from_mapping(ADAPTIVE)
    first = job_waypoints(job)
    clock, robot, scanner = make_cell(job)
    recorder = MemoryRecorder()
    outcome = run_calibration(robot, scanner, recorder, job, first, clock=clock)
    final = run_second_design(robot, scanner, recorder, job, first, outcome, clock=clock)
    return final, json.loads(json.dumps(result_document(final, job)))


def written(tmp_path: Path, document: dict[str, Any]) -> Path:
    path = tmp_path / "result.json"
    path.write_text(json.dumps(document), encoding="utf-8")
    return path


def test_result_json_records_every_waypoint_of_both_designs(adaptive_run, tmp_path: Path) -> None:
    final, document = adaptive_run
    active = load_active_calibration(written(tmp_path, document))
    assert active.run_waypoints is not None and active.run_waypoints.shape == (EVERY, 6)
    assert np.array_equal(active.run_waypoints, final.waypoints)
    assert np.array_equal(active.run_waypoints[:FIRST], job_waypoints(active.job))
    assert sorted(r.index for r in active.result.residuals) == list(range(EVERY))


def test_the_verify_chooses_among_the_second_design_too(adaptive_run, tmp_path: Path) -> None:
    _, document = adaptive_run
    active = load_active_calibration(written(tmp_path, document))
    plan = plan_active(active, active.job, count=EVERY - 2)
    assert plan.waypoints.shape == (EVERY, 6)
    used = [r.index for r in active.result.residuals if r.used]
    assert any(i >= FIRST for i in used)
    # The residual the calibration saw is the prediction's offset at every waypoint it used,
    # the second design's included (matched by pose).
    assert np.isfinite(plan.reference[used]).all()
    by_index = {r.index: (r.du_mm, r.dv_mm) for r in active.result.residuals}
    for i in used:
        assert np.allclose(1000.0 * plan.reference[i], by_index[i])
    assert any(i >= FIRST for i in plan.selection.indices)
    assert "run.waypoints" in active.waypoints_note()
    # Both designs' motion and dwell are the budget's base.
    assert time_budget_s(active, active.job) > 1.5 * _first_design_budget_s(document, tmp_path)


def _first_design_budget_s(document: dict[str, Any], tmp_path: Path) -> float:
    older = json.loads(json.dumps(document))
    del older["run"]["waypoints"]
    older_dir = tmp_path / "older"
    older_dir.mkdir(exist_ok=True)
    active = load_active_calibration(written(older_dir, older))
    budget_s = time_budget_s(active, active.job)
    assert budget_s is not None
    return budget_s


def test_a_file_without_the_record_falls_back_to_the_first_design_and_says_so(
    adaptive_run, tmp_path: Path
) -> None:
    _, document = adaptive_run
    del document["run"]["waypoints"]
    active = load_active_calibration(written(tmp_path, document))
    assert active.run_waypoints is None
    plan = plan_active(active, active.job)
    assert plan.waypoints.shape == (FIRST, 6)
    assert all(i < FIRST for i in plan.selection.indices)
    assert "second design" in active.waypoints_note()


@pytest.mark.parametrize(
    "bad", [[[0.1, 0.2, 0.3]], "poses", [[0.0] * 5 + [float("nan")]], [[1, 2, 3, 4, 5, 6], [1]]]
)
def test_malformed_waypoints_are_refused_by_name(adaptive_run, tmp_path: Path, bad: Any) -> None:
    _, document = adaptive_run
    document = json.loads(json.dumps(document))
    document["run"]["waypoints"] = bad
    with pytest.raises(ConfigError, match=r"run\.waypoints is not a list of UR poses"):
        load_active_calibration(written(tmp_path, document))


def spun_calibration(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> ActiveCalibration:
    """A ``flute_phase_deg`` calibration on the doubles (the spin told a 30 deg turn), as its
    ``result.json`` records it."""
    job = _spun_job(tmp_path)
    spin = job_waypoints(job)
    told = SpinPhase(phase_deg=60.0, phase_std_deg=3.0, gain=20.0, shift_deg=30.0, centres=9)
    monkeypatch.setattr(flute_spin, "phase_from_spin", lambda *args: told)
    clock, robot, scanner = make_cell(job)
    recorder = MemoryRecorder()
    spun = Sequencer(robot, scanner, recorder, job, spin, clock=clock).measure()
    outcome = run_turned_waypoints(robot, scanner, recorder, job, spin, spun, clock=clock)
    return load_active_calibration(written(tmp_path, json.loads(json.dumps(result_document(outcome, job)))))


def test_a_spun_drill_s_turned_waypoints_are_matched_to_their_own_residuals(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A ``flute_phase_deg`` run visits the spin, then its listed waypoints turned about the bit:
    the verify's candidates are those poses, each with the residual measured at that pose (not
    the spin's, which share the first indices; a pose visited twice takes its first visit's)."""
    active = spun_calibration(tmp_path, monkeypatch)
    job = active.job
    spin = job_waypoints(job)

    plan = plan_active(active, active.job)
    turned = turned_about_bit(listed_waypoints(job), job.rod.rod_line(), 30.0)
    assert np.allclose(plan.waypoints, np.vstack([spin, turned]))
    measured = {r.index: (r.du_mm, r.dv_mm) for r in active.result.residuals if r.used}
    first_visit = {
        i: min(j for j in measured if np.allclose(plan.waypoints[j], plan.waypoints[i], atol=1e-6))
        for i in measured
    }
    assert any(i >= len(spin) and first_visit[i] == i for i in measured)
    for i, j in first_visit.items():
        assert np.allclose(1000.0 * plan.reference[i], measured[j])


def test_a_pose_visited_twice_is_one_candidate(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The spin's 30 deg turn is waypoint 0 turned: the verify counts that pose once (its later
    visit is left out, by name in ``selection.left_out``), so no choice weighs one pose twice."""
    active = spun_calibration(tmp_path, monkeypatch)
    plan = plan_active(active, active.job, count=len(plan_active(active, active.job).waypoints))
    repeats = [
        k for k in range(1, len(plan.waypoints))
        if np.any(np.max(np.abs(plan.waypoints[:k] - plan.waypoints[k]), axis=1) <= 1e-6)
    ]
    assert repeats, "the fixture should visit one pose twice"
    assert set(repeats) <= set(plan.selection.left_out)
    assert not set(repeats) & set(plan.selection.indices)
    chosen = plan.waypoints[plan.selection.indices]
    assert len({tuple(np.round(pose, 6)) for pose in chosen}) == len(chosen)
