"""Offline replay of a recorded run: it re-extracts every centre and never guesses."""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from lasercal_hw.errors import CalibrationError, ConfigError
from lasercal_hw.models import LaserScan
from lasercal_hw.run.records import RunOutcome
from lasercal_hw.run.replay import solve_recording
from lasercal_hw.session.format import TOPIC_EVENT, TOPIC_SCAN_INFO
from lasercal_hw.session.reader import read_session
from lasercal_hw.session.recorder import SessionRecorder
from tests.doubles import UTM_GEOMETRY, SimClock, SimRobot, SimScanner, run_calibration, semicircle_waypoints
from tests.run.test_sequencer import fast_job

RECORDER_DOC = Path(__file__).resolve().parents[2] / "docs" / "recorder.md"

# A recording made with another beam layout than the UTM-30LX-EW's default.
CLUSTER_2_FROM_90 = replace(UTM_GEOMETRY, first_step=90, cluster=2)


def _record(path: Path, **scanner_options: object) -> RunOutcome:
    job = fast_job()
    clock = SimClock()
    robot = SimRobot(clock)
    scanner = SimScanner(clock, robot, job.rod.rod_line(), **scanner_options)  # type: ignore[arg-type]
    waypoints = semicircle_waypoints(count=8)
    recorder = SessionRecorder(path, {"job": job.model_dump(mode="json"), "waypoints": waypoints.tolist()})
    try:
        return run_calibration(robot, scanner, recorder, job, waypoints, clock=clock)
    finally:
        recorder.close()


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, RunOutcome]:
    path = tmp_path_factory.mktemp("replay") / "session.mcap"
    return path, _record(path, geometry_used=CLUSTER_2_FROM_90)


def _copy(source: Path, target: Path, change: Callable[[str, bytes], bytes | None]) -> Path:
    """A copy of a recording with each message's bytes passed through ``change`` (None drops it)."""
    with open(source, "rb") as src, open(target, "wb") as dst:
        writer = Writer(dst)
        writer.start(profile="ros2")
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in make_reader(src).iter_messages(log_time_order=False):
            if schema is not None and schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas.get(channel.schema_id, 0)
                )
            data = change(channel.topic, message.data)
            if data is not None:
                writer.add_message(
                    channels[channel.id], message.log_time, data, message.publish_time, message.sequence
                )
        writer.finish()
    return target


def _without_event_field(field: str) -> Callable[[str, bytes], bytes | None]:
    def change(topic: str, data: bytes) -> bytes | None:
        if topic != TOPIC_EVENT:
            return data
        event = json.loads(data)
        if event.get("kind") == "observation":
            event.pop(field, None)
        return json.dumps(event).encode()

    return change


def test_cluster_of_2_from_step_90_replays_like_the_live_run(recorded: tuple[Path, RunOutcome]) -> None:
    path, outcome = recorded
    assert read_session(path).scans[0].geometry == CLUSTER_2_FROM_90
    replay = solve_recording(path)
    assert replay.messages == []
    np.testing.assert_allclose(replay.solution.result.matrix(), outcome.result.matrix(), rtol=0, atol=1e-12)


def test_each_waypoints_centre_covariance_is_recorded_and_a_replay_computes_it_again(
    recorded: tuple[Path, RunOutcome],
) -> None:
    """result.json records, with each residual, the centre covariance the solver weighed that
    waypoint with (mm^2, the scanner's frame) and the part of it a dwell draws anew: the
    verify's choice weighs its candidates with them. A replay computes both from its own
    re-extracted centres, and gets the live run's."""
    path, outcome = recorded
    replay = solve_recording(path).solution
    weighed = {o.index: np.asarray(o.covariance_uv_m2) * 1e6 for o in replay.observations}
    drawn = {o.index: np.asarray(o.noise_covariance_uv_m2) * 1e6 for o in replay.observations}
    assert len(replay.result.residuals) == len(outcome.result.residuals) == len(weighed)
    for live, again in zip(outcome.result.residuals, replay.result.residuals, strict=True):
        assert live.covariance_uv_mm2 is not None and again.covariance_uv_mm2 is not None
        np.testing.assert_allclose(again.covariance_uv_mm2, weighed[again.index], rtol=1e-12)
        np.testing.assert_allclose(again.covariance_uv_mm2, live.covariance_uv_mm2, rtol=1e-9)
        assert live.noise_covariance_uv_mm2 is not None and again.noise_covariance_uv_mm2 is not None
        np.testing.assert_allclose(again.noise_covariance_uv_mm2, drawn[again.index], rtol=1e-12)
        np.testing.assert_allclose(again.noise_covariance_uv_mm2, live.noise_covariance_uv_mm2, rtol=1e-9)
    document = outcome.result.to_json_dict()["residuals"][0]
    assert np.shape(document["covariance_uv_mm2"]) == np.shape(document["noise_covariance_uv_mm2"]) == (2, 2)


