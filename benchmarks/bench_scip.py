"""SCIP driver benchmarks (not collected by pytest).

1. ``decode``: decode one full ME scan (1081 steps, distance + intensity, 102 data
   lines) from the real UTM-30LX capture with the vectorised codec and with a plain
   per-character Python decoder written here, in the same run; prints the speed ratio.
2. ``stream``: stream ME scans at 40 Hz from the fake scanner running in a separate
   process; prints received/dropped scans and the CPU share of this (client) process.

    .venv/bin/python -m benchmarks.bench_scip decode
    .venv/bin/python -m benchmarks.bench_scip stream --duration 30 [--link pty]
"""

from __future__ import annotations

import argparse
import base64
import os
import subprocess
import sys
import time
import timeit
from pathlib import Path

import numpy as np

from drivers.hokuyo.client import HokuyoScanner
from drivers.hokuyo.codec import ResponseFramer, decode_scan_lines, parse_scan_request

CAPTURE = Path(__file__).resolve().parent.parent / "tests" / "data" / "scip" / "utm30lx_read.b64"


def plain_python_decode(data_lines: list[bytes]) -> tuple[int, list[int], list[int]]:
    """Reference decoder: check every line's sum and decode char by char in pure Python."""
    timestamp_line = data_lines[0]
    if chr((sum(timestamp_line[:4]) & 0x3F) + 0x30) != chr(timestamp_line[4]):
        raise ValueError("timestamp checksum")
    timestamp = 0
    for char in timestamp_line[:4]:
        timestamp = (timestamp << 6) | (char - 0x30)
    payload = []
    for line in data_lines[1:]:
        total = 0
        for char in line[:-1]:
            total += char
        if (total & 0x3F) + 0x30 != line[-1]:
            raise ValueError("data line checksum")
        payload.extend(line[:-1])
    values = []
    for start in range(0, len(payload), 3):
        value = 0
        for char in payload[start : start + 3]:
            value = (value << 6) | (char - 0x30)
        values.append(value)
    return timestamp, values[0::2], values[1::2]


def bench_decode(repeat: int) -> None:
    stream = base64.b64decode("".join(CAPTURE.read_text().split()))
    message = ResponseFramer().feed(stream)[-1]
    request = parse_scan_request(message.echo)
    lines = list(message.data_lines)

    vectorised = decode_scan_lines(lines, request)
    timestamp, distances, intensities = plain_python_decode(lines)
    assert timestamp == vectorised.timestamp_ms
    assert distances == vectorised.distances_mm.tolist()
    assert intensities == vectorised.intensities.tolist()  # type: ignore[union-attr]

    number = 200
    fast = (
        min(timeit.repeat(lambda: decode_scan_lines(lines, request), number=number, repeat=repeat)) / number
    )
    slow = min(timeit.repeat(lambda: plain_python_decode(lines), number=number // 10, repeat=repeat)) / (
        number // 10
    )
    print(f"ME scan, {len(distances)} steps with intensities, {len(lines) - 1} data lines")
    print(f"  vectorised codec (checksums + numpy decode): {fast * 1e6:8.1f} us per scan")
    print(f"  plain Python per-character decoder:          {slow * 1e6:8.1f} us per scan")
    print(f"  speed-up: {slow / fast:.1f}x")


def start_fake(link: str) -> tuple[subprocess.Popen[str], str]:
    command = [sys.executable, "-m", "lasercal_hw.cli.main", "fake", "scanner", "--listen", "127.0.0.1:0"]
    if link == "pty":
        command.append("--pty")
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True)
    assert process.stdout is not None
    url = process.stdout.readline().strip()
    if not url.startswith("scip+"):
        process.kill()
        raise SystemExit(f"the fake scanner did not start (printed {url!r})")
    return process, url


def process_cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def bench_stream(duration_s: float, link: str) -> None:
    fake, url = start_fake(link)
    try:
        with HokuyoScanner.open(url) as scanner:
            scanner.start_streaming(intensities=True)
            wall_start, cpu_start = time.monotonic(), time.process_time()
            fake_cpu_start = process_cpu_s(fake.pid)
            lags: list[float] = []
            count = 0
            first_sequence = last_sequence = -1
            while time.monotonic() - wall_start < duration_s:
                scan = scanner.next_scan(2.0)
                lags.append(scan.host_time_s - scan.device_time_s)
                first_sequence = scan.sequence if count == 0 else first_sequence
                last_sequence = scan.sequence
                count += 1
            wall = time.monotonic() - wall_start
            cpu = time.process_time() - cpu_start
            fake_cpu = process_cpu_s(fake.pid) - fake_cpu_start
            scanner.stop_streaming()
            stats = scanner.stream_stats()
            clock = scanner.clock()
    finally:
        fake.terminate()
        fake.wait(10)
    lag_ms = 1000 * np.array(lags)
    expected = wall / 0.025
    print(f"stream over {link}: {wall:.1f} s, ME 1081 steps with intensities")
    not_sent = last_sequence - first_sequence + 1 - count - scanner.dropped_scans()
    print(
        f"  scans consumed {count} (expected ~{expected:.0f} at 40 Hz), received {stats.received}, "
        f"scan periods the fake did not send (stalls) {not_sent}"
    )
    print(
        f"  dropped {scanner.dropped_scans()} (queue overflow {stats.queue_overflows}, corrupted "
        f"{stats.corrupted}), reconnects {stats.reconnects}"
    )
    print(
        f"  client process CPU {cpu:.2f} s = {100 * cpu / wall:.1f} % of one core "
        f"({1000 * cpu / max(count, 1):.2f} ms per scan); fake process {100 * fake_cpu / wall:.1f} %"
    )
    print(
        f"  host receive - device stamp: median {np.median(lag_ms):.1f} ms, p99 "
        f"{np.percentile(lag_ms, 99):.1f} ms; clock drift estimate {clock.drift * 1e6:.1f} ppm"
    )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="what", required=True)
    decode = sub.add_parser("decode", help="vectorised vs. plain Python decode of one ME scan")
    decode.add_argument("--repeat", type=int, default=5)
    stream = sub.add_parser("stream", help="40 Hz ME stream from the fake in another process")
    stream.add_argument("--duration", type=float, default=30.0, help="seconds (the issue asks for 600)")
    stream.add_argument("--link", choices=("tcp", "pty"), default="tcp")
    args = parser.parse_args()
    if args.what == "decode":
        bench_decode(args.repeat)
    else:
        bench_stream(args.duration, args.link)


if __name__ == "__main__":
    main()
