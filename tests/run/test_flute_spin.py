"""The spin before a twist drill's waypoints (``trajectory.flute_phase_deg``): the phase it tells,
the waypoints turned about the bit, and the recording that keeps the turn for resume and replay."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lasercal_hw.calibration.flutes import facing_angles_rad, flute_offsets_m
from lasercal_hw.calibration.model import moved_rod, plane_crossing, rod_lines_in_base
from lasercal_hw.config import job_from_mapping, load_job
from lasercal_hw.errors import ConfigError
from lasercal_hw.models import RobotIdentity, ScannerIdentity
from lasercal_hw.run import flute_spin
from lasercal_hw.run.engine import MotionPlan
from lasercal_hw.run.flute_spin import (
    SPIN_TURNS_DEG,
    SpinPhase,
    phase_from_spin,
    run_turned_waypoints,
    spin_poses,
    tool_shift_deg,
    turned_about_bit,
    turned_within_reach,
    turns_to_try_deg,
)
from lasercal_hw.run.preflight import PreflightReport
from lasercal_hw.run.replay import solve_recording
from lasercal_hw.run.resume import recorded_job, resume_state
from lasercal_hw.run.sequencer import Sequencer
from lasercal_hw.run.two_pass import predict_rod
from lasercal_hw.run.waypoints import job_waypoints, listed_waypoints
from lasercal_hw.session.reader import read_session
from lasercal_hw.session.recorder import SessionRecorder
from tests.doubles import semicircle_waypoints
from tests.run.test_sequencer import FAST_JOB, make_cell

DRILL_JOB = Path(__file__).resolve().parents[2] / "examples" / "drill.toml"
SIGMA_M = 0.0003


def real_bit(rod):
    """The real bit: 2 mm off and 1 deg tilted from the job's axis, as the benchmark's."""
    return moved_rod(rod, np.array([0.0014, 0.0014, 0.0123, 0.0123]))


@pytest.fixture(scope="module")
def drill():
    """The drill job, its listed waypoints and its nominal pose (the truth here)."""
    job = load_job(DRILL_JOB)
    return job, job.rod.rod_line(), listed_waypoints(job), job.scanner.nominal.matrix()


def _spin_centres(rod, first_waypoint, truth, phase_deg, rng, flutes=True):
    """Plain fits of a twist drill 2 mm off and 1 deg tilted from ``rod`` over the spin: where the
    real bit crosses the plane, the section's offset at its turn and a little noise."""
    real = real_bit(rod)
    poses = spin_poses(first_waypoint, rod)
    origins, directions = rod_lines_in_base(poses, real)
    centres, _, _ = plane_crossing(truth[:3, :3], truth[:3, 3], origins, directions)
    if flutes:
        centres = centres + flute_offsets_m(np.radians(phase_deg), truth, poses, real)
    centres = centres + rng.normal(0.0, SIGMA_M, centres.shape)
    return poses, centres, np.broadcast_to(np.eye(2) * SIGMA_M**2, (len(poses), 2, 2)).copy()


def test_turning_about_the_bit_keeps_its_crossing_and_turns_its_facing(drill):
    """A waypoint turned about the bit's nominal axis: the bit crosses the plane where it did,
    along the same line, and faces the scanner turned by the same angle."""
    _, rod, waypoints, T = drill
    turned = turned_about_bit(waypoints, rod, 37.0)
    for before, after in zip(waypoints, turned, strict=True):
        was, now = predict_rod(T, before, rod), predict_rod(T, after, rod)
        assert np.allclose(now.expected_uv_m, was.expected_uv_m, atol=1e-9)
        assert np.allclose(now.axis_in_scanner, was.axis_in_scanner, atol=1e-9)
    assert not np.allclose(turned, waypoints)
    change = facing_angles_rad(0.0, T, turned, rod) - facing_angles_rad(0.0, T, waypoints, rod)
    facing_change = np.degrees(change)
    assert np.allclose((facing_change + 180.0) % 360.0 - 180.0, -37.0, atol=1e-6)


@pytest.mark.parametrize("phase_deg", [17.0, 64.0, 118.0, 161.0])
def test_the_spin_tells_the_phase_of_a_bit_off_its_nominal_axis(drill, phase_deg):
    """Synthetic spins of a bit at a phase the run does not know, 2 mm off and 1 deg tilted from its
    nominal axis (its crossings a few degrees further along the helix than the nominal axis's): the
    phase within a few degrees, and the shift that brings it to the one the file was checked at."""
    _, rod, waypoints, T = drill
    poses, centres, covariances = _spin_centres(rod, waypoints[0], T, phase_deg, np.random.default_rng(5))
    found = phase_from_spin(poses, centres, covariances, T, rod, 90.0)
    assert found is not None and found.centres == len(SPIN_TURNS_DEG)
    assert abs((found.phase_deg - phase_deg + 90.0) % 180.0 - 90.0) < 6.0
    assert abs(tool_shift_deg(phase_deg, 90.0) - found.shift_deg) < 6.0
    assert f"tool turns shifted by {found.shift_deg:+.0f} deg" in found.note


