"""Benchmark: does the fake scanner keep the UTM-30LX-EW rhythm, and what does a scan cost?

Run: ``.venv/bin/python benchmarks/fake_scanner_timing.py [--seconds 3]``

Prints, as ratios against references measured in the same run:
* the cost of building one ME scan message (full 1081 steps with intensities) relative
  to the 25 ms scan period and to the cost of decoding it with the codec;
* the stream rhythm seen by a TCP client: sensor-timestamp period, host arrival period,
  arrival jitter and the drift of the last arrival against the absolute 25 ms schedule.
"""

from __future__ import annotations

import argparse
import itertools
import socket
import statistics
import time

from drivers.hokuyo import codec
from fakes.scan_scene import RoomScene
from fakes.scip_device import SCAN_PERIOD_S, ScipDevice
from fakes.scip_server import FakeScannerServer


def build_cost_s(repeats: int) -> tuple[float, float]:
    """Median seconds to build one ME message, and to decode it."""
    device = ScipDevice(RoomScene(noise_mm=10.0))
    device.handle(b"ME0000108001000", 0.0)
    build, decode = [], []
    request = codec.parse_scan_request(b"ME0000108001000")
    for k in range(1, repeats + 1):
        started = time.perf_counter()
        message = device.complete_scan(device.scan_start_s(k))
        build.append(time.perf_counter() - started)
        assert message is not None
        lines = message[:-2].split(b"\n")
        started = time.perf_counter()
        codec.decode_scan_lines(lines[2:], request)
        decode.append(time.perf_counter() - started)
    return statistics.median(build), statistics.median(decode)


def stream_rhythm(seconds: float) -> dict[str, float]:
    """Stream ME over TCP for ``seconds``; arrival and timestamp statistics."""
    with FakeScannerServer(reply_timing="immediate") as server:
        host, port = server.url.removeprefix("scip+tcp://").rsplit(":", 1)
        with socket.create_connection((host, int(port)), timeout=5.0) as sock:
            framer = codec.ResponseFramer()
            sock.sendall(b"ME0000108001000\n")
            arrivals: list[float] = []
            stamps: list[int] = []
            deadline = time.monotonic() + seconds
            while time.monotonic() < deadline:
                data = sock.recv(1 << 16)
                now = time.monotonic()
                for message in framer.feed(data):
                    if message.status == b"99":
                        arrivals.append(now)
                        stamps.append(codec.decode_timestamp_line(message.data_lines[0]))
            sock.sendall(b"QT\n")
    periods = [b - a for a, b in itertools.pairwise(arrivals)]
    expected_span = (len(arrivals) - 1) * SCAN_PERIOD_S
    return {
        "scans": float(len(arrivals)),
        "stamp_period_ms": (stamps[-1] - stamps[0]) / (len(stamps) - 1),
        "arrival_period_ms": 1000.0 * statistics.mean(periods),
        "arrival_jitter_ms": 1000.0 * statistics.pstdev(periods),
        "worst_arrival_gap_ms": 1000.0 * max(periods),
        "drift_ms": 1000.0 * ((arrivals[-1] - arrivals[0]) - expected_span),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--repeats", type=int, default=200)
    args = parser.parse_args()
    build_s, decode_s = build_cost_s(args.repeats)
    print(f"ME scan build: {1e3 * build_s:.3f} ms = {build_s / SCAN_PERIOD_S:.3f} of the 25 ms period, "
          f"{build_s / decode_s:.2f}x the codec's decode time ({1e3 * decode_s:.3f} ms)")
    rhythm = stream_rhythm(args.seconds)
    period_ms = 1000.0 * SCAN_PERIOD_S
    print(f"stream over TCP: {rhythm['scans']:.0f} scans in {args.seconds:g} s")
    print(f"  sensor timestamp period {rhythm['stamp_period_ms']:.3f} ms "
          f"(ratio {rhythm['stamp_period_ms'] / period_ms:.4f})")
    print(f"  host arrival period {rhythm['arrival_period_ms']:.3f} ms "
          f"(ratio {rhythm['arrival_period_ms'] / period_ms:.4f}), "
          f"jitter {rhythm['arrival_jitter_ms']:.3f} ms "
          f"({rhythm['arrival_jitter_ms'] / period_ms:.3f} of a period), worst gap "
          f"{rhythm['worst_arrival_gap_ms']:.2f} ms")
    print(f"  drift of the last arrival vs the absolute schedule: {rhythm['drift_ms']:+.3f} ms "
          f"({rhythm['drift_ms'] / period_ms:+.4f} periods)")


if __name__ == "__main__":
    main()
