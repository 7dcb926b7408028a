"""Benchmark: does the fake scanner keep the UTM-30LX-EW rhythm, and what does a scan cost?

Run: ``.venv/bin/python -m benchmarks.fake_scanner_timing [--seconds 3]``

Prints, as ratios against references measured in the same run:
* the cost of building one ME scan message (full 1081 steps with intensities) relative
  to the 25 ms scan period and to the cost of decoding it with the codec;
* the physical scanner model's cost per scan (``fakes.world.World.scan_mm``, the fake
  cell's scanner; docs/scanner-model.md) while the rod moves (a new pose every scan: its
  beams are cast again) and at rest, on the default scene and on the drill scene (a fluted
  steel bit and its chuck), against the 25 ms period;
* the stream rhythm seen by a TCP client: sensor-timestamp period, host arrival period,
  arrival jitter and the drift of the last arrival against the absolute 25 ms schedule.
"""

from __future__ import annotations

import argparse
import itertools
import socket
import statistics
import time
from pathlib import Path

import numpy as np

from drivers.hokuyo import codec
from fakes.scan_scene import RoomScene
from fakes.scene import load_scene
from fakes.scip_device import SCAN_PERIOD_S, ScipDevice
from fakes.scip_server import FakeScannerServer
from fakes.world import World
from lasercal_hw.geometry import make_transform

DRILL_SCENE = Path(__file__).resolve().parent.parent / "fakes" / "scenes" / "drill.toml"


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


def physical_scan_costs_s(scene_path: Path | None, scans: int) -> tuple[list[float], list[float]]:
    """Seconds per ``World.scan_mm`` of the physical model with the rod moving along a path
    through the scan plane (0.25-0.95 m ahead, a new pose every scan), then at rest."""
    world = World(load_scene(scene_path))
    rng = np.random.default_rng(0)
    moving, still = [], []
    T = world.ground_truth_T_base_laser
    for k in range(scans):
        T = world.ground_truth_T_base_laser @ make_transform(
            np.eye(3), [0.25 + 0.7 * k / scans, 0.1 + 0.0003 * k, -0.15]
        )
        started = time.perf_counter()
        world.scan_mm(T, rng)
        moving.append(time.perf_counter() - started)
    for _ in range(scans):
        started = time.perf_counter()
        world.scan_mm(T, rng)
        still.append(time.perf_counter() - started)
    return moving, still


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
    for name, path in (("default scene", None), ("drill scene", DRILL_SCENE)):
        moving, still = physical_scan_costs_s(path, args.repeats)
        p50, p99 = np.percentile(moving, [50, 99])
        print(f"physical model, {name}: rod moving {1e3 * p50:.2f} ms median ({p50 / SCAN_PERIOD_S:.3f} of "
              f"the period), p99 {1e3 * p99:.2f} ms ({p99 / SCAN_PERIOD_S:.3f}); at rest "
              f"{1e3 * statistics.median(still):.2f} ms ({statistics.median(still) / SCAN_PERIOD_S:.3f})")
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