def test_a_round_bit_tells_no_phase(drill):
    """Without flutes the spin's centres carry no phase: no shift is made."""
    _, rod, waypoints, T = drill
    rng = np.random.default_rng(6)
    poses, centres, covariances = _spin_centres(rod, waypoints[0], T, 0.0, rng, flutes=False)
    assert phase_from_spin(poses, centres, covariances, T, rod, 90.0) is None


def test_tool_shift_takes_the_short_way_round_the_half_turn():
    assert tool_shift_deg(90.0, 90.0) == 0.0
    assert tool_shift_deg(170.0, 90.0) == pytest.approx(-80.0)
    assert tool_shift_deg(10.0, 90.0) == pytest.approx(80.0)
    assert tool_shift_deg(179.0, 0.0) == pytest.approx(1.0)


def test_the_turns_tried_come_nearest_the_checked_facing_first():
    assert turns_to_try_deg(30.0) == pytest.approx([30.0, -150.0, 20.0, 10.0, 0.0])
    assert turns_to_try_deg(-85.0) == pytest.approx([-85.0, 95.0, *np.linspace(-85.0, 0.0, 10)[1:]])
    assert turns_to_try_deg(0.0) == [0.0, -180.0]


def test_a_waypoint_out_of_reach_at_the_shift_takes_the_nearest_turn_within_reach(drill):
    _, rod, listed, _ = drill
    first_three = listed[:3]
    out_of_reach = {1: [30.0, -150.0], 2: turns_to_try_deg(30.0)}  # listed 2: no turn within reach

    def reachable(pose):
        return not any(
            np.allclose(pose, turned_about_bit(first_three[k], rod, turn)[0])
            for k, turns in out_of_reach.items()
            for turn in turns
        )

    turned, instead = turned_within_reach(first_three, rod, 30.0, reachable)
    assert instead == {1: pytest.approx(20.0), 2: None}
    assert np.allclose(turned[0], turned_about_bit(first_three[0], rod, 30.0)[0])
    assert np.allclose(turned[1], turned_about_bit(first_three[1], rod, 20.0)[0])
    assert np.array_equal(turned[2], first_three[2])  # as listed: the preflight names it


SPUN = {
    **FAST_JOB,
    # The doubles' rod is round, which the fluted extraction moves by a flute's mean offset (about
    # half the radius): a thin one keeps that within the centres' allowance.
    "rod": {"fluted": True, "radius_m": 0.01},
    "scanner": {"nominal": {"translation_m": [0.30, 0.50, 0.20], "euler_zyx_deg": [5.0, 7.0, 3.0]}},
}


def _spun_job(tmp_path: Path):
    listed = tmp_path / "waypoints.csv"
    rows = [f"{k}," + ",".join(f"{v:.9f}" for v in pose) for k, pose in enumerate(semicircle_waypoints(12))]
    listed.write_text("index,x,y,z,rx,ry,rz\n" + "\n".join(rows) + "\n", encoding="utf-8")
    return job_from_mapping({**SPUN, "trajectory": {"waypoints_file": str(listed), "flute_phase_deg": 90.0}})


def test_a_spun_run_records_the_turn_it_made_and_resume_and_replay_read_it(tmp_path, monkeypatch):
    """The run visits its waypoints turned by the spin's shift; the recording keeps the turned
    waypoints and the shift, which a resumed run reads (it does not fit the spin again), and
    ``lasercal solve session.mcap`` gives the live result."""
    job = _spun_job(tmp_path)
    spin = job_waypoints(job)
    assert spin.shape == (len(SPIN_TURNS_DEG), 6)
    told = SpinPhase(phase_deg=60.0, phase_std_deg=3.0, gain=20.0, shift_deg=30.0, centres=9)
    monkeypatch.setattr(flute_spin, "phase_from_spin", lambda *args: told)
    clock, robot, scanner = make_cell(job)
    path = tmp_path / "session.mcap"
    recorder = SessionRecorder(path, {"job": job.model_dump(mode="json"), "waypoints": spin.tolist()})
    try:
        spun = Sequencer(robot, scanner, recorder, job, spin, clock=clock).measure()
        outcome = run_turned_waypoints(robot, scanner, recorder, job, spin, spun, clock=clock)
    finally:
        recorder.close()

    turned = turned_about_bit(listed_waypoints(job), job.rod.rod_line(), 30.0)
    visited = {m.index: m.tcp_pose for m in outcome.measurements}
    assert sorted(visited) == list(range(len(spin) + len(turned)))
    assert np.allclose([visited[len(spin) + k] for k in range(len(turned))], turned)
    assert outcome.refinement.startswith("flute phase ~60 +- 3 deg from the spin")
    assert "tool turns shifted by +30 deg" in outcome.refinement

    monkeypatch.setattr(flute_spin, "phase_from_spin", lambda *args: pytest.fail("a resume fits no spin"))
    recording = read_session(path)
    (design,) = recording.events_of("trajectory_design")
    assert design["tool_turn_shift_deg"] == 30.0 and design["flute_phase_deg"] == 60.0
    _, waypoints = recorded_job(recording)
    assert np.allclose(waypoints, np.vstack([spin, turned]))
    replayed = solve_recording(path).solution
    assert np.array_equal(replayed.result.matrix(), outcome.result.matrix())
    assert replayed.refinement == f"as the live run recorded it, not fitted again: {outcome.refinement}"

    # Resumed after the turn, the run is solved as it is and says what its turn was, as it did.
    state = resume_state(recording)
    assert state.turn_note == design["notes"][0]
    every = np.vstack([spin, turned])
    meta = {"job": job.model_dump(mode="json"), "waypoints": every.tolist()}
    again = SessionRecorder(tmp_path / "again.mcap", meta)
    try:
        measured = Sequencer(robot, scanner, again, job, every, clock=clock, resume=state).measure()
        resumed = run_turned_waypoints(robot, scanner, again, job, every, measured, clock=clock,
                                       resumed_turn_note=state.turn_note)
    finally:
        again.close()
    assert resumed.refinement.startswith(f"{design['notes'][0]}; ")


