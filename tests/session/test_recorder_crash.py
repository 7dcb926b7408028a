"""Crash safety: a SIGKILLed writer or a file cut anywhere still reads back, and resume
continues an interrupted session."""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lasercal_hw.errors import ConfigError
from lasercal_hw.session.reader import read_session
from lasercal_hw.session.recorder import SessionRecorder
from tests.recorder_helpers import START_TIME_S, assert_scans_equal, make_pose, make_scan

REPO_ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.timeout(60)
def test_sigkilled_writer_leaves_every_flushed_message_readable(tmp_path):
    path = tmp_path / "session.mcap"
    child = subprocess.Popen(
        [sys.executable, "-m", "tests.recorder_crash_child", str(path)],
        cwd=REPO_ROOT,
        stdout=subprocess.PIPE,
        stdin=subprocess.DEVNULL,
        text=True,
    )
    try:
        assert child.stdout is not None
        assert child.stdout.readline().strip() == "ready"
        last_written = -1
        while last_written < 120:
            line = child.stdout.readline()
            assert line, "writer exited early"
            last_written = int(line)
        os.kill(child.pid, signal.SIGKILL)
        assert child.wait(timeout=30) == -signal.SIGKILL
    finally:
        if child.poll() is None:
            child.kill()
            child.wait(timeout=30)
        if child.stdout is not None:
            child.stdout.close()

    recording = read_session(path)

    assert recording.truncated
    assert "footer" in recording.truncation_reason or "incomplete" in recording.truncation_reason
    assert recording.meta == {"child": True}
    assert len(recording.scans) >= last_written + 1
    for k, scan in enumerate(recording.scans):
        assert_scans_equal(scan, make_scan(k))
    dwell_indices = [e["index"] for e in recording.events_of("dwell_start")]
    assert dwell_indices[: last_written // 10 + 1] == list(range(0, last_written + 1, 10))
    assert len(recording.tcp_poses) >= last_written // 10 + 1


def test_open_recording_is_readable_while_it_is_written(tmp_path):
    path = tmp_path / "session.mcap"
    with SessionRecorder(path, {"live": 1}) as recorder:
        for i in range(5):
            recorder.write_scan(make_scan(i))
            recording = read_session(path)
            assert recording.truncated
            assert [s.sequence for s in recording.scans] == list(range(i + 1))
    assert not read_session(path).truncated


def _record_boundaries(data: bytes) -> list[int]:
    offsets, offset = [], 8
    while offset < len(data) - 8:
        offsets.append(offset)
        _, length = struct.unpack_from("<BQ", data, offset)
        offset += 9 + length
    return offsets


def test_a_file_cut_anywhere_reads_as_a_prefix(tmp_path):
    path = tmp_path / "session.mcap"
    scans = [make_scan(i) for i in range(6)]
    with SessionRecorder(path, {"m": 1}) as recorder:
        for i, scan in enumerate(scans):
            recorder.write_scan(scan)
            recorder.write_event(START_TIME_S + i, "dwell_start", index=i, tcp_pose=make_pose(i))
    data = path.read_bytes()
    rng = np.random.default_rng(7)
    boundaries = _record_boundaries(data)
    cuts = sorted({*rng.integers(0, len(data), 150).tolist(), *boundaries, *(b + 1 for b in boundaries),
                   *(b - 1 for b in boundaries), 0, 3, len(data) - 1})
    cut_path = tmp_path / "cut.mcap"
    previous_count = 0
    for cut in cuts:
        cut_path.write_bytes(data[:cut])
        recording = read_session(cut_path)
        assert recording.truncated, cut
        assert len(recording.scans) >= previous_count  # longer prefix, never fewer scans
        previous_count = len(recording.scans)
        for k, scan in enumerate(recording.scans):
            assert_scans_equal(scan, scans[k])
        assert [e["index"] for e in recording.events] == list(range(len(recording.events)))
    assert previous_count == len(scans)


def test_zero_filled_tail_is_treated_as_truncation(tmp_path):
    path = tmp_path / "session.mcap"
    with SessionRecorder(path, {}) as recorder:
        recorder.write_scan(make_scan(0))
    data = path.read_bytes()
    cut = _record_boundaries(data)[-3]
    path.write_bytes(data[:cut] + bytes(4096))
    recording = read_session(path)
    assert recording.truncated and "zero bytes" in recording.truncation_reason
    assert len(recording.scans) == 1


def _interrupted_session(path: Path, scan_count: int) -> bytes:
    """A session whose writer died: a closed file cut in the middle of its last scan."""
    with SessionRecorder(path, {"config": {"dwell_s": 3.0}}) as recorder:
        for i in range(scan_count):
            if i % 4 == 0:
                recorder.write_event(START_TIME_S + i, "dwell_start", index=i // 4, tcp_pose=make_pose(i))
            recorder.write_scan(make_scan(i))
            if i % 4 == 3:
                recorder.write_event(START_TIME_S + i + 0.5, "dwell_end", index=i // 4)
    data = path.read_bytes()
    boundaries = _record_boundaries(data)
    last_scan_chunk = boundaries[-8]  # somewhere inside the final scan's records
    data = data[: last_scan_chunk + 50]
    path.write_bytes(data)
    return data


def test_resume_copies_the_old_session_and_continues(tmp_path):
    path = tmp_path / "session.mcap"
    old_bytes = _interrupted_session(path, 10)
    old = read_session(path)
    assert old.truncated
    done = [w.index for w in old.dwell_windows() if w.complete]

    recorder = SessionRecorder.resume(path, {"resumed_by": "test"}, host_time_s=START_TIME_S + 100)
    with recorder:
        assert recorder.previous is not None
        assert [w.index for w in recorder.previous.dwell_windows() if w.complete] == done == [0, 1]
        assert read_session(path).events[-1]["kind"] == "resume"  # in place before any new data
        for i in range(len(old.scans), len(old.scans) + 4):
            recorder.write_scan(make_scan(i))
        recorder.write_event(START_TIME_S + 200, "run_end", status="ok")

    backup = tmp_path / "session.interrupted-1.mcap"
    assert backup.read_bytes() == old_bytes
    recording = read_session(path)
    assert not recording.truncated
    assert recording.meta == {"config": {"dwell_s": 3.0}, "resumed_by": "test"}
    assert [s.sequence for s in recording.scans] == list(range(len(old.scans) + 4))
    for k, scan in enumerate(recording.scans):
        assert_scans_equal(scan, make_scan(k))
    kinds = [e["kind"] for e in recording.events]
    assert kinds[: len(old.events)] == [e["kind"] for e in old.events]
    assert recording.events[: len(old.events)] == old.events
    resume_event = recording.events[len(old.events)]
    assert resume_event["kind"] == "resume"
    assert resume_event["previous_file"] == backup.name
    assert resume_event["previous_truncated"] is True
    assert kinds[-1] == "run_end"
    assert not list(tmp_path.glob("*.resume-tmp"))


def test_resuming_twice_keeps_every_interrupted_file(tmp_path):
    path = tmp_path / "session.mcap"
    _interrupted_session(path, 6)
    SessionRecorder.resume(path).close()
    SessionRecorder.resume(path).close()
    assert (tmp_path / "session.interrupted-1.mcap").exists()
    assert (tmp_path / "session.interrupted-2.mcap").exists()
    assert len(read_session(path).events_of("resume")) == 2


def test_resume_without_a_session_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        SessionRecorder.resume(tmp_path / "missing.mcap")
