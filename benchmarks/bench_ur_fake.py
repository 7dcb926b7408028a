"""Benchmark: the fake UR controller's RTDE stream to two clients.

Starts ``lasercal fake robot`` as a child process on a loopback address, opens two raw
RTDE connections with ur_rtde's default 5.11 receive recipe (58 variables, 500 Hz), reads
for ``--duration`` seconds and prints the achieved rate, the inter-arrival jitter
(|period - nominal|, p50/p99) and the fake process's CPU share from /proc/<pid>/stat.
As a reference measured in the same run, a plain absolute-deadline sleep loop at the
same rate runs in a process of its own; the fake's jitter is also printed as a ratio to
it. One thread reads both connections, so the two clients do not compete for the GIL.

    .venv/bin/python -m benchmarks.bench_ur_fake --duration 60 --address 127.0.0.90
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import selectors
import socket
import struct
import time
from multiprocessing.connection import Connection

import numpy as np

from fakes.ur_controller.process import RTDE_PORT
from tests.drivers.ur.robot_process import FakeRobotProcess

RECEIVE_RECIPE_5_11 = [
    "timestamp", "target_q", "target_qd", "target_qdd", "target_current", "target_moment", "actual_q",
    "actual_qd", "actual_current", "joint_control_output", "actual_TCP_pose", "actual_TCP_speed",
    "actual_TCP_force", "target_TCP_pose", "target_TCP_speed", "actual_digital_input_bits",
    "joint_temperatures", "actual_execution_time", "robot_mode", "joint_mode", "safety_mode",
    "actual_tool_accelerometer", "speed_scaling", "target_speed_fraction", "actual_momentum",
    "actual_main_voltage", "actual_robot_voltage", "actual_robot_current", "actual_joint_voltage",
    "actual_digital_output_bits", "runtime_state", "standard_analog_input0", "standard_analog_input1",
    "standard_analog_output0", "standard_analog_output1", "robot_status_bits", "safety_status_bits",
    "ft_raw_wrench", "payload", "payload_cog", "payload_inertia", "output_int_register_2",
    *[f"output_int_register_{k}" for k in range(12, 20)],
    *[f"output_double_register_{k}" for k in range(12, 20)],
]


def _read_message(sock: socket.socket) -> tuple[int, bytes]:
    header = _read_exact(sock, 3)
    size, kind = struct.unpack(">HB", header)
    return kind, _read_exact(sock, size - 3)


def _read_exact(sock: socket.socket, count: int) -> bytes:
    data = bytearray()
    while len(data) < count:
        chunk = sock.recv(count - len(data))
        if not chunk:
            raise ConnectionError("fake closed the RTDE connection")
        data += chunk
    return bytes(data)


def _request(sock: socket.socket, kind: str, payload: bytes = b"") -> bytes:
    sock.sendall(struct.pack(">HB", 3 + len(payload), ord(kind)) + payload)
    reply_kind, reply = _read_message(sock)
    if reply_kind != ord(kind):
        raise ConnectionError(f"expected a {kind!r} reply, got {chr(reply_kind)!r}")
    return reply


def open_stream(address: str, frequency_hz: float) -> socket.socket:
    """An RTDE connection with the 5.11 receive recipe set up and started."""
    sock = socket.create_connection((address, RTDE_PORT), timeout=5.0)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    _request(sock, "V", struct.pack(">H", 2))
    _request(sock, "v")
    names = ",".join(RECEIVE_RECIPE_5_11) + ","
    reply = _request(sock, "O", struct.pack(">d", frequency_hz) + names.encode())
    if b"NOT_FOUND" in reply:
        raise ConnectionError(f"recipe rejected: {reply!r}")
    _request(sock, "S")
    sock.setblocking(False)
    return sock


def read_streams(socks: list[socket.socket], duration_s: float) -> list[list[float]]:
    """Arrival time of every data package on each socket, read by one thread (so the
    clients do not compete for the GIL)."""
    arrivals: list[list[float]] = [[] for _ in socks]
    buffers = [bytearray() for _ in socks]
    with selectors.DefaultSelector() as selector:
        for index, sock in enumerate(socks):
            selector.register(sock, selectors.EVENT_READ, index)
        end = time.perf_counter() + duration_s
        while time.perf_counter() < end:
            for key, _ in selector.select(timeout=0.1):
                index = key.data
                chunk = socks[index].recv(65536)
                if not chunk:
                    raise ConnectionError("fake closed an RTDE connection")
                now = time.perf_counter()
                buffer = buffers[index]
                buffer += chunk
                while len(buffer) >= 3:
                    size, kind = struct.unpack_from(">HB", buffer)
                    if len(buffer) < size:
                        break
                    if kind == ord("U"):
                        arrivals[index].append(now)
                    del buffer[:size]
    return arrivals


def reference_sleep_loop(frequency_hz: float, duration_s: float, results: Connection) -> None:
    """The fake's absolute-deadline loop doing nothing, in a process of its own."""
    period = 1.0 / frequency_hz
    ticks: list[float] = []
    next_deadline = time.perf_counter()
    end = next_deadline + duration_s
    while next_deadline < end:
        next_deadline += period
        delay = next_deadline - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        ticks.append(time.perf_counter())
    results.send(ticks)
    results.close()