def test_a_spun_run_turns_a_waypoint_out_of_reach_the_other_way_round(tmp_path, monkeypatch):
    """A waypoint turned to the phase can fall out of the arm's reach (the 12th of the drill's file
    from +80 deg on a UR5); the preflight of the turned waypoints refused the whole rest of the
    run. The run takes the same facing the other way round, and says so."""
    job = _spun_job(tmp_path)
    spin = job_waypoints(job)
    told = SpinPhase(phase_deg=60.0, phase_std_deg=3.0, gain=20.0, shift_deg=30.0, centres=9)
    monkeypatch.setattr(flute_spin, "phase_from_spin", lambda *args: told)
    listed, rod = listed_waypoints(job), job.rod.rod_line()
    clock, robot, scanner = make_cell(job, forbidden_poses=[turned_about_bit(listed[4], rod, 30.0)[0]])
    recorder = SessionRecorder(tmp_path / "session.mcap", {"job": job.model_dump(mode="json"),
                                                           "waypoints": spin.tolist()})
    try:
        spun = Sequencer(robot, scanner, recorder, job, spin, clock=clock).measure()
        outcome = run_turned_waypoints(robot, scanner, recorder, job, spin, spun, clock=clock)
    finally:
        recorder.close()

    visited = {m.index: m.tcp_pose for m in outcome.measurements}
    first = len(spin)
    assert sorted(visited) == list(range(first + len(listed)))
    assert np.allclose(visited[first + 4], turned_about_bit(listed[4], rod, -150.0)[0])
    assert np.allclose(visited[first + 3], turned_about_bit(listed[3], rod, 30.0)[0])
    taken = f"out of reach so, turned otherwise: waypoint {first + 4} (listed 4) by -150 deg"
    assert taken in outcome.refinement


def test_flute_phase_needs_a_fluted_rod_and_a_rough_scanner_pose(tmp_path):
    job = _spun_job(tmp_path).model_dump(mode="json")
    with pytest.raises(ConfigError, match=r"set rod\.fluted = true"):
        job_from_mapping({**job, "rod": {**job["rod"], "fluted": False}})
    with pytest.raises(ConfigError, match=r"needs \[scanner.nominal\]"):
        job_from_mapping({**job, "scanner": {**job["scanner"], "nominal": None}})
    with pytest.raises(ConfigError, match="an adaptive run designs its own"):
        job_from_mapping({"trajectory": {"adaptive": True, "flute_phase_deg": 90.0}})



def test_the_question_before_motion_says_a_spun_run_goes_on_after_its_spin(tmp_path):
    """The operator confirms the whole run: a spun job's first part is its 12 spin dwells, and
    the question said only "through 12 waypoints" though the arm then visits the rest."""
    job = _spun_job(tmp_path)
    report = PreflightReport(
        RobotIdentity("UR5", "sim-0001", "5.11.0", (5, 11, 0, 0)),
        ScannerIdentity("Hokuyo", "UTM-30LX-EW", "1.0", "SCIP 2.0", "H0000", "UTM"),
        [],
    )
    first = MotionPlan(report, job, len(SPIN_TURNS_DEG)).summary()
    assert "through 12 waypoints (the bit's spin), then the job's 12 turned about the bit" in first
    resumed = MotionPlan(report, job, len(SPIN_TURNS_DEG) + 12).summary()  # the turned ones recorded
    assert "through 24 waypoints, " in resumed
    assert "spin" not in resumed
