"""SCIP 2.0 codec against real device captures and round-trip properties."""

from __future__ import annotations

import hashlib
import random

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.hokuyo import codec
from drivers.hokuyo.codec import (
    CommandFramer,
    DataLineChecksumError,
    Response,
    ResponseFramer,
    ScanRequest,
    checksum,
    decode_data_lines,
    decode_int,
    decode_scan_lines,
    decode_values,
    encode_data_lines,
    encode_int,
    encode_scan_lines,
    encode_values,
    format_request,
    format_response,
    format_scan_request,
    parameter_line,
    parse_parameter_lines,
    parse_scan_request,
    parse_time_field,
    status_meaning,
)
from lasercal_hw.errors import ChecksumError, ProtocolError
from tests.scip_captures import URG04LX_ECHOES, UTM30LX_ECHOES, UXM30LXE_ECHOES, capture


def sha_joined(values: np.ndarray) -> str:
    return hashlib.sha256(",".join(str(int(v)) for v in values).encode()).hexdigest()


def feed_in_chunks(framer: ResponseFramer, data: bytes, rng: random.Random, max_chunk: int = 4096):
    responses: list[Response] = []
    position = 0
    while position < len(data):
        size = rng.randint(1, max_chunk)
        responses += framer.feed(data[position : position + size])
        position += size
    return responses


# --------------------------------------------------------------------------- spec vectors


@pytest.mark.parametrize(
    ("chars", "value"),
    [(b"CB", 1234), (b"1Dh", 5432), (b"m2@0", 16_000_000), (b"BI9Y", 4_821_609), (b"JUGn", 6_968_830)],
)
def test_spec_encoding_examples(chars: bytes, value: int) -> None:
    assert decode_int(chars) == value
    assert encode_int(value, len(chars)) == chars


@pytest.mark.parametrize(
    ("text", "expected"),
    [(b"00", b"P"), (b"99", b"b"), (b"BI9Y", b"M"), (b"PROT:SCIP 2.0", b"N"), (b"0E", b"e")],
)
def test_checksum_examples(text: bytes, expected: bytes) -> None:
    assert checksum(text) == expected


def test_status_line_table_from_reference() -> None:
    table = (
        "00P 01Q 02R 03S 04T 05U 06V 07W 0Aa 0Bb 0Cc 0Dd 0Ee 0Ff 0Gg 0Hh 0Ii "
        "0Ll 0Mm 10Q 21S 49] 50U 97` 98a 99b"
    )
    for entry in table.split():
        assert checksum(entry[:2].encode()) == entry[2:].encode()


def test_decode_rejects_characters_outside_the_alphabet() -> None:
    with pytest.raises(ProtocolError):
        decode_int(b"0p")
    with pytest.raises(ProtocolError, match="position 4"):
        decode_values(b"0000/0", 3)
    with pytest.raises(ProtocolError):
        decode_values(b"0000", 3)


def test_encode_rejects_values_that_do_not_fit() -> None:
    with pytest.raises(ValueError):
        encode_int(4096, 2)
    with pytest.raises(ValueError):
        encode_values(np.array([1, -1]), 3)


def test_parameter_lines_follow_the_semicolon_excluded_rule() -> None:
    assert parameter_line("PROT", "SCIP 2.0") == b"PROT:SCIP 2.0;N"
    assert parameter_line("MODL", "UTM-30LX-EW") == b"MODL:UTM-30LX-EW;I"


def test_parameter_values_may_contain_colons_and_semicolons(caplog: pytest.LogCaptureFixture) -> None:
    parsed = parse_parameter_lines([b"TIME:j;o[;H", b"MESM:STANDARD(max:100000[mm]);1"])
    assert parsed == {"TIME": "j;o[", "MESM": "STANDARD(max:100000[mm])"}
    assert not caplog.records
    assert parse_time_field(parsed["TIME"]) == 15_253_483
    assert parse_time_field("4991D0") == 0x4991D0


