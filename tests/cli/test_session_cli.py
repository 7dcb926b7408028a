"""``lasercal session info`` and ``lasercal session repair`` on a crashed recording."""

from __future__ import annotations

import json

from mcap.reader import make_reader

from lasercal_hw.session.reader import read_session
from lasercal_hw.session.recorder import SessionRecorder
from tests.cli_helpers import assert_one_line_error, run_cli
from tests.recorder_helpers import START_TIME_S, assert_scans_equal, make_pose, make_scan


def _crashed_session(path) -> None:
    with SessionRecorder(path, {"config": {"dwell_s": 0.1}}) as recorder:
        for index in range(2):
            start_s = START_TIME_S + index * 0.1
            recorder.write_event(start_s, "dwell_start", index=index, tcp_pose=make_pose(index))
            for k in range(4):
                recorder.write_scan(make_scan(index * 4 + k))
            recorder.write_event(START_TIME_S + index * 0.1 + 0.09, "dwell_end", index=index)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) - 2000])  # lose the summary and footer


def test_info_reports_truncation_and_dwell_windows(tmp_path):
    path = tmp_path / "session.mcap"
    _crashed_session(path)
    result = run_cli("session", "info", "--json", str(path))
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["truncated"] is True
    assert summary["scans"] == 8
    assert summary["events"] == {"dwell_start": 2, "dwell_end": 2}
    windows = [(w["index"], w["complete"], w["scans"]) for w in summary["dwell_windows"]]
    assert windows == [(0, True, 4), (1, True, 4)]
    human = run_cli("session", "info", str(path))
    assert "truncated" in human.stdout and "waypoint 1" in human.stdout


def test_repair_writes_a_closed_indexed_copy(tmp_path):
    source = tmp_path / "session.mcap"
    _crashed_session(source)
    target = tmp_path / "repaired.mcap"
    result = run_cli("session", "repair", str(source), str(target))
    assert result.returncode == 0, result.stderr
    repaired = read_session(target)
    assert not repaired.truncated
    for k, scan in enumerate(repaired.scans):
        assert_scans_equal(scan, make_scan(k))
    assert repaired.events == read_session(source).events
    with open(target, "rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and summary.chunk_indexes

    again = run_cli("session", "repair", str(source), str(target))
    assert again.returncode == 2
    assert "already exists" in again.stderr


def test_info_on_a_missing_file_is_a_one_line_error(tmp_path):
    result = run_cli("session", "info", str(tmp_path / "none.mcap"))
    assert result.returncode == 2
    assert "not found" in result.stderr and "Traceback" not in result.stderr


def test_info_on_a_directory_or_a_non_mcap_file_is_a_one_line_error(tmp_path):
    not_mcap = tmp_path / "notes.mcap"
    not_mcap.write_text("not a recording\n")
    for path, message in ((tmp_path, "is a directory"), (not_mcap, "is not an MCAP file")):
        assert_one_line_error(run_cli("session", "info", str(path)), 2, message)


def test_repair_of_a_bad_source_creates_no_target(tmp_path):
    target = tmp_path / "repaired.mcap"
    result = run_cli("session", "repair", str(tmp_path / "none.mcap"), str(target))
    assert_one_line_error(result, 2, "not found")
    assert not target.exists()  # a retry with the right source must not find a stale target


def test_repair_onto_an_existing_target_says_to_choose_another_name(tmp_path):
    source = tmp_path / "session.mcap"
    _crashed_session(source)
    target = tmp_path / "repaired.mcap"
    target.write_bytes(b"keep me")
    result = run_cli("session", "repair", str(source), str(target))
    assert_one_line_error(result, 2, "choose a new file name")
    assert "--resume" not in result.stderr
    assert target.read_bytes() == b"keep me"
