"""RTDE server (port 30004): setup handshake per connection, data streaming, inputs.

Each connection gets an ``RtdeSession``. Its own thread reads requests and answers each
setup request with exactly one reply (ur_rtde takes whatever arrives next as the reply).
Data packages are sent from the controller's cycle thread (``RtdeServer.on_cycle``),
one per controller cycle at the full rate (every n-th cycle for a rate n times lower),
with a non-blocking send: a client that stops
reading loses packages, never the stream's framing, and never stalls the controller.
"""

from __future__ import annotations

import logging
import operator
import socket
import struct
import threading

from fakes.ur_controller import rtde_protocol as rp
from fakes.ur_controller.controller import SNAPSHOT_SLICES, FakeController, Snapshot

logger = logging.getLogger(__name__)

_CONSTANT_VALUES: dict[str, object] = {
    "joint_temperatures": (30.0,) * 6,
    "actual_execution_time": 0.3,
    "joint_mode": (253,) * 6,
    "actual_tool_accelerometer": (0.0, 0.0, 9.81),
    "speed_scaling": 1.0,
    "target_speed_fraction": 1.0,
    "actual_main_voltage": 48.0,
    "actual_robot_voltage": 48.0,
    "actual_robot_current": 0.5,
    "tool_temperature": 30.0,
}
_OUTPUT_RECIPE_ID = 1


def _constant(name: str, rtype: str) -> tuple[object, ...]:
    """The scalars of an output the fake does not simulate: a fixed value, else zeros."""
    if name in _CONSTANT_VALUES:
        value = _CONSTANT_VALUES[name]
        return value if isinstance(value, tuple) else (value,)
    zero: object = 0.0 if rtype in ("DOUBLE", "VECTOR3D", "VECTOR6D") else 0
    return (zero,) * rp.VECTOR_LENGTHS.get(rtype, 1)


def _snapshot_slice(name: str) -> slice | None:
    """Where output ``name`` lies in ``Snapshot.state``; None if the fake does not simulate it."""
    register = rp.register_index(name)
    if register is None:
        return SNAPSHOT_SLICES.get(name)
    direction, kind, index = register
    first = SNAPSHOT_SLICES[f"{direction}_{kind}_register"].start + index
    return slice(first, first + 1)


class DataPackager:
    """One output recipe compiled once: each cycle's whole data package (header, recipe
    id, values) is one index pick from the snapshot and one ``struct.pack``, so the cycle
    thread spends microseconds per client, not a lookup per variable."""

    def __init__(self, recipe: rp.Recipe, recipe_id: int) -> None:
        self._struct = rp.data_package_struct(recipe)
        state_size = max(where.stop for where in SNAPSHOT_SLICES.values())
        # The header and the constants follow the snapshot's state in what the pick reads.
        constants: list[object] = [self._struct.size, rp.DATA_PACKAGE, recipe_id]
        picks = [state_size, state_size + 1, state_size + 2]
        for name, rtype in zip(recipe.names, recipe.types, strict=True):
            where = _snapshot_slice(name)
            if where is not None:
                picks.extend(range(where.start, where.stop))
            else:
                for value in _constant(name, rtype):
                    picks.append(state_size + len(constants))
                    constants.append(value)
        self._constants = tuple(constants)
        self._pick = operator.itemgetter(*picks)

    def package(self, snapshot: Snapshot) -> bytes:
        """The framed data package of this recipe for ``snapshot``."""
        return self._struct.pack(*self._pick(snapshot.state + self._constants))