def cpu_seconds(pid: int) -> float:
    """utime + stime of a process (s)."""
    with open(f"/proc/{pid}/stat") as handle:
        fields = handle.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def jitter_ms(times: list[float], frequency_hz: float) -> tuple[float, float, float]:
    """Rate (Hz) and p50/p99 of |inter-arrival - period| (ms)."""
    stamps = np.array(times)
    deviation = np.abs(np.diff(stamps) - 1.0 / frequency_hz) * 1000.0
    rate = (len(stamps) - 1) / (stamps[-1] - stamps[0])
    return rate, float(np.percentile(deviation, 50)), float(np.percentile(deviation, 99))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--duration", type=float, default=60.0, help="seconds to stream (default 60)")
    parser.add_argument("--address", default="127.0.0.90", help="loopback address for the fake")
    parser.add_argument("--version", choices=["5.11", "3.15"], default="5.11",
                        help="controller the fake reports (3.15 streams at most 125 Hz)")
    parser.add_argument("--frequency", type=float, default=None,
                        help="requested rate (Hz; default 500, 125 for 3.15)")
    args = parser.parse_args()
    if args.frequency is None:
        args.frequency = 500.0 if args.version == "5.11" else 125.0

    with FakeRobotProcess(args.address, ["--version", args.version]) as fake:
        socks = [open_stream(args.address, args.frequency) for _ in range(2)]
        receiver, sender = multiprocessing.Pipe(duplex=False)
        reference_process = multiprocessing.Process(target=reference_sleep_loop,
                                                    args=(args.frequency, args.duration, sender))
        cpu_before, wall_before = cpu_seconds(fake.pid), time.perf_counter()
        reference_process.start()
        try:
            arrivals = read_streams(socks, args.duration)
        finally:
            for sock in socks:
                sock.close()
        cpu_share = (cpu_seconds(fake.pid) - cpu_before) / (time.perf_counter() - wall_before)
        reference = receiver.recv()
        reference_process.join()

    ref_rate, ref_p50, ref_p99 = jitter_ms(reference, args.frequency)
    print(f"fake UR {args.version} RTDE stream, {args.duration:g} s, 2 clients, "
          f"{len(RECEIVE_RECIPE_5_11)} variables, target {args.frequency:g} Hz")
    print(f"reference sleep loop (own process): {ref_rate:.1f} Hz, jitter p50 {ref_p50:.3f} ms, "
          f"p99 {ref_p99:.3f} ms")
    for k, times in enumerate(arrivals):
        rate, p50, p99 = jitter_ms(times, args.frequency)
        print(f"client {k + 1}: {rate:.1f} Hz ({rate / args.frequency:.3f} x target), "
              f"jitter p50 {p50:.3f} ms, p99 {p99:.3f} ms ({p99 / max(ref_p99, 1e-6):.2f} x reference p99)")
    print(f"fake process CPU: {cpu_share * 100:.1f} % of one core")


if __name__ == "__main__":
    main()
