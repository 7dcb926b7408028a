"""The smaller things of issue 14 item 6: a damaged MCAP chunk costs only itself, nan
and port 0 are named as what they are, corrupted-scan warnings are summarised."""

from __future__ import annotations

import dataclasses
import logging
import struct

import pytest
from mcap.opcode import Opcode

from drivers.hokuyo.client import HokuyoScanner
from drivers.hokuyo.transport import parse_url
from fakes.scip_faults import ScipFaults
from fakes.scip_server import FakeScannerServer
from lasercal_hw.config import JobConfig
from lasercal_hw.errors import ConfigError
from lasercal_hw.session.reader import read_session
from lasercal_hw.session.recorder import SessionRecorder
from tests.recorder_helpers import START_TIME_S, make_scan

pytestmark = pytest.mark.timeout(120)


def _chunks(data: bytes) -> list[tuple[int, int]]:
    """(start, end) of every chunk record of an MCAP file."""
    spans, offset = [], 8
    while offset + 9 <= len(data):
        opcode, length = struct.unpack_from("<BQ", data, offset)
        if opcode == Opcode.CHUNK:
            spans.append((offset, offset + 9 + length))
        if opcode == Opcode.FOOTER:
            break
        offset += 9 + length
    return spans


def test_a_flipped_byte_in_one_chunk_loses_that_chunk_only_and_says_how_much(
    tmp_path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "session.mcap"
    with SessionRecorder(path, {"job": 1}) as recorder:
        for waypoint in range(3):  # scans and events close chunks: many small chunks
            for k in range(5):
                recorder.write_scan(make_scan(10 * waypoint + k))
            recorder.write_event(START_TIME_S + waypoint, "dwell_end", index=waypoint)
    data = bytearray(path.read_bytes())
    chunks = _chunks(bytes(data))
    assert len(chunks) >= 4
    middle_start, middle_end = max(chunks[1:-1], key=lambda span: span[1] - span[0])
    data[(middle_start + middle_end) // 2] ^= 0x01
    path.write_bytes(bytes(data))

    with caplog.at_level(logging.WARNING):
        recording = read_session(path)
    assert len(recording.damaged) == 1 and f"chunk at byte {middle_start}" in recording.damaged[0]
    assert "s of messages" in recording.damaged[0]
    assert "damaged chunk was skipped and the rest kept" in caplog.text and "--resume" not in caplog.text
    kept = {scan.sequence for scan in recording.scans}
    assert {0, 1, 2, 3, 4} <= kept or {20, 21, 22, 23, 24} <= kept
    assert len(kept) == 14  # the damaged chunk held one scan: that one is lost, no more
    assert [e["index"] for e in recording.events_of("dwell_end")][-1] == 2  # what follows is kept
    assert not recording.truncated


def test_nan_and_infinite_settings_are_named_as_not_finite() -> None:
    with pytest.raises(ValueError, match="finite number"):
        JobConfig(dwell_s=float("nan"))
    with pytest.raises(ValueError, match="finite number"):
        JobConfig.model_validate({"settle": {"timeout_s": float("inf")}})


def test_port_0_in_a_scanner_url_is_refused_not_replaced() -> None:
    with pytest.raises(ConfigError, match="port 0 is no port a scanner listens on"):
        parse_url("scip+tcp://127.0.0.1:0")
    assert parse_url("scip+tcp://127.0.0.1").port == 10940


def test_corrupted_scans_are_counted_and_summarised_not_warned_one_by_one(
    caplog: pytest.LogCaptureFixture,
) -> None:
    with FakeScannerServer(faults=ScipFaults(corrupt_every_scans=2)) as server, \
            HokuyoScanner.open(server.url, sync_clock=False) as scanner, caplog.at_level(logging.WARNING):
        scanner.start_streaming()
        for _ in range(8):
            scanner.next_scan(2.0)
        scanner.stop_streaming()
        corrupted = scanner.stream_stats().corrupted
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert corrupted >= 4
    assert len([w for w in warnings if "corrupted scan dropped" in w]) == 1
    assert any(f"{corrupted} corrupted scans dropped in this stream" in w for w in warnings)


def test_a_failed_quality_gate_writes_no_ros_files(tmp_path) -> None:
    from lasercal_hw.calibration.quality import GateCheck, Verdict
    from lasercal_hw.run.outputs import TF_ARGS_FILE, URDF_FILE, write_outputs
    from tests.doubles import MemoryRecorder, run_calibration, semicircle_waypoints
    from tests.run.test_sequencer import fast_job, make_cell

    job = fast_job(output={"report": False})
    clock, robot, scanner = make_cell(job)
    passed = run_calibration(robot, scanner, MemoryRecorder(), job, semicircle_waypoints(8), clock=clock)
    failed = dataclasses.replace(passed, verdict=Verdict([GateCheck("residual RMS", 9.0, 1.0, "mm", False)]))
    assert passed.verdict.passed
    for outcome, written in ((passed, True), (failed, False)):
        files = write_outputs(tmp_path, outcome, job)
        for name in (URDF_FILE, TF_ARGS_FILE):
            assert (tmp_path / name).exists() is written  # the failed pass also removed the earlier pair
        assert ("urdf" in files) is written and (tmp_path / "result.json").exists()
