"""Pure RTDE wire-format pieces of the fake: framing, setup payloads, recipes."""

from __future__ import annotations

import itertools
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fakes.ur_controller import rtde_protocol as rp


def test_message_framing_splits_and_joins_across_chunks() -> None:
    wire = rp.encode_message(rp.CONTROL_PACKAGE_START) + rp.encode_message(rp.DATA_PACKAGE, b"\x01abc")
    framer = rp.MessageFramer()
    assert framer.feed(wire[:4]) == [(rp.CONTROL_PACKAGE_START, b"")]
    assert framer.feed(wire[4:6]) == []
    assert framer.feed(wire[6:]) == [(rp.DATA_PACKAGE, b"\x01abc")]


def test_framer_rejects_size_below_header() -> None:
    with pytest.raises(ValueError, match="below the header"):
        rp.MessageFramer().feed(b"\x00\x02U")


def test_output_setup_parses_frequency_and_drops_trailing_comma() -> None:
    payload = struct.pack(">d", 500.0) + b"timestamp,actual_TCP_pose,"
    assert rp.parse_setup_outputs(payload) == (500.0, ["timestamp", "actual_TCP_pose"])


def test_types_resolve_registers_and_unknown_names() -> None:
    types, ok = rp.resolve(["output_int_register_2", "output_double_register_47", "actual_q"], rp.output_type)
    assert ok and types == ["INT32", "DOUBLE", "VECTOR6D"]
    types, ok = rp.resolve(["output_int_register_48", "bogus"], rp.output_type)
    assert not ok and types == [rp.NOT_FOUND, rp.NOT_FOUND]
    assert rp.input_type("output_int_register_0") is None
    assert rp.input_type("input_double_register_5") == "DOUBLE"


def test_recipe_packs_standard_sizes_and_pads_short_input() -> None:
    recipe = rp.Recipe(["timestamp", "actual_q", "robot_mode", "actual_tool_accelerometer"],
                       ["DOUBLE", "VECTOR6D", "INT32", "VECTOR3D"])
    assert recipe.size == 8 + 48 + 4 + 24
    packed = recipe.pack({"timestamp": 1.5, "actual_q": (1, 2, 3, 4, 5, 6), "robot_mode": 7,
                          "actual_tool_accelerometer": (0, 0, 9.81)})
    values = recipe.unpack(packed)
    assert values["actual_q"] == (1, 2, 3, 4, 5, 6) and values["robot_mode"] == 7
    short = rp.Recipe(["input_int_register_0", "input_double_register_0"], ["INT32", "DOUBLE"])
    assert short.unpack(struct.pack(">i", 55)) == {"input_int_register_0": 55, "input_double_register_0": 0.0}


def test_version_reply_is_four_big_endian_uint32() -> None:
    assert rp.version_reply((5, 11, 6, 108949)) == struct.pack(">IIII", 5, 11, 6, 108949)


@given(payloads=st.lists(st.binary(max_size=300), max_size=8),
       cuts=st.lists(st.integers(0, 3000), max_size=10))
def test_framing_is_independent_of_how_the_stream_is_cut(payloads: list[bytes], cuts: list[int]) -> None:
    wire = b"".join(rp.encode_message(rp.DATA_PACKAGE, payload) for payload in payloads)
    bounds = sorted({0, len(wire), *(c for c in cuts if c < len(wire))})
    framer = rp.MessageFramer()
    received = [m for a, b in itertools.pairwise(bounds) for m in framer.feed(wire[a:b])]
    assert received == [(rp.DATA_PACKAGE, payload) for payload in payloads]


@given(q=st.lists(st.floats(allow_nan=False, width=64), min_size=6, max_size=6),
       mode=st.integers(-(2**31), 2**31 - 1), bits=st.integers(0, 2**32 - 1))
def test_recipe_round_trip(q: list[float], mode: int, bits: int) -> None:
    recipe = rp.Recipe(["actual_q", "robot_mode", "safety_status_bits"], ["VECTOR6D", "INT32", "UINT32"])
    values = recipe.unpack(recipe.pack({"actual_q": q, "robot_mode": mode, "safety_status_bits": bits}))
    assert values == {"actual_q": tuple(q), "robot_mode": mode, "safety_status_bits": bits}
