"""The fake UTM-30LX-EW's state machine, byte for byte, without sockets."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.hokuyo import codec
from fakes.scan_scene import STEP_COUNT, Cylinder, RoomScene
from fakes.scip_device import ScipDevice
from fakes.scip_identity import UTM_30LX_CAPTURED, LinkKind, SensorState
from tests.scip_captures import capture

B3_PP = (
    b"PP\n00P\nMODL:UTM-30LX-EW;I\nDMIN:23;7\nDMAX:60000;J\nARES:1440;^\nAMIN:0;?\n"
    b"AMAX:1080;Z\nAFRT:540;0\nSCAN:2400;U\n\n"
)


class ReplaySource:
    """Returns the same full revolution every time (a captured or hand-made scan)."""

    def __init__(self, ranges: np.ndarray, intensities: np.ndarray) -> None:
        self.ranges = np.asarray(ranges, dtype=np.int64)
        self.intensities_all = np.asarray(intensities, dtype=np.int64)
        self.times: list[float] = []

    def ranges_mm(self, time_s: float) -> tuple[np.ndarray, np.ndarray]:
        self.times.append(time_s)
        return self.ranges, self.intensities_all


def ramp_source() -> ReplaySource:
    steps = np.arange(STEP_COUNT)
    return ReplaySource(1000 + steps, 5000 + 2 * steps)


def reply(device: ScipDevice, line: bytes, now_s: float = 1.0) -> bytes:
    return device.handle(line, now_s).data


def status_of(message: bytes) -> str:
    return message.split(b"\n")[1][:2].decode()


def test_pp_is_the_utm30lx_ew_message_byte_for_byte() -> None:
    assert reply(ScipDevice(RoomScene()), b"PP") == B3_PP


def test_bm_twice_and_qt_give_the_captured_bytes() -> None:
    device = ScipDevice(RoomScene())
    assert reply(device, b"BM") == b"BM\n00P\n\n"
    assert reply(device, b"BM") == b"BM\n02R\n\n"
    assert reply(device, b"QT") == b"QT\n00P\n\n"
    assert reply(device, b"BM") == b"BM\n00P\n\n"


def test_captured_utm30lx_mode_reproduces_the_whole_a1_stream() -> None:
    """Replay the host side of scip_captures.md A.1 against the captured-UTM-30LX
    identity: all 7814 bytes (VV, PP, II with its TIME, BM 02, CR 04, ME ack and the ME
    scan, given the captured ranges) must come out identical."""
    expected = capture("utm30lx_read")
    captured_scan = codec.ResponseFramer().feed(expected)[-1]
    decoded = codec.decode_scan_lines(captured_scan.data_lines, codec.parse_scan_request(captured_scan.echo))
    source = ReplaySource(decoded.distances_mm, decoded.intensities)
    scan_timestamp_ms = 4821609
    device = ScipDevice(
        source,
        identity=UTM_30LX_CAPTURED,
        link=LinkKind.SERIAL,
        start_time_ms=scan_timestamp_ms - 6 * 25,
        origin_s=0.0,
    )
    device.handle(b"BM", -1.0)  # the laser was already on before the log started
    host_lines = capture("utm30lx_write").split(b"\n")[:-1]
    ii_times_s = iter([0x4991D0 - (scan_timestamp_ms - 150), 0x49924D - (scan_timestamp_ms - 150)])
    stream = b""
    for line in host_lines:
        now_s = next(ii_times_s) / 1000.0 if line == b"II" else 0.1
        stream += device.handle(line, now_s).data
    stream += device.complete_scan(device.scan_start_s(6)) or b""
    assert stream == expected
    assert device.state is SensorState.IDLE  # finite ME done: laser off again


def test_vv_and_ii_of_the_default_identity_parse_and_reflect_the_state() -> None:
    device = ScipDevice(RoomScene(), start_time_ms=0x123456, origin_s=10.0)
    vv = codec.ResponseFramer().feed(reply(device, b"VV;tag1"))[0]
    assert vv.echo == b"VV;tag1"
    fields = codec.parse_parameter_lines(vv.data_lines)
    assert list(fields) == ["VEND", "PROD", "FIRM", "PROT", "SERI"]
    assert fields["PROT"] == "SCIP 2.0"
    off = codec.parse_parameter_lines(codec.ResponseFramer().feed(reply(device, b"II", 10.5))[0].data_lines)
    assert off["LASR"] == "OFF" and off["MESM"] == "000 Idle" and off["SBPS"] == "Ethernet 100 [Mbps]"
    assert codec.parse_time_field(off["TIME"]) == 0x123456 + 500
    reply(device, b"BM", 10.6)
    on = codec.parse_parameter_lines(codec.ResponseFramer().feed(reply(device, b"II", 10.7))[0].data_lines)
    assert on["LASR"] == "ON" and on["MESM"] == "003 Single_scan" and on["STAT"] == "Stable 000 no error."


def test_me_stream_has_the_captured_message_layout_and_decodes() -> None:
    source = ramp_source()
    device = ScipDevice(source, start_time_ms=1000)
    assert reply(device, b"ME0000108001000", 0.010) == b"ME0000108001000\n00P\n\n"
    assert device.complete_scan(device.scan_start_s(0)) is None  # started before the request
    message = device.complete_scan(device.scan_start_s(1))
    assert message is not None and message.endswith(b"\n\n") and message.count(b"\n\n") == 1
    lines = message[:-2].split(b"\n")
    assert lines[0] == b"ME0000108001000" and lines[1] == b"99b"
    assert lines[2] == codec.timestamp_line(1025)
    data = lines[3:]
    assert len(data) == 102 and all(len(line) == 65 for line in data[:-1]) and len(data[-1]) == 23
    assert all(codec.checksum(line[:-1]) == line[-1:] for line in data)
    scan = codec.decode_scan_lines(lines[2:], codec.parse_scan_request(lines[0]))
    assert scan.timestamp_ms == 1025
    np.testing.assert_array_equal(scan.distances_mm, source.ranges)
    np.testing.assert_array_equal(scan.intensities, source.intensities_all)
    assert device.state is SensorState.STREAMING


def test_remaining_scan_counter_and_end_of_finite_stream() -> None:
    device = ScipDevice(ramp_source())
    assert status_of(reply(device, b"MD0100020001003;abc", 0.0)) == "00"
    echoes = [device.complete_scan(device.scan_start_s(k)) for k in range(5)]
    assert [e.split(b"\n")[0] if e else None for e in echoes] == [
        b"MD0100020001002;abc", b"MD0100020001001;abc", b"MD0100020001000;abc", None, None
    ]
    assert device.state is SensorState.IDLE and not device.laser_on


def test_scan_interval_skips_revolutions() -> None:
    device = ScipDevice(ramp_source())
    reply(device, b"MD0000108001200", 0.0)
    sent = [device.complete_scan(device.scan_start_s(k)) is not None for k in range(7)]
    assert sent == [True, False, False, True, False, False, True]


def test_cluster_takes_the_minimum_valid_distance_per_group() -> None:
    ranges = np.full(STEP_COUNT, 3000, dtype=np.int64)
    ranges[3:6] = [2500, 5, 2600]  # 5 is an error code: ignored by the minimum
    ranges[6:9] = [1, 1, 1]  # no valid value: the group reports its first error code
    intensities = np.arange(STEP_COUNT, dtype=np.int64)
    device = ScipDevice(ReplaySource(ranges, intensities))
    reply(device, b"BM")
    lines = reply(device, b"GE0000108003", 1.0)[:-2].split(b"\n")
    scan = codec.decode_scan_lines(lines[2:], codec.parse_scan_request(lines[0]))
    assert scan.distances_mm.size == 361  # ceil(1081 / 3)
    assert scan.distances_mm[1] == 2500 and scan.intensities[1] == 3
    assert scan.distances_mm[2] == 1 and scan.intensities[2] == 6
    assert scan.distances_mm[-1] == 3000  # last group holds one step


def test_two_char_commands_clamp_distances_to_4095() -> None:
    source = ReplaySource(np.full(STEP_COUNT, 60000), np.zeros(STEP_COUNT))
    device = ScipDevice(source)
    reply(device, b"BM")
    lines = reply(device, b"GS0000000501")[:-2].split(b"\n")
    scan = codec.decode_scan_lines(lines[2:], codec.parse_scan_request(lines[0]))
    assert scan.distances_mm.tolist() == [4095] * 6


def test_gd_returns_the_latest_complete_revolution() -> None:
    source = ramp_source()
    device = ScipDevice(source, start_time_ms=0)
    reply(device, b"BM", 0.0)
    lines = reply(device, b"GD0000108001", 0.060)[:-2].split(b"\n")
    assert lines[:2] == [b"GD0000108001", b"00P"]
    assert codec.decode_timestamp_line(lines[2]) == 25  # revolution 25..50 ms is the latest complete
    assert source.times == [pytest.approx(0.025)]


def test_timestamps_wrap_at_24_bits() -> None:
    start = (1 << 24) - 30
    device = ScipDevice(ramp_source(), start_time_ms=start)
    reply(device, b"MD0000000100000", 0.0)
    stamps = []
    for k in range(3):
        message = device.complete_scan(device.scan_start_s(k))
        assert message is not None
        stamps.append(codec.decode_timestamp_line(message.split(b"\n")[2]))
    assert stamps == [start, start + 25, 20]
    ii = codec.parse_parameter_lines(codec.ResponseFramer().feed(reply(device, b"II", 0.031))[0].data_lines)
    assert ii["TIME"] == "000001"


def test_tm_sequence_and_rs_resets_the_timer() -> None:
    device = ScipDevice(RoomScene(), start_time_ms=5000)
    assert reply(device, b"BM", 0.0) == b"BM\n00P\n\n"
    assert reply(device, b"TM0", 0.001) == b"TM0\n00P\n\n"
    assert not device.laser_on  # TM0 switched the laser off
    tm1 = reply(device, b"TM1;x", 0.002)
    assert tm1 == b"TM1;x\n00P\n" + codec.timestamp_line(5002) + b"\n\n"
    assert reply(device, b"RS", 0.100) == b"RS\n00P\n\n"
    assert device.state is SensorState.TIME_ADJUST  # only TM2 leaves time-adjust mode
    assert reply(device, b"TM1", 0.107) == b"TM1\n00P\n" + codec.timestamp_line(7) + b"\n\n"
    assert reply(device, b"TM2", 0.108) == b"TM2\n00P\n\n"
    assert reply(device, b"BM", 0.109) == b"BM\n00P\n\n"


# state -> setup commands that reach it
_SETUP = {
    "idle": [],
    "laser": [b"BM"],
    "stream": [b"MD0000108001000"],
    "tm": [b"TM0"],
}

STATE_TABLE = [
    # command, idle, laser on, streaming, time-adjust  (scip2.md section 8 + docs/scip-fake.md)
    (b"VV", "00", "00", "00", "00"),
    (b"II", "00", "00", "00", "00"),
    (b"PP", "00", "00", "00", "10"),
    (b"BM", "00", "02", "02", "10"),
    (b"QT", "00", "00", "00", "0E"),
    (b"RS", "00", "00", "00", "00"),
    (b"GD0000108001", "10", "00", "00", "10"),
    (b"GE0000108001", "10", "00", "00", "10"),
    (b"MD0000108001000", "00", "00", "00", "10"),
    (b"TM0", "00", "00", "10", "02"),
    (b"TM1", "04", "04", "04", "00"),
    (b"TM2", "03", "03", "03", "00"),
    (b"CR00", "04", "04", "04", "10"),
    (b"SS115200", "0F", "0F", "0F", "10"),
]

AFTER = {  # state reached after the command succeeds (or stays)
    (b"BM", "idle"): SensorState.MEASURING,
    (b"QT", "laser"): SensorState.IDLE,
    (b"QT", "stream"): SensorState.IDLE,
    (b"RS", "stream"): SensorState.IDLE,
    (b"RS", "tm"): SensorState.TIME_ADJUST,
    (b"MD0000108001000", "idle"): SensorState.STREAMING,
    (b"MD0000108001000", "laser"): SensorState.STREAMING,
    (b"TM0", "laser"): SensorState.TIME_ADJUST,
    (b"TM2", "tm"): SensorState.IDLE,
}


@pytest.mark.parametrize(
    ("command", "state", "expected"),
    [
        (row[0], state, row[1 + index])
        for row in STATE_TABLE
        for index, state in enumerate(_SETUP)
    ],
)
def test_state_table(command: bytes, state: str, expected: str) -> None:
    device = ScipDevice(ramp_source())
    for line in _SETUP[state]:
        assert status_of(reply(device, line, 0.5)) == "00"
    message = reply(device, command, 1.0)
    assert message.split(b"\n")[0] == command
    assert status_of(message) == expected
    if (command, state) in AFTER:
        assert device.state is AFTER[(command, state)]


@pytest.mark.parametrize(
    ("line", "status"),
    [
        (b"XX", "0E"),
        (b"vv", "0E"),
        (b"\x01\xffQ", "0E"),
        (b"V", "0E"),
        (b"DB02", "0E"),
        (b"%ST", "0E"),
        (b"VVX", "0D"),
        (b"QT1", "0D"),
        (b"TM", "0C"),
        (b"TM12", "0D"),
        (b"TM5", "01"),
        (b"TMx", "01"),
        (b"CR", "0C"),
        (b"CRab", "01"),
        (b"HS2", "01"),
        (b"HS1", "00"),
        (b"HS0", "02"),
        (b"VV;" + b"a" * 17, "0G"),
        (b"VV;a-b", "0H"),
        (b"MD000010800100", "0C"),
        (b"MD00001080010000", "0D"),
        (b"MDA000108001000", "01"),
        (b"MD0000A08001000", "02"),
        (b"MD00001080X1000", "03"),
        (b"MD000010800110X0", "0D"),
        (b"MD00001080011X0", "07"),
        (b"MD0000108001X00", "06"),
        (b"MD0000108101000", "04"),
        (b"MD0500040001000", "05"),
        (b"GD0000108101", "04"),
        (b"GD0500040001", "05"),
        (b"GD000010800", "0C"),
        (b"GD0000108001;" + b"x" * 17, "0G"),
        (b"SS", "0C"),
    ],
)
def test_malformed_and_out_of_range_requests(line: bytes, status: str) -> None:
    message = reply(ScipDevice(ramp_source()), line)
    assert message == codec.format_response(line, status.encode())


@pytest.mark.parametrize("tag", [b"a" * 16, b"a b.c_d+e@f", b""])
def test_string_field_of_allowed_characters_is_echoed(tag: bytes) -> None:
    message = reply(ScipDevice(RoomScene()), b"VV;" + tag)
    assert message.startswith(b"VV;" + tag + b"\n00P\nVEND:")


def test_ss_on_the_serial_link_validates_the_bit_rate() -> None:
    device = ScipDevice(RoomScene(), link=LinkKind.SERIAL)
    lines = (b"SS11520x", b"SS012345", b"SS115200", b"SS019200")
    assert [status_of(reply(device, line)) for line in lines] == ["01", "02", "03", "00"]


def test_rb_twice_within_a_second_reboots() -> None:
    device = ScipDevice(RoomScene(), start_time_ms=777)
    reply(device, b"BM", 0.0)
    first = device.handle(b"RB", 1.0)
    assert first.data == b"RB\n01Q\n\n" and not first.hang_up
    second = device.handle(b"RB", 1.5)
    assert second.data == b"RB\n00P\n\n" and second.hang_up
    assert device.state is SensorState.IDLE and device.time_ms(1.6) == 100
    assert device.handle(b"RB", 5.0).data == b"RB\n01Q\n\n"


def test_disconnect_stops_the_stream_and_switches_the_laser_off() -> None:
    device = ScipDevice(ramp_source())
    reply(device, b"MD0000108001000", 0.0)
    device.disconnect()
    assert device.state is SensorState.IDLE
    assert device.complete_scan(device.scan_start_s(3)) is None


def test_range_source_with_wrong_shape_is_rejected_clearly() -> None:
    device = ScipDevice(ReplaySource(np.zeros(10), np.zeros(10)))
    reply(device, b"BM")
    with pytest.raises(ValueError, match="expected \\(1081,\\)"):
        reply(device, b"GD0000108001")


def test_default_scene_sees_walls_and_the_rod() -> None:
    scene = RoomScene(cylinders=(Cylinder((2.0, 0.0), 0.020),))
    ranges, intensities = scene.ranges_mm(0.0)
    assert ranges.shape == (STEP_COUNT,) and intensities.shape == (STEP_COUNT,)
    assert ranges[540] == 1980  # straight ahead: rod surface at 2.0 - 0.02 m
    assert ranges[0] == round(2000 * np.sqrt(2))  # -135 deg: hits the x = -2 m wall first
    assert (ranges >= 23).all() and (intensities > 0).all()
    rod_beams = np.flatnonzero(ranges < 2100)
    assert 3 <= rod_beams.size <= 8 and rod_beams.min() < 540 < rod_beams.max()
    noisy = RoomScene(noise_mm=10.0, seed=3)
    first, _ = noisy.ranges_mm(1.0)
    again, _ = noisy.ranges_mm(1.0)
    later, _ = noisy.ranges_mm(1.025)
    np.testing.assert_array_equal(first, again)
    assert not np.array_equal(first, later)


def test_one_source_call_serves_the_requested_steps_of_a_scan() -> None:
    class Revolution:
        calls = 0

        def ranges_mm(self, time_s: float) -> tuple[np.ndarray, np.ndarray]:
            Revolution.calls += 1
            steps = np.arange(STEP_COUNT)
            return 2000 + steps, 7 * steps

    device = ScipDevice(Revolution())
    reply(device, b"BM")
    lines = reply(device, b"GE0100010901")[:-2].split(b"\n")
    scan = codec.decode_scan_lines(lines[2:], codec.parse_scan_request(lines[0]))
    assert scan.distances_mm.tolist() == list(range(2100, 2110))
    assert scan.intensities is not None and scan.intensities.tolist() == [7 * s for s in range(100, 110)]
    assert Revolution.calls == 1  # distances and intensities of one scan come from one call