def test_parameter_checksum_variants_are_accepted_and_a_mismatch_names_the_line() -> None:
    texts = (b"PROT:SCIP 2.0", b"SERI:H0123456")
    with_semicolon = [text + b";" + checksum(text + b";") for text in texts]
    assert parse_parameter_lines(with_semicolon, "VV") == {"PROT": "SCIP 2.0", "SERI": "H0123456"}
    commented = b"SCSP:Initial(600[rpm])<-Default setting by user;A"
    assert parse_parameter_lines([commented], "II")["SCSP"].startswith("Initial(600[rpm])")
    with pytest.raises(ChecksumError, match=r"PP reply line 'AFRT:560;0' fails its checksum"):
        parse_parameter_lines([b"AMAX:1080;Z", b"AFRT:560;0"], "PP")


def test_a_line_matching_only_the_other_checksum_convention_is_refused() -> None:
    """'MODL:UTM-35LX-EW' under the old checksum passes if the ';' is summed too: one
    firmware sums one way, so a reply mixing the two is damaged."""
    with pytest.raises(ChecksumError, match="'MODL:UTM-35LX-EW;I' fails its checksum"):
        parse_parameter_lines([b"DMIN:23;7", b"MODL:UTM-35LX-EW;I"], "PP")
    with pytest.raises(ChecksumError, match="not printable"):
        parse_parameter_lines([b"MODL:UTM-3\xb0LX-EW;I"], "PP")


@pytest.mark.parametrize(
    ("line", "problem"), [(b"SERI:00903971", "no ';' \\+ checksum"), (b"garbage", "no key")]
)
def test_parameter_line_without_checksum_or_key_is_an_error(line: bytes, problem: str) -> None:
    with pytest.raises(ChecksumError, match=problem):
        parse_parameter_lines([line], "VV")


def test_time_field_rejects_other_widths() -> None:
    with pytest.raises(ProtocolError):
        parse_time_field("12345")


def test_status_meanings_are_command_specific() -> None:
    assert status_meaning("BM", "02") == "laser is already on"
    assert status_meaning("GD", "10") == "laser is off (send BM first)"
    assert status_meaning("TM", "04") == "TM1 while not in time-adjust mode"
    assert status_meaning("XX", "0E") == "undefined command"
    assert status_meaning("MD", "0E") == "undefined command"
    for command in ("ME", "GE"):  # a model without intensities: the way out is MD
        assert "intensities = false" in status_meaning(command, "0E")
    assert "hardware" in status_meaning("MD", "55")
    assert codec.STATUS_MEANINGS["0G"].startswith("string field")


def test_request_formatting() -> None:
    assert format_scan_request("ME", 0, 1080, 1, interval=0, count=1) == b"ME0000108001001\n"
    assert format_scan_request("GD", 44, 725, 1) == b"GD0044072501\n"
    assert format_request("TM", "1", tag="1a") == b"TM1;1a\n"
    with pytest.raises(ValueError):
        format_request("VV", tag="x" * 17)
    with pytest.raises(ValueError):
        format_scan_request("XX", 0, 1, 1)


def test_scan_request_parse_and_echo() -> None:
    request = parse_scan_request(b"ME0000108001101")
    assert request == ScanRequest("ME", 0, 1080, 1, 1, 1, None)
    assert request.line(count=0) == b"ME0000108001100"
    assert request.payload_chars == 6486
    assert parse_scan_request(b"GD0044072501;ab").tag == "ab"
    assert parse_scan_request(b"MS0000001003099").chars_per_value == 2


@pytest.mark.parametrize(
    ("line", "status"),
    [
        (b"MDx000108000000", "01"),
        (b"MD0000x08000000", "02"),
        (b"MD000010800x000", "03"),
        (b"MD0000108001x00", "06"),
        (b"MD000010800100x", "07"),
        (b"GD00000100", "0C"),
        (b"GD00000100011", "0D"),
        (b"GD0000010001;" + b"a" * 17, "0G"),
        (b"GD0000010001;a-b", "0H"),
    ],
)
def test_scan_request_errors_carry_the_sensor_status(line: bytes, status: str) -> None:
    with pytest.raises(codec.RequestParameterError) as info:
        parse_scan_request(line)
    assert info.value.status == status


# --------------------------------------------------------------------------- captures