def test_reversed_scans_fail_loudly(recorded: tuple[Path, RunOutcome], tmp_path: Path) -> None:
    path, _ = recorded
    recording = read_session(path)
    reversed_path = tmp_path / "reversed.mcap"
    with SessionRecorder(reversed_path, recording.meta) as rewritten:
        for scan in recording.scans:
            flipped: LaserScan = replace(
                scan, ranges_m=scan.ranges_m[::-1].copy(), raw_ranges_mm=scan.raw_ranges_mm[::-1].copy()
            )
            rewritten.write_scan(flipped)
        for event in recording.events:
            fields = {k: v for k, v in event.items() if k not in ("kind", "host_time_s")}
            rewritten.write_event(event["host_time_s"], event["kind"], **fields)
    with pytest.raises(CalibrationError, match=r"waypoint 0: .*(no rod found|not show what the live)"):
        solve_recording(reversed_path)


@pytest.mark.parametrize("field", ["quality", "centre_uv_m"])
def test_observation_without_a_field_is_a_one_line_error(
    recorded: tuple[Path, RunOutcome], tmp_path: Path, field: str
) -> None:
    path = _copy(recorded[0], tmp_path / "incomplete.mcap", _without_event_field(field))
    with pytest.raises(ConfigError, match=f"waypoint 0 lacks {field} in its 'observation' event") as caught:
        solve_recording(path)
    assert "\n" not in str(caught.value)


def test_recording_without_observation_events_is_a_one_line_error(
    recorded: tuple[Path, RunOutcome], tmp_path: Path
) -> None:
    def drop_observations(topic: str, data: bytes) -> bytes | None:
        return None if topic == TOPIC_EVENT and json.loads(data).get("kind") == "observation" else data

    path = _copy(recorded[0], tmp_path / "no-observations.mcap", drop_observations)
    with pytest.raises(ConfigError, match="holds no 'observation' events") as caught:
        solve_recording(path)
    # It names a section of docs/recorder.md by its heading, so a reader finds it.
    section = re.search(r'docs/recorder\.md, "([^"]+)"', str(caught.value))
    headings = [line.lstrip("#").strip() for line in RECORDER_DOC.read_text(encoding="utf-8").splitlines()
                if line.startswith("#")]
    assert section is not None and section[1] in headings, str(caught.value)


def test_scans_without_scan_info_are_a_one_line_error(
    recorded: tuple[Path, RunOutcome], tmp_path: Path
) -> None:
    path = _copy(
        recorded[0], tmp_path / "no-scan-info.mcap", lambda t, d: None if t == TOPIC_SCAN_INFO else d
    )
    with pytest.raises(ConfigError, match=r"no usable scans .*scan_info"):
        solve_recording(path)


def test_no_waypoint_left_says_what_is_missing_and_what_to_solve_instead(
    recorded: tuple[Path, RunOutcome], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Every dwell loses every other scan: nothing can be re-extracted, and the error says so
    and points to the live run's centres; a replay re-measures nothing, so no --resume talk."""
    observations = read_session(recorded[0]).events_of("observation")
    windows = [(event["window_start_s"], event["window_end_s"]) for event in observations]

    def halve_the_dwells(topic: str, data: bytes) -> bytes | None:
        if topic != TOPIC_SCAN_INFO:
            return data
        info = json.loads(data)
        in_a_dwell = any(start <= info["device_time_s"] < end for start, end in windows)
        return None if in_a_dwell and info["sequence"] % 2 else data

    path = _copy(recorded[0], tmp_path / "session.mcap", halve_the_dwells)
    with pytest.raises(CalibrationError) as caught:
        solve_recording(path)
    message = str(caught.value)
    assert "none of its 8 waypoints could be re-extracted" in message and "\n" not in message
    assert "scans recorded in its dwell window" in message and "measure again with lasercal run" in message
    assert "--use-recorded-centres" not in message  # it cannot bring back missing scans
    assert "resume" not in message + caplog.text and "measuring again" not in caplog.text

    (tmp_path / "observations.csv").write_text("index,tcp_x,tcp_y,tcp_z,tcp_rx,tcp_ry,tcp_rz,u,v\n")
    with pytest.raises(CalibrationError, match=f"lasercal solve {tmp_path / 'observations.csv'}$"):
        solve_recording(path)
