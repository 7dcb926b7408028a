"""RTDE wire format (port 30004), pure: framing, setup payloads, recipes, type table.

Everything is big-endian. A message is ``uint16 size (including the 3-byte header),
uint8 package type, payload``. No I/O happens here; the server feeds bytes in and writes
the bytes these functions return.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Callable, Iterable, Mapping, Sequence

HEADER = struct.Struct(">HB")

REQUEST_PROTOCOL_VERSION = ord("V")
GET_URCONTROL_VERSION = ord("v")
TEXT_MESSAGE = ord("M")
DATA_PACKAGE = ord("U")
CONTROL_PACKAGE_SETUP_OUTPUTS = ord("O")
CONTROL_PACKAGE_SETUP_INPUTS = ord("I")
CONTROL_PACKAGE_START = ord("S")
CONTROL_PACKAGE_PAUSE = ord("P")

NOT_FOUND = "NOT_FOUND"
IN_USE = "IN_USE"

#: struct codes and scalar counts of the RTDE types.
TYPE_FORMATS: dict[str, str] = {
    "DOUBLE": "d",
    "UINT32": "I",
    "INT32": "i",
    "UINT64": "Q",
    "UINT8": "B",
    "BOOL": "B",
    "VECTOR3D": "3d",
    "VECTOR6D": "6d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}
VECTOR_LENGTHS: dict[str, int] = {"VECTOR3D": 3, "VECTOR6D": 6, "VECTOR6INT32": 6, "VECTOR6UINT32": 6}

REGISTER_COUNT = 48

_OUTPUT_TYPES: dict[str, str] = {
    "timestamp": "DOUBLE",
    "target_q": "VECTOR6D",
    "target_qd": "VECTOR6D",
    "target_qdd": "VECTOR6D",
    "target_current": "VECTOR6D",
    "target_moment": "VECTOR6D",
    "actual_q": "VECTOR6D",
    "actual_qd": "VECTOR6D",
    "actual_current": "VECTOR6D",
    "actual_current_window": "VECTOR6D",
    "actual_current_as_torque": "VECTOR6D",
    "joint_control_output": "VECTOR6D",
    "actual_TCP_pose": "VECTOR6D",
    "actual_TCP_speed": "VECTOR6D",
    "actual_TCP_force": "VECTOR6D",
    "target_TCP_pose": "VECTOR6D",
    "target_TCP_speed": "VECTOR6D",
    "actual_digital_input_bits": "UINT64",
    "joint_temperatures": "VECTOR6D",
    "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32",
    "safety_status": "INT32",
    "actual_tool_accelerometer": "VECTOR3D",
    "speed_scaling": "DOUBLE",
    "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE",
    "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE",
    "actual_joint_voltage": "VECTOR6D",
    "actual_digital_output_bits": "UINT64",
    "runtime_state": "UINT32",
    "elbow_position": "VECTOR3D",
    "elbow_velocity": "VECTOR3D",
    "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32",
    "analog_io_types": "UINT32",
    "standard_analog_input0": "DOUBLE",
    "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE",
    "standard_analog_output1": "DOUBLE",
    "io_current": "DOUBLE",
    "euromap67_input_bits": "UINT32",
    "euromap67_output_bits": "UINT32",
    "euromap67_24V_voltage": "DOUBLE",
    "euromap67_24V_current": "DOUBLE",
    "tool_mode": "UINT32",
    "tool_analog_input_types": "UINT32",
    "tool_analog_input0": "DOUBLE",
    "tool_analog_input1": "DOUBLE",
    "tool_output_voltage": "INT32",
    "tool_output_current": "DOUBLE",
    "tool_temperature": "DOUBLE",
    "tcp_force_scalar": "DOUBLE",
    "output_bit_registers0_to_31": "UINT32",
    "output_bit_registers32_to_63": "UINT32",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "payload": "DOUBLE",
    "payload_cog": "VECTOR3D",
    "payload_inertia": "VECTOR6D",
    "script_control_line": "UINT32",
    "ft_raw_wrench": "VECTOR6D",
    "tool_accelerometer_values": "VECTOR3D",
}

_INPUT_TYPES: dict[str, str] = {
    "speed_slider_mask": "UINT32",
    "speed_slider_fraction": "DOUBLE",
    "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8",
    "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8",
    "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": "DOUBLE",
    "standard_analog_output_1": "DOUBLE",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "external_force_torque": "VECTOR6D",
}

_REGISTER = re.compile(r"^(input|output)_(int|double)_register_(\d+)$")


def register_index(name: str) -> tuple[str, str, int] | None:
    """``("input"|"output", "int"|"double", index)`` for a register name, else None."""
    match = _REGISTER.match(name)
    if match is None or int(match.group(3)) >= REGISTER_COUNT:
        return None
    return match.group(1), match.group(2), int(match.group(3))


def _register_type(name: str) -> str | None:
    reg = register_index(name)
    if reg is None:
        return None
    return "INT32" if reg[1] == "int" else "DOUBLE"


def output_type(name: str) -> str | None:
    """RTDE type of an output (controller -> client) variable, None if unknown.

    Input registers may be read back as outputs, as on a real controller.
    """
    return _OUTPUT_TYPES.get(name) or _register_type(name)


def input_type(name: str) -> str | None:
    """RTDE type of an input (client -> controller) variable, None if unknown."""
    reg = register_index(name)
    if reg is not None:
        return _register_type(name) if reg[0] == "input" else None
    return _INPUT_TYPES.get(name)


def encode_message(package_type: int, payload: bytes = b"") -> bytes:
    """One framed RTDE message."""
    return HEADER.pack(HEADER.size + len(payload), package_type) + payload


class MessageFramer:
    """Incremental splitter: bytes in, ``(package_type, payload)`` tuples out."""

    def __init__(self) -> None:
        self._buffer = bytearray()

    def feed(self, data: bytes) -> list[tuple[int, bytes]]:
        """Add received bytes; return every complete message now available.

        Raises ``ValueError`` on a size field below the header size (stream is corrupt).
        """
        self._buffer += data
        messages: list[tuple[int, bytes]] = []
        while len(self._buffer) >= HEADER.size:
            size, package_type = HEADER.unpack_from(self._buffer)
            if size < HEADER.size:
                raise ValueError(f"RTDE message size {size} is below the header size")
            if len(self._buffer) < size:
                break
            messages.append((package_type, bytes(self._buffer[HEADER.size:size])))
            del self._buffer[:size]
        return messages


def split_names(text: bytes) -> list[str]:
    """Comma-separated variable names; the trailing comma ur_rtde sends gives no name."""
    return [name.strip() for name in text.decode("ascii", errors="replace").split(",") if name.strip()]


def parse_setup_outputs(payload: bytes) -> tuple[float, list[str]]:
    """``O`` request (protocol v2): float64 frequency then the names."""
    if len(payload) < 8:
        raise ValueError("RTDE output setup request shorter than its 8-byte frequency")
    (frequency_hz,) = struct.unpack_from(">d", payload)
    return frequency_hz, split_names(payload[8:])


def setup_reply(recipe_id: int, types: Sequence[str]) -> bytes:
    """Payload of an ``O``/``I`` reply: recipe id byte then the comma-separated types."""
    return bytes([recipe_id & 0xFF]) + ",".join(types).encode("ascii")


def version_reply(version: tuple[int, int, int, int]) -> bytes:
    """Payload of the ``v`` reply: major, minor, bugfix, build as uint32."""
    return struct.pack(">IIII", *version)


class Recipe:
    """An ordered list of variables with their types, packed as one struct."""

    def __init__(self, names: Sequence[str], types: Sequence[str]) -> None:
        self.names = tuple(names)
        self.types = tuple(types)
        self._struct = struct.Struct(">" + "".join(TYPE_FORMATS[t] for t in self.types))
        self._counts = tuple(VECTOR_LENGTHS.get(t, 1) for t in self.types)

    @property
    def size(self) -> int:
        """Packed size in bytes (without the recipe id byte)."""
        return self._struct.size

    @property
    def format(self) -> str:
        """The ``struct`` format of the values (big-endian)."""
        return self._struct.format

    def pack(self, values: Mapping[str, object]) -> bytes:
        """Pack the values named by the recipe; every name must be present."""
        return self.pack_in_order([values[name] for name in self.names])

    def pack_in_order(self, values: Sequence[object]) -> bytes:
        """Pack one value per recipe entry, in recipe order."""
        flat: list[object] = []
        for value, count in zip(values, self._counts, strict=True):
            if count > 1:
                flat.extend(value)  # type: ignore[call-overload]
            else:
                flat.append(value)
        return self._struct.pack(*flat)

    def unpack(self, data: bytes) -> dict[str, object]:
        """Values by name. Short input is zero-padded and long input truncated: ur_rtde
        1.6.5 sends at least one command 4 bytes short of its recipe."""
        if len(data) < self.size:
            data = data + bytes(self.size - len(data))
        flat = self._struct.unpack_from(data)
        values: dict[str, object] = {}
        pos = 0
        for name, count in zip(self.names, self._counts, strict=True):
            values[name] = flat[pos:pos + count] if count > 1 else flat[pos]
            pos += count
        return values


def data_package_struct(recipe: Recipe) -> struct.Struct:
    """A whole output data package as one struct: the header (size, ``U``), the recipe id
    byte, then the recipe's values."""
    return struct.Struct(HEADER.format + "B" + recipe.format.removeprefix(">"))


def resolve(names: Iterable[str], lookup: Callable[[str], str | None]) -> tuple[list[str], bool]:
    """Types for the names via ``lookup`` (``output_type`` or ``input_type``); the flag is
    False when at least one name is unknown (its type is then ``NOT_FOUND``)."""
    types = [lookup(name) or NOT_FOUND for name in names]
    return types, NOT_FOUND not in types