class RtdeSession:
    """One client connection."""

    def __init__(self, server: RtdeServer, sock: socket.socket) -> None:
        self.server = server
        self.sock = sock
        self._write_lock = threading.Lock()
        self._pending = b""
        self._output: DataPackager | None = None
        self._cycles_per_package = 1
        self._cycle_count = 0
        self._inputs: dict[int, rp.Recipe] = {}
        self._next_input_id = 1
        self.streaming = False

    # -- writes ----------------------------------------------------------------------------

    def _reply(self, package_type: int, payload: bytes) -> None:
        message = rp.encode_message(package_type, payload)
        with self._write_lock:
            if self._pending:
                self.sock.sendall(self._pending)
                self._pending = b""
            self.sock.sendall(message)

    def send_data(self, snapshot: Snapshot) -> None:
        """Send this cycle's data package if one is due (called on the cycle thread):
        every cycle at the full rate, every n-th cycle at a rate n times lower."""
        if not self.streaming or self._output is None:
            return
        self._cycle_count += 1
        if self._cycle_count < self._cycles_per_package:
            return
        self._cycle_count = 0
        message = self._output.package(snapshot)
        if not self._write_lock.acquire(blocking=False):
            return  # a reply is being written; this package is skipped
        try:
            if self._pending:
                self._pending = self._send_some(self._pending)
                if self._pending:
                    return  # client is not reading; drop this package
            self._pending = self._send_some(message)
        except OSError:
            self.streaming = False
        finally:
            self._write_lock.release()

    def _send_some(self, data: bytes) -> bytes:
        try:
            sent = self.sock.send(data, socket.MSG_DONTWAIT)
        except BlockingIOError:
            return data
        return data[sent:]

    # -- requests -------------------------------------------------------------------------

    def serve(self) -> None:
        """Read and answer requests until the client disconnects."""
        framer = rp.MessageFramer()
        while True:
            chunk = self.sock.recv(65536)
            if not chunk:
                return
            for package_type, payload in framer.feed(chunk):
                self._handle(package_type, payload)

    def _handle(self, package_type: int, payload: bytes) -> None:
        controller = self.server.controller
        if package_type == rp.DATA_PACKAGE:
            recipe = self._inputs.get(payload[0]) if payload else None
            if recipe is None:
                logger.debug("RTDE input package with unknown recipe ignored")
                return
            controller.write_inputs(recipe.unpack(payload[1:]))
        elif package_type == rp.REQUEST_PROTOCOL_VERSION:
            version = struct.unpack(">H", payload[:2])[0] if len(payload) >= 2 else 0
            self._reply(package_type, bytes([1 if version in (1, 2) else 0]))
        elif package_type == rp.GET_URCONTROL_VERSION:
            self._reply(package_type, rp.version_reply(controller.config.version))
        elif package_type == rp.CONTROL_PACKAGE_SETUP_OUTPUTS:
            self._setup_outputs(payload)
        elif package_type == rp.CONTROL_PACKAGE_SETUP_INPUTS:
            self._setup_inputs(payload)
        elif package_type == rp.CONTROL_PACKAGE_START:
            self._cycle_count = self._cycles_per_package - 1  # first package on the next cycle
            self._reply(package_type, bytes([1 if self._output is not None else 0]))
            self.streaming = self._output is not None
        elif package_type == rp.CONTROL_PACKAGE_PAUSE:
            self.streaming = False
            self._reply(package_type, b"\x01")
        else:
            logger.debug("RTDE package type %r ignored", chr(package_type))

    def _setup_outputs(self, payload: bytes) -> None:
        frequency_hz, names = rp.parse_setup_outputs(payload)
        types, ok = rp.resolve(names, rp.output_type)
        if not ok:
            self._reply(rp.CONTROL_PACKAGE_SETUP_OUTPUTS, rp.setup_reply(0, types))
            return
        cycle_hz = self.server.controller.config.cycle_hz
        if not 0.0 < frequency_hz <= cycle_hz:
            logger.warning("RTDE output frequency %.1f Hz out of range; streaming at %.0f Hz",
                           frequency_hz, cycle_hz)
            frequency_hz = cycle_hz
        self._output = DataPackager(rp.Recipe(names, types), _OUTPUT_RECIPE_ID)
        self._cycles_per_package = max(1, round(cycle_hz / frequency_hz))
        self._reply(rp.CONTROL_PACKAGE_SETUP_OUTPUTS, rp.setup_reply(_OUTPUT_RECIPE_ID, types))

    def _setup_inputs(self, payload: bytes) -> None:
        names = rp.split_names(payload)
        types, ok = rp.resolve(names, rp.input_type)
        if ok:
            types, ok = self.server.claim_inputs(self, names, types)
        if not ok:
            self._reply(rp.CONTROL_PACKAGE_SETUP_INPUTS, rp.setup_reply(0, types))
            return
        recipe_id = self._next_input_id
        self._next_input_id += 1
        self._inputs[recipe_id] = rp.Recipe(names, types)
        self._reply(rp.CONTROL_PACKAGE_SETUP_INPUTS, rp.setup_reply(recipe_id, types))


class RtdeServer:
    """All RTDE sessions of one controller, input ownership, and the data streamer."""

    def __init__(self, controller: FakeController) -> None:
        self.controller = controller
        self._sessions: list[RtdeSession] = []
        self._owners: dict[str, RtdeSession] = {}
        self._lock = threading.Lock()
        controller.add_tick_listener(self.on_cycle)

    def claim_inputs(self, session: RtdeSession, names: list[str],
                     types: list[str]) -> tuple[list[str], bool]:
        """Claim input variables for a session; ``IN_USE`` for those another live
        connection owns (nothing is claimed then)."""
        with self._lock:
            result = [rp.IN_USE if self._owners.get(n, session) is not session else t
                      for n, t in zip(names, types, strict=True)]
            if rp.IN_USE in result:
                return result, False
            for name in names:
                self._owners[name] = session
            return result, True

    def serve(self, sock: socket.socket) -> None:
        """Handle one connection (TcpListener handler)."""
        session = RtdeSession(self, sock)
        with self._lock:
            self._sessions.append(session)
        try:
            session.serve()
        finally:
            session.streaming = False
            with self._lock:
                self._sessions.remove(session)
                for name in [n for n, owner in self._owners.items() if owner is session]:
                    del self._owners[name]

    def on_cycle(self, snapshot: Snapshot) -> None:
        """Stream to every started session (controller cycle thread)."""
        if self.controller.streaming_frozen():
            return
        with self._lock:
            sessions = list(self._sessions)
        for session in sessions:
            session.send_data(snapshot)
