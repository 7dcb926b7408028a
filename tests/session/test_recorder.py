"""SessionRecorder -> read_session round trips, and readability by the standard MCAP tools."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import quat_to_rotvec, rotvec_to_matrix
from lasercal_hw.models import LaserScan
from lasercal_hw.session.format import (
    TOPIC_JOINT_STATES,
    TOPIC_SCAN,
    TOPIC_TCP_POSE,
    UR_JOINT_NAMES,
    raw_mm_to_ros_ranges,
    ros_ranges_to_raw_mm,
)
from lasercal_hw.session.reader import read_session
from lasercal_hw.session.recorder import SessionRecorder
from tests.recorder_helpers import START_TIME_S, UTM_GEOMETRY, assert_scans_equal, make_pose, make_scan

META = {"config": {"rod": {"radius_m": 0.02}, "dwell_s": 3.0}, "scanner": {"serial": "H1234"}}


def _record(path, scans, poses=(), joints=(), events=()):
    with SessionRecorder(path, META) as recorder:
        for scan in scans:
            recorder.write_scan(scan)
        for t, pose in poses:
            recorder.write_tcp_pose(t, pose)
        for t, q in joints:
            recorder.write_joint_state(t, q)
        for t, kind, fields in events:
            recorder.write_event(t, kind, **fields)


def test_round_trip_reproduces_everything_exactly(tmp_path):
    scans = [make_scan(i) for i in range(30)] + [make_scan(30, intensities=False)]
    poses = [(START_TIME_S + k / 7, make_pose(k)) for k in range(20)]
    joints = [(START_TIME_S + k / 3, np.linspace(-3.0, 3.0, 6) + k * 1e-9) for k in range(5)]
    events = [
        (START_TIME_S + 0.1, "dwell_start", {"index": 0, "tcp_pose": make_pose(0)}),
        (START_TIME_S + 3.1, "dwell_end", {"index": 0, "tcp_pose": make_pose(0), "scans": 120}),
        (START_TIME_S + 3.2, "observation", {"index": 0, "centre_uv_m": np.array([0.5, -0.25]),
                                             "nan": np.nan}),
        (START_TIME_S + 9.0, "run_end", {"status": "ok"}),
    ]
    path = tmp_path / "session.mcap"
    _record(path, scans, poses, joints, events)

    recording = read_session(path)

    assert not recording.truncated
    assert recording.meta == META
    assert len(recording.scans) == len(scans)
    for actual, expected in zip(recording.scans, scans, strict=True):
        assert_scans_equal(actual, expected)
    assert [p.host_time_s for p in recording.tcp_poses] == [t for t, _ in poses]
    for actual, (_, expected) in zip(recording.tcp_poses, poses, strict=True):
        assert actual.pose.tobytes() == expected.tobytes()
    assert [j.host_time_s for j in recording.joint_states] == [t for t, _ in joints]
    for actual, (_, expected) in zip(recording.joint_states, joints, strict=True):
        assert actual.q_rad.tobytes() == expected.tobytes()
    assert [e["kind"] for e in recording.events] == ["dwell_start", "dwell_end", "observation", "run_end"]
    assert recording.events[0]["host_time_s"] == START_TIME_S + 0.1
    assert recording.events[0]["tcp_pose"] == make_pose(0).tolist()
    assert recording.events[2]["centre_uv_m"] == [0.5, -0.25]
    assert recording.events[2]["nan"] is None  # strict JSON: non-finite floats become null


def test_scans_that_break_the_compact_encoding_still_round_trip(tmp_path):
    """Values a float32 cannot carry and ranges not made by the standard rule go into the
    JSON companion, so nothing is lost."""
    base = make_scan(5)
    clustered = dataclasses.replace(UTM_GEOMETRY, first_step=44, last_step=725, cluster=3)
    odd = [
        dataclasses.replace(base, ranges_m=base.raw_ranges_mm * 1e-3),  # another mm -> m rule
        dataclasses.replace(base, raw_ranges_mm=base.raw_ranges_mm + 2**25),  # beyond float32
        dataclasses.replace(base, intensities=np.full(1081, 2**40, dtype=np.int64)),
        make_scan(6, geometry=clustered),
        dataclasses.replace(base, sequence=2**40, intensities=np.zeros(1081, dtype=np.int64)),
    ]
    path = tmp_path / "session.mcap"
    _record(path, odd)
    recording = read_session(path)
    assert len(recording.scans) == len(odd)
    for actual, expected in zip(recording.scans, odd, strict=True):
        assert_scans_equal(actual, expected)


def test_ros_range_encoding_carries_every_raw_value_a_scip_scan_can_hold():
    raw = np.arange(0, 2**18, dtype=np.int64)  # three-character SCIP values
    np.testing.assert_array_equal(ros_ranges_to_raw_mm(raw_mm_to_ros_ranges(raw)), raw)


def test_standard_mcap_readers_see_ros2_messages(tmp_path):
    """What Foxglove and ros2 bag need: a summary, ros2msg schemas, CDR messages that the
    reference decoder reads, ROS conventions on the values."""
    scan = make_scan(3)
    pose = make_pose(3)
    path = tmp_path / "session.mcap"
    _record(path, [scan], [(START_TIME_S, pose)], [(START_TIME_S, np.arange(6.0))])

    with open(path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert reader.get_header().profile == "ros2"
        schemas = {schema.name: schema.encoding for schema in summary.schemas.values()}
        assert schemas["sensor_msgs/msg/LaserScan"] == "ros2msg"
        assert schemas["geometry_msgs/msg/PoseStamped"] == "ros2msg"
        decoded = {channel.topic: message for _, channel, _, message in reader.iter_decoded_messages(
            topics=[TOPIC_SCAN, TOPIC_TCP_POSE, TOPIC_JOINT_STATES]
        )}

    ros_scan = decoded[TOPIC_SCAN]
    assert ros_scan.header.frame_id == "laser"
    assert ros_scan.header.stamp.sec == int(scan.host_time_s)
    assert ros_scan.angle_min == pytest.approx(-3 * np.pi / 4, rel=1e-6)
    assert ros_scan.angle_max == pytest.approx(3 * np.pi / 4, rel=1e-6)
    assert ros_scan.angle_increment == pytest.approx(2 * np.pi / 1440, rel=1e-6)
    assert ros_scan.scan_time == pytest.approx(0.025)
    ranges = np.asarray(ros_scan.ranges, dtype=np.float32)
    ros_valid = (ranges >= np.float32(ros_scan.range_min)) & (ranges <= np.float32(ros_scan.range_max))
    np.testing.assert_array_equal(ros_valid, scan.valid)  # invalid beams fall outside the limits
    np.testing.assert_allclose(ranges[ros_valid], scan.ranges_m[scan.valid], rtol=1e-7)

    ros_pose = decoded[TOPIC_TCP_POSE]
    assert ros_pose.header.frame_id == "base"
    quat = [ros_pose.pose.orientation.x, ros_pose.pose.orientation.y,
            ros_pose.pose.orientation.z, ros_pose.pose.orientation.w]
    assert [ros_pose.pose.position.x, ros_pose.pose.position.y, ros_pose.pose.position.z] == pose[:3].tolist()
    np.testing.assert_allclose(quat_to_rotvec(quat), pose[3:], atol=1e-12)
    assert list(decoded[TOPIC_JOINT_STATES].name) == list(UR_JOINT_NAMES)
    assert list(decoded[TOPIC_JOINT_STATES].position) == [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]


def test_pose_quaternion_round_trip_is_near_exact():
    """The PoseStamped view alone already keeps the rotation to 1e-12 (the JSON companion
    keeps the vector itself, including rotation angles the quaternion folds)."""
    from lasercal_hw.geometry import rotvec_to_quat

    for k in range(500):
        rotvec = make_pose(k)[3:]
        back = quat_to_rotvec(rotvec_to_quat(rotvec))
        np.testing.assert_allclose(rotvec_to_matrix(back), rotvec_to_matrix(rotvec), atol=1e-12)
        np.testing.assert_allclose(back, rotvec, atol=1e-12)


def test_meta_documents_merge_in_order(tmp_path):
    path = tmp_path / "session.mcap"
    with SessionRecorder(path, {"config": {"a": 1}, "software_version": "0.1"}) as recorder:
        recorder.write_meta({"robot": {"serial": "2019301234"}, "config": {"a": 2}})
    recording = read_session(path)
    assert recording.metas[0] == {"config": {"a": 1}, "software_version": "0.1"}
    merged = {"config": {"a": 2}, "software_version": "0.1", "robot": {"serial": "2019301234"}}
    assert recording.meta == merged


def test_dwell_windows_pair_starts_with_ends_and_prefer_completed_redos(tmp_path):
    path = tmp_path / "session.mcap"
    t = START_TIME_S
    with SessionRecorder(path, {}) as recorder:
        recorder.write_event(t + 0, "dwell_start", index=0, tcp_pose=make_pose(0))
        recorder.write_event(t + 3, "dwell_end", index=0, tcp_pose=make_pose(100))
        recorder.write_event(t + 5, "dwell_start", index=1, tcp_pose=make_pose(1))
        recorder.write_event(t + 6, "abort", reason="operator")
        recorder.write_event(t + 9, "dwell_start", index=1, tcp_pose=make_pose(11))
        recorder.write_event(t + 12, "dwell_end", index=1)
        recorder.write_event(t + 13, "dwell_start", index=2, tcp_pose=make_pose(2))
        for i in range(-10, 200):
            recorder.write_scan(dataclasses.replace(make_scan(i % 7), sequence=i, host_time_s=t + i * 0.025))
    recording = read_session(path)

    windows = recording.dwell_windows()

    assert [w.index for w in windows] == [0, 1, 2]
    assert (windows[0].start_s, windows[0].end_s) == (t + 0, t + 3)
    np.testing.assert_array_equal(windows[0].tcp_pose, make_pose(0))
    np.testing.assert_array_equal(windows[0].tcp_pose_end, make_pose(100))
    assert (windows[1].start_s, windows[1].end_s) == (t + 9, t + 12)
    np.testing.assert_array_equal(windows[1].tcp_pose, make_pose(11))
    assert windows[1].complete and not windows[2].complete
    assert windows[2].end_s is None
    in_first = recording.scans_between(windows[0].start_s, windows[0].end_s)
    assert [s.sequence for s in in_first] == list(range(0, 121))
    assert len(recording.events_of("abort")) == 1


def test_write_event_requires_the_waypoint_index_for_dwells(tmp_path):
    with SessionRecorder(tmp_path / "s.mcap", {}) as recorder, pytest.raises(ValueError, match="index"):
        recorder.write_event(START_TIME_S, "dwell_start", tcp_pose=make_pose(0))


def test_existing_session_is_never_overwritten(tmp_path):
    path = tmp_path / "session.mcap"
    _record(path, [make_scan(1)])
    before = path.read_bytes()
    with pytest.raises(ConfigError, match="resume that run from its recording"):
        SessionRecorder(path, META)
    assert path.read_bytes() == before


def test_unrecordable_value_is_a_clear_error(tmp_path):
    with SessionRecorder(tmp_path / "s.mcap", {}) as recorder, pytest.raises(TypeError, match="object"):
        recorder.write_event(START_TIME_S, "fault", detail=object())


def test_write_after_close_fails(tmp_path):
    recorder = SessionRecorder(tmp_path / "s.mcap", {})
    recorder.close()
    recorder.close()
    with pytest.raises(RuntimeError, match="closed"):
        recorder.write_scan(make_scan(0))


def test_reading_a_missing_or_foreign_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        read_session(tmp_path / "nope.mcap")
    foreign = tmp_path / "observations.csv"
    foreign.write_text("index,tcp_x\n")
    with pytest.raises(ConfigError, match="not an MCAP file"):
        read_session(foreign)


def test_json_topics_are_strict_json(tmp_path):
    """Foxglove parses JSON messages with a strict parser: no NaN literals anywhere."""
    path = tmp_path / "session.mcap"
    _record(path, [make_scan(2)], events=[(START_TIME_S, "fault", {"value": float("inf")})])
    with open(path, "rb") as stream:
        for _, channel, message in make_reader(stream).iter_messages():
            if channel.message_encoding == "json":
                json.loads(message.data, parse_constant=lambda name: pytest.fail(f"{name} in JSON"))


def test_scan_type_is_the_product_scan(tmp_path):
    path = tmp_path / "session.mcap"
    _record(path, [make_scan(1)])
    assert isinstance(read_session(path).scans[0], LaserScan)
    assert read_session(path, include_scans=False).scans == []


def test_fast_scan_decoder_matches_the_reference_decoder(tmp_path):
    from lasercal_hw.session.reader import _laser_scan_arrays

    path = tmp_path / "session.mcap"
    _record(path, [make_scan(1), make_scan(2, intensities=False)])
    with open(path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        decoded = list(reader.iter_decoded_messages(topics=[TOPIC_SCAN]))
    assert len(decoded) == 2
    for _, _, message, reference in decoded:
        fast = _laser_scan_arrays(message.data)
        assert fast.ranges.tolist() == list(reference.ranges)
        assert fast.intensities.tolist() == list(reference.intensities)
        angles = (fast.angle_min_rad, fast.angle_increment_rad)
        assert angles == (reference.angle_min, reference.angle_increment)
        assert _laser_scan_arrays(message.data[:-1]) is None  # not the expected layout
        assert _laser_scan_arrays(b"\x00\x03" + message.data[2:]) is None  # not plain CDR


def test_a_watching_scanners_scans_go_on_its_own_topic_and_frame(tmp_path):
    """A cell's other scanner (docs/cell.md) records on ``/scan/NAME`` in ``laser_NAME``: read
    back exactly and apart from the run's own scans, which stay on ``/scan``; a resume keeps both."""
    own = [make_scan(i) for i in range(4)]
    watched = [dataclasses.replace(make_scan(10 + i), host_time_s=START_TIME_S + 10 + i) for i in range(3)]
    path = tmp_path / "session.mcap"
    with SessionRecorder(path, META) as recorder:
        for scan, other in zip(own, [*watched, None], strict=True):  # interleaved
            recorder.write_scan(scan)
            if other is not None:
                recorder.write_scan(other, "rear")
    SessionRecorder.resume(path).close()

    recording = read_session(path)
    assert len(recording.scans) == len(own) and list(recording.scans_by_scanner) == ["rear"]
    for actual, expected in zip(recording.scans, own, strict=True):
        assert_scans_equal(actual, expected)
    for actual, expected in zip(recording.scans_by_scanner["rear"], watched, strict=True):
        assert_scans_equal(actual, expected)
    with open(path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        frames = {channel.topic: message.header.frame_id for _, channel, _, message in
                  reader.iter_decoded_messages(topics=[TOPIC_SCAN, f"{TOPIC_SCAN}/rear"])}
    assert frames == {TOPIC_SCAN: "laser", "/scan/rear": "laser_rear"}


def test_dwell_scans_are_the_ones_the_live_run_listed(tmp_path):
    """With scan_sequences in dwell_end a replay averages exactly the live run's scans, even
    when the scanner restarted its sequence numbers; without them, the time window rules."""
    path = tmp_path / "session.mcap"
    t = START_TIME_S
    with SessionRecorder(path, {}) as recorder:
        for i in range(10):  # first connection: sequences 0..9
            recorder.write_scan(dataclasses.replace(make_scan(i), host_time_s=t + i))
        recorder.write_event(t + 2.5, "dwell_start", index=0)
        recorder.write_event(t + 6.5, "dwell_end", index=0)
        for i in range(10):  # reconnected: sequences 0..9 again, 100 s later
            recorder.write_scan(dataclasses.replace(make_scan(i), host_time_s=t + 100 + i))
        recorder.write_event(t + 101.5, "dwell_start", index=1)
        recorder.write_event(t + 108.5, "dwell_end", index=1, scan_sequences=[2, 3, 5])
    recording = read_session(path)
    first, second = recording.dwell_windows()
    assert first.scan_sequences is None
    assert [s.host_time_s - t for s in recording.dwell_scans(first)] == [3, 4, 5, 6]
    assert second.scan_sequences == (2, 3, 5)
    assert [s.host_time_s - t for s in recording.dwell_scans(second)] == [102, 103, 105]


def test_meta_accepts_the_products_value_types(tmp_path):
    import enum
    from pathlib import Path

    from pydantic import BaseModel

    from lasercal_hw.models import ScannerIdentity

    class Mode(enum.Enum):
        DRY_RUN = "dry-run"

    class Limits(BaseModel):
        speed_m_s: float = 0.1

    identity = ScannerIdentity("Hokuyo", "UTM-30LX-EW", "1.2.3", "SCIP 2.0", "H1", "UTM-30LX-EW")
    meta = {"scanner": identity, "mode": Mode.DRY_RUN, "limits": Limits(), "out": Path("/tmp/x"),
            "q": np.arange(3, dtype=np.int32), "flag": np.bool_(True), "gain": np.float32(0.5)}
    path = tmp_path / "session.mcap"
    SessionRecorder(path, meta).close()
    assert read_session(path).meta == {
        "scanner": {"vendor": "Hokuyo", "product": "UTM-30LX-EW", "firmware": "1.2.3", "protocol": "SCIP 2.0",
                    "serial": "H1", "model": "UTM-30LX-EW"},
        "mode": "dry-run", "limits": {"speed_m_s": 0.1}, "out": "/tmp/x", "q": [0, 1, 2], "flag": True,
        "gain": 0.5,
    }
