"""Recorder throughput: how many scans per second session.mcap can take and give back,
as ratios against a plain-file reference measured in the same run.

    .venv/bin/python -m benchmarks.recorder_bench [--scans 2000]

Reference: each scan's raw values (int32 ranges and intensities, float64 times) appended to
a plain file with a flush per scan, read back with numpy. The recorder must stay far above
the scanner's 40 Hz while it also writes the ROS views and compresses.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lasercal_hw.session.reader import read_session
from lasercal_hw.session.recorder import SessionRecorder
from tests.recorder_helpers import make_scan

SCANNER_RATE_HZ = 40.0


def reference_write(path: Path, scans) -> float:
    start = time.perf_counter()
    with open(path, "wb") as stream:
        for scan in scans:
            stream.write(np.asarray([scan.host_time_s, scan.device_time_s]).tobytes())
            stream.write(scan.raw_ranges_mm.astype("<i4").tobytes())
            stream.write(scan.intensities.astype("<i4").tobytes())
            stream.flush()
    return time.perf_counter() - start


def reference_read(path: Path, beams: int) -> float:
    start = time.perf_counter()
    record = np.dtype([("times", "<f8", 2), ("raw", "<i4", beams), ("intensities", "<i4", beams)])
    np.fromfile(path, dtype=record)["raw"].astype(np.int64)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=2000)
    count = parser.parse_args().scans
    scans = [make_scan(i % 50) for i in range(count)]
    with tempfile.TemporaryDirectory() as tmp:
        ref_path, mcap_path = Path(tmp) / "ref.bin", Path(tmp) / "session.mcap"
        ref_write_s = reference_write(ref_path, scans)
        start = time.perf_counter()
        with SessionRecorder(mcap_path, {"bench": True}) as recorder:
            for scan in scans:
                recorder.write_scan(scan)
        write_s = time.perf_counter() - start
        ref_read_s = reference_read(ref_path, scans[0].geometry.beam_count)
        start = time.perf_counter()
        recording = read_session(mcap_path)
        read_s = time.perf_counter() - start
        assert len(recording.scans) == count
        ref_bytes, mcap_bytes = ref_path.stat().st_size, mcap_path.stat().st_size

    print(f"scans: {count} x {scans[0].geometry.beam_count} beams with intensities")
    print(f"write: {write_s / count * 1e3:.3f} ms/scan = {count / write_s:.0f} scans/s "
          f"= {count / write_s / SCANNER_RATE_HZ:.0f}x the scanner's 40 Hz; "
          f"{write_s / ref_write_s:.1f}x the plain-file reference")
    print(f"read:  {read_s / count * 1e3:.3f} ms/scan = {count / read_s:.0f} scans/s; "
          f"{read_s / ref_read_s:.0f}x the plain-file reference")
    print(f"size:  {mcap_bytes / count:.0f} bytes/scan = {mcap_bytes / ref_bytes:.2f}x the raw values")


if __name__ == "__main__":
    main()