def test_utm30lx_capture_in_random_chunks_gives_exactly_the_logged_messages() -> None:
    stream = capture("utm30lx_read")
    for seed in range(20):
        framer = ResponseFramer()
        responses = feed_in_chunks(framer, stream, random.Random(seed))
        assert [r.echo for r in responses] == UTM30LX_ECHOES
        assert framer.discarded_bytes == 0 and framer.pending_bytes == 0
        assert b"".join(r.to_bytes() for r in responses) == stream


def test_utm30lx_statuses_and_parameters() -> None:
    responses = ResponseFramer().feed(capture("utm30lx_read"))
    assert [r.status_text for r in responses] == ["00", "00", "00", "00", "02", "04", "00", "00", "00",
                                                  "00", "99"]
    version = parse_parameter_lines(responses[0].data_lines)
    assert version == {
        "VEND": "Hokuyo Automatic Co.,Ltd.",
        "PROD": "SOKUIKI Sensor TOP-URG UTM-30LX",
        "FIRM": "P.1.05(17/Apr./2009)",
        "PROT": "SCIP 2.0",
        "SERI": "00903971",
    }
    params = parse_parameter_lines(responses[2].data_lines)
    assert params["DMIN"] == "23" and params["ARES"] == "1440" and params["AFRT"] == "540"
    status = parse_parameter_lines(responses[3].data_lines)
    assert parse_time_field(status["TIME"]) == 0x4991D0


def test_utm30lx_me_scan_decodes_to_the_oracle() -> None:
    message = ResponseFramer().feed(capture("utm30lx_read"))[-1]
    assert len(message.data_lines) == 1 + 102
    assert len(message.data_lines[-1]) == 22 + 1
    scan = decode_scan_lines(message.data_lines, parse_scan_request(message.echo))
    assert scan.timestamp_ms == 4_821_609
    distances, intensities = scan.distances_mm, scan.intensities
    assert intensities is not None
    assert distances.dtype == np.int64 and len(distances) == 1081
    assert (distances.min(), distances.max(), distances.sum()) == (45, 5856, 1_287_760)
    assert list(distances[:5]) == [45, 48, 49, 50, 49]
    assert list(distances[-10:]) == [49, 49, 49, 51, 55, 55, 53, 52, 52, 49]
    assert (intensities.min(), intensities.max(), intensities.sum()) == (137, 16219, 2_602_800)
    assert list(intensities[:3]) == [1809, 1780, 1792]
    assert sha_joined(distances) == "6ec2d81ce6d75e5460080468f072492aa1e724bab53d2adf2c6333a15704de1f"
    assert sha_joined(intensities) == "ba14f09914bdabac48e59b2e55aeea7e84a07d960713b909d4f0246ca9518ddb"
    # and back: the encoder reproduces the captured lines byte for byte
    assert encode_scan_lines(scan.timestamp_ms, distances, intensities) == list(message.data_lines)


@pytest.mark.parametrize(
    ("name", "echo", "count", "stats", "digest"),
    [
        ("urg04lx_read", b"GD0044072501", 682, (0, 4166, 656_336),
         "64ed2992ec7fe2beafbbc46eafcaec27fdd1283921de4e9bb87e3002205a580e"),
        ("uxm30lxe_read", b"GD0000076001", 761, (337, 3179, 1_275_747),
         "ebd564254c79a5038acc515001283fa163f60d6b77172db8bfb943cf48c10d9f"),
    ],
)
def test_gd_captures_decode_to_the_oracle(name, echo, count, stats, digest) -> None:
    message = ResponseFramer().feed(capture(name))[-1]
    assert message.echo == echo
    scan = decode_scan_lines(message.data_lines, parse_scan_request(message.echo))
    assert scan.intensities is None and len(scan.distances_mm) == count
    d = scan.distances_mm
    assert (d.min(), d.max(), d.sum()) == stats
    assert sha_joined(d) == digest


