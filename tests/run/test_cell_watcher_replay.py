"""A cell's watcher (``run/watchers``) records every scan it reads in the calibrated scanner's
recording, on its own topic, and a replay (``run/replay.replay_shared_centres``, what the cell's
agreement reads) computes each watcher's centre again from them as the live watcher did, then,
given the watcher's solved run, fits it again as its second pass; a recording without them says
which centres it reused and why. Simulated devices, simulated time."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from lasercal_hw.config import NominalPose
from lasercal_hw.geometry import euler_zyx_to_matrix, make_transform, matrix_to_euler_zyx
from lasercal_hw.run.records import RunOutcome
from lasercal_hw.run.replay import replay_shared_centres
from lasercal_hw.run.two_pass import predict_rod
from lasercal_hw.run.watchers import SHARED_OBSERVATION, SolvedWatcher, Watcher
from lasercal_hw.session.format import TOPIC_EVENT, scan_topics
from lasercal_hw.session.reader import SessionRecording, read_session
from lasercal_hw.session.recorder import SessionRecorder
from tests.doubles import (
    PAPER_T_BASE_LASER,
    SimClock,
    SimRobot,
    SimScanner,
    run_calibration,
    semicircle_waypoints,
)
from tests.run.test_replay import _copy
from tests.run.test_sequencer import fast_job

#: The watcher 4 cm above the calibrated scanner, turned 3 deg: the rod crosses both planes.
T_WATCHER = make_transform(euler_zyx_to_matrix(*np.radians([3.0, 7.0, 3.0])), [0.30, 0.50, 0.24])
#: Its nominal pose: a tape measure's, 1 cm and 1 deg off.
NOMINAL = NominalPose(
    translation_m=(T_WATCHER[:3, 3] + [0.01, 0.0, 0.0]).tolist(),
    euler_zyx_deg=(np.degrees(matrix_to_euler_zyx(T_WATCHER[:3, :3])) + np.array([1.0, 0.0, 0.0])).tolist(),
)
WATCH_TOPICS = scan_topics("rear")[:2]


def _record(path: Path) -> RunOutcome:
    job = fast_job()
    clock = SimClock()
    robot = SimRobot(clock)
    rod = job.rod.rod_line()
    scanner = SimScanner(clock, robot, rod, T_base_laser=PAPER_T_BASE_LASER)
    watcher = Watcher("rear", SimScanner(clock, robot, rod, T_base_laser=T_WATCHER, seed=2), NOMINAL.matrix())
    waypoints = semicircle_waypoints(count=8)
    recorder = SessionRecorder(path, {"job": job.model_dump(mode="json"), "waypoints": waypoints.tolist()})
    try:
        return run_calibration(robot, scanner, recorder, job, waypoints, clock=clock, watchers=[watcher])
    finally:
        recorder.close()


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("watcher") / "session.mcap"
    _record(path)
    return path


def _replay(recording: SessionRecording):
    return replay_shared_centres(recording, fast_job().rod.rod_line(), {"rear": NOMINAL})


def test_the_watchers_scans_are_in_the_recording_on_their_own_topic(recorded: Path) -> None:
    recording = read_session(recorded)
    shared = recording.events_of(SHARED_OBSERVATION)
    assert len(shared) >= 6, "the watcher saw the rod at most waypoints"
    watched = recording.scans_by_scanner["rear"]
    assert list(recording.scans_by_scanner) == ["rear"]
    for event in shared:  # every scan it averaged is on record, the run's own scans apart
        start_s, end_s = event["window_start_s"], event["window_end_s"]
        assert len([s for s in watched if start_s <= s.device_time_s < end_s]) == event["scans"] >= 5
        assert [s for s in recording.scans if start_s <= s.device_time_s < end_s] == []


def test_a_replay_computes_every_watcher_centre_again_as_the_live_watcher_did(recorded: Path) -> None:
    recording = read_session(recorded)
    replayed = _replay(recording)
    shared = recording.events_of(SHARED_OBSERVATION)
    assert replayed.notes == {} and replayed.recomputed == {"rear": len(shared)}
    for event in shared:
        tcp_pose, centre_uv_m, covariance_uv_m2 = replayed.centres["rear"][event["index"]]
        np.testing.assert_allclose(tcp_pose, event["tcp_pose"], rtol=0, atol=1e-12)
        np.testing.assert_allclose(centre_uv_m, event["centre_uv_m"], rtol=0, atol=1e-12)
        np.testing.assert_allclose(covariance_uv_m2, event["covariance_uv_m2"], rtol=1e-9, atol=1e-18)


def test_with_the_watchers_solved_pose_every_centre_gets_its_second_pass(recorded: Path) -> None:
    recording = read_session(recorded)
    rod = fast_job().rod.rod_line()
    first = _replay(recording)
    solved = {"rear": SolvedWatcher(T_WATCHER, rod, None, None)}
    second = replay_shared_centres(recording, rod, {"rear": NOMINAL}, solved)
    assert second.notes == {} and second.second_pass == second.recomputed == first.recomputed
    errors_mm = {"first": [], "second": []}
    for index, (tcp_pose, centre_uv_m, _) in first.centres["rear"].items():
        truth = predict_rod(T_WATCHER, tcp_pose, rod).expected_uv_m  # the rod is cut where it crosses
        errors_mm["first"].append(1e3 * np.linalg.norm(centre_uv_m - truth))
        errors_mm["second"].append(1e3 * np.linalg.norm(second.centres["rear"][index][1] - truth))
    assert errors_mm["second"] != errors_mm["first"]  # fitted again, with the solved pose's axis
    assert np.mean(errors_mm["second"]) <= np.mean(errors_mm["first"]), errors_mm


def test_a_second_pass_that_finds_no_rod_keeps_the_first_with_its_scanners_scatter(recorded: Path) -> None:
    recording = read_session(recorded)
    rod = fast_job().rod.rod_line()
    far = T_WATCHER.copy()
    far[:3, 3] += 0.5 * T_WATCHER[:3, 0]  # a solved pose that puts the rod half a metre from where it is
    scatter_uv_m2 = np.diag([4e-6, 1e-6])
    first = _replay(recording)
    solved = {"rear": SolvedWatcher(far, rod, None, scatter_uv_m2)}
    kept = replay_shared_centres(recording, rod, {"rear": NOMINAL}, solved)
    assert kept.second_pass == {"rear": 0} and kept.recomputed == first.recomputed
    for index, (_, centre_uv_m, covariance_uv_m2) in first.centres["rear"].items():
        _, kept_uv_m, kept_covariance_uv_m2 = kept.centres["rear"][index]
        np.testing.assert_array_equal(kept_uv_m, centre_uv_m)
        np.testing.assert_allclose(kept_covariance_uv_m2, covariance_uv_m2 + scatter_uv_m2, rtol=1e-12)


def as_before_watchers_scans(name: str) -> Callable[[str, bytes], bytes | None]:
    """A recording's messages as written before the watcher ``name``'s scans were recorded:
    none of its scans, no window in its events (for ``tests/run/test_replay._copy``)."""
    dropped = scan_topics(name)[:2]

    def change(topic: str, data: bytes) -> bytes | None:
        if topic in dropped:
            return None
        if topic == TOPIC_EVENT:
            event = json.loads(data)
            if event["kind"] == SHARED_OBSERVATION and event["scanner"] == name:
                event.pop("window_start_s")
                event.pop("window_end_s")
            return json.dumps(event).encode()
        return data

    return change


def test_an_older_recording_reuses_the_recorded_centres_and_says_so(recorded: Path, tmp_path: Path) -> None:
    recording = read_session(_copy(recorded, tmp_path / "old.mcap", as_before_watchers_scans("rear")))
    replayed = _replay(recording)
    shared = recording.events_of(SHARED_OBSERVATION)
    assert replayed.recomputed == {}
    (note,) = replayed.notes["rear"]
    indices = ", ".join(str(event["index"]) for event in shared)
    assert f"rear's centres at waypoints {indices} are reused as recorded" in note
    assert "holds no scans of them" in note and str(tmp_path / "old.mcap") in note
    for event in shared:
        np.testing.assert_array_equal(replayed.centres["rear"][event["index"]][1], event["centre_uv_m"])


def test_a_watcher_centre_whose_scans_are_gone_is_left_out_saying_why(recorded: Path, tmp_path: Path) -> None:
    without_scans = _copy(recorded, tmp_path / "cut.mcap", lambda t, d: None if t in WATCH_TOPICS else d)
    recording = read_session(without_scans)
    replayed = _replay(recording)
    shared = recording.events_of(SHARED_OBSERVATION)
    assert replayed.centres == {} and len(replayed.notes["rear"]) == len(shared)
    event = shared[0]
    assert replayed.notes["rear"][0].endswith(
        f"rear's centre at waypoint {event['index']}: 0 scans recorded in its dwell window, the live run "
        f"averaged {event['scans']}; left out"
    )
