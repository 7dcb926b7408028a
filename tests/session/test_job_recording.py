"""A cell job's one recording (docs/recorder.md): each scanner's run written through
``SessionRecorder.for_scanner`` and read back through ``SessionRecording.for_scanner`` as its
own one-scanner recording would hold it; a one-scanner recording is its own view, and a scanner
a file does not hold is a one-line error naming those it holds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import euler_zyx_to_matrix, make_transform, quat_to_matrix
from lasercal_hw.session.format import META_JOB_SCANNERS, TOPIC_TF_STATIC
from lasercal_hw.session.reader import read_session
from lasercal_hw.session.recorder import SessionRecorder
from tests.recorder_helpers import START_TIME_S, assert_scans_equal, make_pose, make_scan


def _write_job_recording(path: Path, *, killed_in_rear: bool = False) -> None:
    """front's run (rear watching waypoint 0), then rear's (front watching), both from index 0."""
    recorder = SessionRecorder(path, {META_JOB_SCANNERS: ["front", "rear"], "software_version": "test"})
    for k, (name, other) in enumerate((("front", "rear"), ("rear", "front"))):
        run = recorder.for_scanner(name)
        run.write_meta({"job": {"of": name}, "waypoints": [[k] * 6]})
        t = START_TIME_S + 10.0 * k
        run.write_tcp_pose(t, make_pose(k))
        run.write_event(t, "dwell_start", index=0, tcp_pose=make_pose(k))
        run.write_scan(make_scan(10 * k))
        run.write_scan(make_scan(10 * k + 1), other)  # the other scanner watching this waypoint
        if killed_in_rear and name == "rear":
            return  # never closed: the writer was killed during the second scanner's run
        run.write_event(t + 1.0, "dwell_end", index=0, tcp_pose=make_pose(k), scan_sequences=[10 * k])
        run.write_event(t + 1.0, "shared_observation", scanner=other, index=0)
    recorder.close()


def test_each_scanners_run_reads_as_its_own_one_scanner_recording(tmp_path: Path) -> None:
    path = tmp_path / "session.mcap"
    _write_job_recording(path)
    recording = read_session(path)
    assert recording.is_job_recording and recording.scanner_names == ["front", "rear"]
    assert recording.scans == []  # every scan is named by its scanner
    for k, (name, other) in enumerate((("front", "rear"), ("rear", "front"))):
        view = recording.for_scanner(name)
        assert view.scanner_names == [name] and not view.is_job_recording
        assert view.meta["job"] == {"of": name} and view.meta["scanner_name"] == name
        assert view.meta[META_JOB_SCANNERS] == ["front", "rear"]  # the job's untagged document
        assert [w.index for w in view.dwell_windows()] == [0]  # indices per scanner, not mixed
        (window,) = view.dwell_windows()
        np.testing.assert_array_equal(window.tcp_pose, make_pose(k))
        (own,) = view.dwell_scans(window)
        assert_scans_equal(own, make_scan(10 * k))
        # its own scan and its watching scan on its topic; the other's on theirs
        assert [s.sequence for s in view.scans] == sorted([10 * k, 10 * (1 - k) + 1])
        assert list(view.scans_by_scanner) == [other]
        assert [e["scanner"] for e in view.events_of("shared_observation")] == [other]
        assert len(view.tcp_poses) == 2  # the robot is one: every pose in every view
        assert view.for_scanner(name) is view and view.for_scanner(None) is view


def test_a_scanner_the_file_does_not_hold_is_a_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "session.mcap"
    _write_job_recording(path)
    recording = read_session(path)
    with pytest.raises(ConfigError, match=r"no run of scanner 'side'; the scanners it holds: front, rear"):
        recording.for_scanner("side")
    with pytest.raises(ConfigError, match=r"several scanners \(front, rear\); name the one to read with"):
        recording.for_scanner(None)
    with pytest.raises(ConfigError, match=r"the recording of scanner 'front' alone, not of 'rear'"):
        recording.for_scanner("front").for_scanner("rear")


def test_a_one_scanner_recording_is_its_own_view(tmp_path: Path) -> None:
    old = tmp_path / "old.mcap"
    with SessionRecorder(old, {"job": {}, "waypoints": []}) as recorder:
        recorder.write_scan(make_scan(1))
        recorder.write_event(START_TIME_S, "dwell_start", index=0)
    recording = read_session(old)
    assert not recording.is_job_recording and recording.scanner_names == ["default"]
    assert recording.for_scanner(None) is recording and recording.for_scanner("default") is recording
    with pytest.raises(ConfigError, match=r"scanner 'default' alone, not of 'rear'; leave out the scanner"):
        recording.for_scanner("rear")
    # a cell scanner's own file, as cell jobs wrote them before the one recording
    cell_scanner = tmp_path / "rear.mcap"
    with SessionRecorder(cell_scanner, {"job": {}, "waypoints": [], "scanner_name": "rear"}) as recorder:
        recorder.write_scan(make_scan(2))
        recorder.write_scan(make_scan(3), "front")
    recording = read_session(cell_scanner)
    assert recording.scanner_names == ["rear"] and recording.for_scanner("rear") is recording
    with pytest.raises(ConfigError, match="scanner 'rear' alone, not of 'front'"):
        recording.for_scanner("front")


def test_a_job_recording_killed_in_the_second_scanner_keeps_both_runs(tmp_path: Path) -> None:
    """The writer killed (never closed) during rear's run: the file reads up to the last call,
    front's run whole, rear's dwell open; resuming it copies both and continues."""
    path = tmp_path / "session.mcap"
    _write_job_recording(path, killed_in_rear=True)
    recording = read_session(path)
    assert recording.truncated and recording.scanner_names == ["front", "rear"]
    assert recording.for_scanner("front").dwell_windows()[0].complete
    (open_dwell,) = recording.for_scanner("rear").dwell_windows()
    assert not open_dwell.complete
    resumed = SessionRecorder.resume(path, {META_JOB_SCANNERS: ["front", "rear"]})
    assert resumed.previous is not None and resumed.previous.scanner_names == ["front", "rear"]
    resumed.for_scanner("rear").write_event(START_TIME_S + 20.0, "dwell_end", index=0)
    resumed.close()
    again = read_session(path)
    assert (tmp_path / "session.interrupted-1.mcap").is_file()
    assert again.for_scanner("rear").dwell_windows()[0].complete
    front_ends = recording.for_scanner("front").events_of("dwell_end")
    assert again.for_scanner("front").events_of("dwell_end") == front_ends


def scanner_frames(path: Path) -> dict[str, np.ndarray]:
    """The last ``/tf_static`` transform of each child frame in a recording, as a standard ROS 2
    reader decodes it (what Foxglove places each scanner's scans with): 4x4 in the base frame."""
    frames = {}
    with open(path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, _, _, message in reader.iter_decoded_messages(topics=[TOPIC_TF_STATIC]):
            for transform in message.transforms:
                assert transform.header.frame_id == "base"
                t, q = transform.transform.translation, transform.transform.rotation
                frames[transform.child_frame_id] = make_transform(
                    quat_to_matrix([q.x, q.y, q.z, q.w]), [t.x, t.y, t.z]
                )
    return frames


def test_scanner_frames_are_on_tf_static_for_viewers_and_survive_a_resume(tmp_path: Path) -> None:
    path = tmp_path / "session.mcap"
    T = make_transform(euler_zyx_to_matrix(0.3, -0.2, 0.1), [0.3, -0.4, 0.25])
    recorder = SessionRecorder(path, {META_JOB_SCANNERS: ["front"]})
    recorder.write_frame(START_TIME_S, "laser_front", np.eye(4))
    recorder.write_frame(START_TIME_S + 1.0, "laser_front", T)  # its calibrated frame replaces the nominal
    recorder.flush()  # not closed: a killed writer
    SessionRecorder.resume(path).close()
    (frame,) = scanner_frames(path).items()
    assert frame[0] == "laser_front"
    np.testing.assert_allclose(frame[1], T, atol=1e-12)
    assert read_session(path).scanner_names == []  # a frame is no scanner's run