def test_garbage_in_front_resynchronises() -> None:
    me_message = ResponseFramer().feed(capture("utm30lx_read"))[-1].to_bytes()
    garbage = me_message[len(me_message) // 2 :]
    for name, echoes in (("urg04lx_read", URG04LX_ECHOES), ("uxm30lxe_read", UXM30LXE_ECHOES)):
        stream = capture(name)
        for seed in range(5):
            framer = ResponseFramer()
            responses = feed_in_chunks(framer, garbage + stream, random.Random(seed))
            assert [r.echo for r in responses] == echoes
            assert framer.discarded_bytes == len(garbage)
    both = ResponseFramer().feed(garbage + capture("urg04lx_read") + capture("uxm30lxe_read"))
    assert [r.echo for r in both] == URG04LX_ECHOES + UXM30LXE_ECHOES


def test_garbage_without_blank_line_before_an_echo_is_skipped() -> None:
    framer = ResponseFramer()
    responses = framer.feed(b"0Pg0;E0Pn0;F\n0Q:0;J0P^\nQT\n00P\n\n")
    assert [(r.echo, r.status) for r in responses] == [(b"QT", b"00")]


def test_urg_stamped_resync_vector() -> None:
    data = b"QT\n00P\n\nFOO\nBAR\nQT\n\nQT\n\nQT\n00P\n\n\n\n"
    for seed in range(10):
        responses = feed_in_chunks(ResponseFramer(), data, random.Random(seed), max_chunk=4)
        assert [r.echo for r in responses] == [b"QT", b"QT"]


def test_truncated_message_followed_by_a_complete_one_keeps_the_complete_one() -> None:
    scan = ResponseFramer().feed(capture("utm30lx_read"))[-1].to_bytes()
    truncated = scan[: scan.index(b"\n", len(scan) // 3) + 1]  # cut after a whole line
    framer = ResponseFramer()
    responses = framer.feed(truncated + b"QT\n00P\n\n")
    assert [(r.echo, r.status) for r in responses] == [(b"QT", b"00")]
    assert framer.discarded_bytes == len(truncated)


def test_message_cut_mid_line_is_rejected_by_the_scan_decoder() -> None:
    scan = ResponseFramer().feed(capture("utm30lx_read"))[-1].to_bytes()
    truncated = scan[: len(scan) // 3]
    (response,) = ResponseFramer().feed(truncated + b"QT\n00P\n\n")
    assert response.echo == b"ME0000108001100"
    with pytest.raises(ProtocolError):
        decode_scan_lines(response.data_lines, parse_scan_request(response.echo))


def test_corrupted_char_in_74th_data_line_is_reported_for_that_line_only() -> None:
    message = ResponseFramer().feed(capture("utm30lx_read"))[-1]
    lines = list(message.data_lines[1:])
    assert lines[73] == b"QE0;=0Pg0;E0Pn0;F0Q:0;J0P^0;J0P[0;S0Pe0;S0PT0;R0P80;R0P@0;T0Ol0;>"
    corrupted = lines[73][:10] + b"1" + lines[73][11:]
    assert corrupted != lines[73]
    lines[73] = corrupted
    with pytest.raises(DataLineChecksumError) as info:
        decode_data_lines(lines)
    assert info.value.bad_lines == [73]
    assert "line(s) 74 of 102" in str(info.value)
    # the framer still delivers the message (it cannot know the line types); the scan
    # decoder rejects it
    stream = format_response(message.echo, message.status, [message.data_lines[0], *lines])
    framed = ResponseFramer().feed(stream)
    assert len(framed) == 1
    with pytest.raises(ChecksumError):
        decode_scan_lines(framed[0].data_lines, parse_scan_request(framed[0].echo))


def test_scan_with_wrong_value_count_is_a_protocol_error() -> None:
    lines = encode_scan_lines(5, np.arange(30, 40))
    with pytest.raises(ProtocolError, match="expected 33"):
        decode_scan_lines(lines, ScanRequest("GD", 0, 10, 1))
    with pytest.raises(ProtocolError, match="timestamp"):
        decode_scan_lines([], ScanRequest("GD", 0, 10, 1))
    with pytest.raises(ChecksumError):
        decode_scan_lines([b"BI9YN", *lines[1:]], ScanRequest("GD", 0, 9, 1))


def test_command_framer_terminators_and_empty_lines() -> None:
    framer = CommandFramer()
    assert framer.feed(b"VV\r\nPP\rII\n\n\r\nBM") == [b"VV", b"PP", b"II"]
    assert framer.feed(b"\r") == [b"BM"]
    assert framer.feed(b"\nQT;abc\n") == [b"QT;abc"]
    assert framer.feed(b"\x02AR00" + b"x" * 5000) == []
    assert framer.feed(b"\nVV\n") == [b"VV"]


# --------------------------------------------------------------------------- properties


@given(width=st.integers(1, 4), data=st.data())
def test_int_round_trip(width: int, data: st.DataObject) -> None:
    value = data.draw(st.integers(0, (1 << (6 * width)) - 1))
    chars = encode_int(value, width)
    assert len(chars) == width and all(0x30 <= c <= 0x6F for c in chars)
    assert decode_int(chars) == value


@given(width=st.sampled_from([2, 3, 4]), data=st.data())
def test_values_round_trip_and_match_scalar_codec(width: int, data: st.DataObject) -> None:
    values = data.draw(st.lists(st.integers(0, (1 << (6 * width)) - 1), max_size=300))
    chars = encode_values(np.array(values, dtype=np.int64), width)
    assert chars == b"".join(encode_int(v, width) for v in values)
    decoded = decode_values(chars, width)
    assert decoded.dtype == np.int64
    assert decoded.tolist() == values


@given(payload=st.binary(max_size=700).map(lambda b: bytes(0x30 + (x & 0x3F) for x in b)))
def test_data_lines_round_trip(payload: bytes) -> None:
    lines = encode_data_lines(payload)
    assert all(len(line) <= 65 for line in lines)
    assert all(len(line) == 65 for line in lines[:-1])
    assert decode_data_lines(lines) == payload


echo_text = st.text(alphabet="ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789;", min_size=2, max_size=20).filter(
    lambda s: s[:2].isalpha()
)
status_text = st.text(alphabet="0123456789ABCDEFGHIJKLMNOPQRSTUVWXYZ", min_size=2, max_size=2)
scip_payload = st.binary(min_size=1, max_size=200).map(lambda b: bytes(0x30 + (x & 0x3F) for x in b))


@settings(max_examples=60, deadline=None)
@given(
    messages=st.lists(st.tuples(echo_text, status_text, scip_payload), min_size=1, max_size=6),
    seed=st.integers(0, 1000),
)
def test_responses_survive_the_framer_in_random_chunks(messages, seed) -> None:
    expected = [
        Response(echo.encode(), status.encode(), tuple(encode_data_lines(payload)))
        for echo, status, payload in messages
    ]
    stream = b"".join(r.to_bytes() for r in expected)
    assert feed_in_chunks(ResponseFramer(), stream, random.Random(seed), max_chunk=50) == expected


@settings(max_examples=200, deadline=None)
@given(garbage=st.binary(max_size=3000), seed=st.integers(0, 1000))
def test_random_garbage_never_crashes_and_stays_bounded(garbage: bytes, seed: int) -> None:
    framer = ResponseFramer(max_buffer_bytes=1000)
    feed_in_chunks(framer, garbage, random.Random(seed), max_chunk=300)
    assert framer.pending_bytes <= 1000 + 300
    # after garbage and a blank line, a good message still comes through
    assert [r.echo for r in framer.feed(b"\n\nQT\n00P\n\n")] == [b"QT"]


@settings(max_examples=100, deadline=None)
@given(cut=st.integers(0, 7813), seed=st.integers(0, 1000))
def test_truncated_capture_yields_only_complete_messages(cut: int, seed: int) -> None:
    stream = capture("utm30lx_read")
    framer = ResponseFramer()
    responses = feed_in_chunks(framer, stream[:cut], random.Random(seed))
    complete = stream[:cut].count(b"\n\n")
    assert [r.echo for r in responses] == UTM30LX_ECHOES[:complete]


def test_irregular_line_lengths_are_checked_one_by_one() -> None:
    lines = [b"0123" + checksum(b"0123"), b"45" + checksum(b"45"), b"6789" + checksum(b"6789")]
    assert decode_data_lines(lines) == b"0123456789"
    with pytest.raises(DataLineChecksumError) as info:
        decode_data_lines([lines[0], b"45X", lines[2], b"7"])
    assert info.value.bad_lines == [1, 3]
    with pytest.raises(DataLineChecksumError) as info:
        decode_data_lines([*encode_data_lines(b"0" * 130)[:2], b"12X"])
    assert info.value.bad_lines == [2]
    assert decode_data_lines([]) == b""
