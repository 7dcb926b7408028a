"""Cost of one cycle of the fake UR controller (the 500 Hz ``step`` and its RTDE streaming),
with the two RTDE clients a dry run's driver opens (ur_rtde 1.6.5's receive and control
recipes, 500 Hz each), at rest and during a moveJ and a moveL.

Run: .venv/bin/python -m benchmarks.fake_cycle [--cycles 3000] [--profile]

The cycles are driven one by one in this thread (no cycle thread, no sleeping); the RTDE
sessions serve in threads of their own over socket pairs, as on the real port, and sit
idle in ``recv`` while the cycles run. Printed per phase: the cycle's cost (median and
mean of step + streaming, microseconds), its ratio to a reference measured in the same
run (``struct.pack`` of the same two data packages from ready values: what streaming the
state costs at the least), and the share of one core it takes at 500 Hz (mean x 500).
``--profile``: each phase once more under cProfile, the functions that cost the most.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import socket
import statistics
import struct
import threading
import time

import numpy as np

from benchmarks.bench_ur_fake import RECEIVE_RECIPE_5_11
from fakes.ur_controller import rtde_protocol as rp
from fakes.ur_controller.controller import FakeController
from fakes.ur_controller.rtde_server import RtdeServer

#: What ur_rtde 1.6.5's RTDEControlInterface subscribes on a 5.11 controller (captured).
CONTROL_RECIPE_5_11 = [
    "timestamp", "robot_status_bits", "safety_status_bits", "runtime_state",
    "output_int_register_0", "output_int_register_1", "output_int_register_2",
    *[f"output_double_register_{k}" for k in range(6)],
]
CYCLE_HZ = 500.0
DT_S = 1.0 / CYCLE_HZ
PHASES = ("rest", "moveJ", "moveL")


class Clients:
    """Two RTDE clients subscribed at 500 Hz over socket pairs, their sessions served by
    the fake's ``RtdeServer`` in threads of their own; ``drain`` reads what arrived."""

    def __init__(self, server: RtdeServer, recipes: list[list[str]]) -> None:
        self.socks: list[socket.socket] = []
        for names in recipes:
            fake_end, client_end = socket.socketpair()
            threading.Thread(target=server.serve, args=(fake_end,), daemon=True).start()
            self._request(client_end, rp.CONTROL_PACKAGE_SETUP_OUTPUTS,
                          struct.pack(">d", CYCLE_HZ) + ",".join(names).encode())
            self._request(client_end, rp.CONTROL_PACKAGE_START)
            client_end.setblocking(False)
            self.socks.append(client_end)

    @staticmethod
    def _request(sock: socket.socket, kind: int, payload: bytes = b"") -> None:
        sock.sendall(rp.encode_message(kind, payload))
        size, reply_kind = struct.unpack(">HB", sock.recv(3, socket.MSG_WAITALL))
        reply = sock.recv(size - 3, socket.MSG_WAITALL)
        if reply_kind != kind or not reply.startswith(b"\x01"):
            raise RuntimeError(f"RTDE request {chr(kind)!r} refused: {reply!r}")

    def drain(self) -> int:
        """Bytes received since the last drain."""
        received = 0
        for sock in self.socks:
            try:
                while chunk := sock.recv(1 << 20):
                    received += len(chunk)
            except BlockingIOError:
                pass
        return received


def _move(controller: FakeController, phase: str, count: int) -> None:
    """Start the next move of a phase: back and forth by 0.3 rad or 0.1 m."""
    with controller.lock:
        if phase == "moveJ":
            q = np.array(controller.config.start_q_rad) + (0.3 if count % 2 else 0.0)
            controller.start_joint_move(q, 1.0, 2.0)
        else:
            pose = controller.tcp_pose()
            pose[0] += 0.1 if count % 2 else -0.1
            controller.start_linear_move(pose, 0.25, 1.0)


def run_phase(phase: str, cycles: int) -> list[int]:
    """Nanoseconds of each cycle (step + tick listeners) of a fresh controller."""
    controller = FakeController()
    clients = Clients(RtdeServer(controller), [RECEIVE_RECIPE_5_11, CONTROL_RECIPE_5_11])
    controller.load_program("rtde_control", "")
    moves = 0
    costs: list[int] = []
    for _ in range(cycles):
        if phase != "rest" and not controller.motion_active():
            moves += 1
            _move(controller, phase, moves)
        started = time.perf_counter_ns()
        controller.cycle(DT_S)
        costs.append(time.perf_counter_ns() - started)
        if not clients.drain():
            raise RuntimeError("the fake streamed nothing this cycle")
    return costs


def reference_ns(cycles: int) -> float:
    """Median ns of packing both recipes' data packages from ready values."""
    packings = []
    for names in (RECEIVE_RECIPE_5_11, CONTROL_RECIPE_5_11):
        types, _ = rp.resolve(names, rp.output_type)
        packer = rp.data_package_struct(rp.Recipe(names, types))
        scalars = len(packer.unpack(bytes(packer.size)))
        packings.append((packer, (packer.size, rp.DATA_PACKAGE, 1, *[0] * (scalars - 3))))
    costs = []
    for _ in range(cycles):
        started = time.perf_counter_ns()
        for packer, values in packings:
            packer.pack(*values)
        costs.append(time.perf_counter_ns() - started)
    return statistics.median(costs)


def profile(phase: str, cycles: int, top: int = 12) -> None:
    """The functions a phase spends its time in (cProfile, by own time)."""
    profiler = cProfile.Profile()
    profiler.runcall(run_phase, phase, cycles)
    print(f"--- {phase}: cProfile, top {top} by own time (includes the client side's set-up and drain)")
    pstats.Stats(profiler).sort_stats("tottime").print_stats(top)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cycles", type=int, default=3000, help="cycles per phase (default 3000)")
    parser.add_argument("--profile", action="store_true", help="also profile each phase")
    args = parser.parse_args()
    reference = reference_ns(args.cycles)
    print(f"fake UR cycle, {args.cycles} cycles per phase, 2 RTDE clients at {CYCLE_HZ:g} Hz "
          f"({len(RECEIVE_RECIPE_5_11)} + {len(CONTROL_RECIPE_5_11)} variables)")
    print(f"reference (struct.pack of both packages): {reference / 1e3:.1f} us")
    for phase in PHASES:
        costs = run_phase(phase, args.cycles)
        median, mean = statistics.median(costs), statistics.fmean(costs)
        print(f"{phase:>5}: median {median / 1e3:7.1f} us, mean {mean / 1e3:7.1f} us "
              f"({median / reference:5.1f} x reference), {mean * CYCLE_HZ / 1e7:5.1f} % of a core at "
              f"{CYCLE_HZ:g} Hz")
    if args.profile:
        for phase in PHASES:
            profile(phase, args.cycles)


if __name__ == "__main__":
    main()
