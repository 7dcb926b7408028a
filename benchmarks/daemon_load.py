"""The daemon under load: ``GET /v1/status`` latency while a dry-run job streams (the fake
scanner at 40 Hz) and 20 clients follow its events; the daemon's CPU share; and the run's
overhead over motion and dwell beside the CLI's on the same scene and job.

Targets (issue 9): status p99 under 50 ms; the daemon's overhead no more than 1 percentage
point above the CLI's. Both runs are measured in the same invocation (the machine's load
moves both). The event followers run in another process, so their work does not slow the
latency probe.

    .venv/bin/python -m benchmarks.daemon_load [--preset quick] [--dwell 0.5] [--clients 20]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import httpx

from tests.daemon_helpers import DaemonProcess

TICKS_S = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    """User plus system CPU time of one process (not its children)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS_S


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q / 100 * (len(ordered) - 1)))]


def cli_run(root: Path, job_file: Path) -> dict[str, Any]:
    """``lasercal run --dry-run --json``: the reference."""
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "lasercal_hw.cli.main",
            "run",
            "--dry-run",
            "--json",
            "--config",
            str(job_file),
            "--out",
            str(root / "cli-out"),
        ],
        capture_output=True,
        text=True,
        stdin=subprocess.DEVNULL,
        check=False,
    )
    if result.returncode not in (0, 1):
        sys.exit(f"CLI dry run failed ({result.returncode}):\n{result.stderr[-2000:]}")
    return json.loads(result.stdout)


def follow(url: str, job_id: str, clients: int, results: Any) -> None:
    """``clients`` threads each reading the job's event stream to its end (another process)."""
    counts: list[int] = []

    def one() -> None:
        events = 0
        with (
            httpx.Client(base_url=url, timeout=120.0) as client,
            client.stream("GET", f"/v1/jobs/{job_id}/events") as stream,
        ):
            for line in stream.iter_lines():
                events += line.startswith("id: ")
        counts.append(events)

    threads = [threading.Thread(target=one) for _ in range(clients)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    results.put(counts)


def probe_status(client: httpx.Client, stop: threading.Event, period_s: float) -> list[float]:
    latencies_ms: list[float] = []
    while not stop.is_set():
        started = time.perf_counter()
        client.get("/v1/status").raise_for_status()
        latencies_ms.append(1000 * (time.perf_counter() - started))
        time.sleep(period_s)
    return latencies_ms


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="quick")
    parser.add_argument("--dwell", type=float, default=0.5)
    parser.add_argument("--clients", type=int, default=20)
    parser.add_argument("--probe-period", type=float, default=0.05, help="s between status requests")
    args = parser.parse_args()
    # Both runs take the same job; the acquisition settings ride out the scan gaps of a loaded machine.
    job = {
        "trajectory": {"preset": args.preset},
        "dwell_s": args.dwell,
        "motion": {"joint_speed_rad_s": 1.2, "joint_accel_rad_s2": 3.0},
        "acquisition": {"max_missed_scans": 10000, "max_attempts": 10},
    }
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder)
        job_file = root / "job.toml"
        job_file.write_text(
            f'dwell_s = {args.dwell}\n[trajectory]\npreset = "{args.preset}"\n'
            "[motion]\njoint_speed_rad_s = 1.2\njoint_accel_rad_s2 = 3.0\n"
            "[acquisition]\nmax_missed_scans = 10000\nmax_attempts = 10\n"
        )
        print(f"CLI dry run ({args.preset}, dwell {args.dwell} s) ...", flush=True)
        cli = cli_run(root, job_file)

        daemon = DaemonProcess(root / "data").start()
        url, pid = daemon.url, daemon.pid
        try:
            with daemon.client() as client:
                stop = threading.Event()
                idle_cpu0, idle_t0 = cpu_s(pid), time.monotonic()
                idle: list[float] = []
                idle_thread = threading.Thread(target=lambda: idle.extend(probe_status(client, stop, 0.05)))
                idle_thread.start()
                time.sleep(5.0)
                stop.set()
                idle_thread.join()
                idle_cpu_share = (cpu_s(pid) - idle_cpu0) / (time.monotonic() - idle_t0)

                print(f"daemon dry run with {args.clients} event followers ...", flush=True)
                cpu0, t0 = cpu_s(pid), time.monotonic()
                job_id = (
                    client.post("/v1/jobs", json={"kind": "dry_run", "confirm_motion": True, "job": job})
                    .raise_for_status()
                    .json()["id"]
                )
                results: Any = multiprocessing.Queue()
                followers = multiprocessing.Process(target=follow, args=(url, job_id, args.clients, results))
                followers.start()
                stop = threading.Event()
                busy: list[float] = []
                probe = threading.Thread(
                    target=lambda: busy.extend(probe_status(client, stop, args.probe_period))
                )
                probe.start()
                while client.get(f"/v1/jobs/{job_id}").json()["state"] not in (
                    "succeeded",
                    "failed",
                    "cancelled",
                    "interrupted",
                ):
                    time.sleep(0.5)
                wall_s = time.monotonic() - t0
                job_cpu_share = (cpu_s(pid) - cpu0) / wall_s
                stop.set()
                probe.join()
                counts = results.get(timeout=60)
                followers.join()
                finished = client.get(f"/v1/jobs/{job_id}").json()
        finally:
            daemon.stop()
    if finished["state"] != "succeeded":
        sys.exit(f"daemon job ended {finished['state']}: {finished['error']}")
    d_t, c_t = finished["document"]["timings"], cli["timings"]
    cores = os.cpu_count() or 1
    print(
        f"\nGET /v1/status idle:  p50 {statistics.median(idle):.1f} ms, p99 {percentile(idle, 99):.1f} ms "
        f"({len(idle)} requests)"
    )
    print(
        f"GET /v1/status busy:  p50 {statistics.median(busy):.1f} ms, p99 {percentile(busy, 99):.1f} ms, "
        f"max {max(busy):.1f} ms ({len(busy)} requests; target p99 < 50 ms)"
    )
    print(
        f"event followers: {len(counts)} clients, events each min {min(counts)} max {max(counts)} "
        f"(all equal: {len(set(counts)) == 1})"
    )
    print(
        f"daemon CPU: idle {100 * idle_cpu_share:.1f} % of one core; during the job "
        f"{100 * job_cpu_share:.1f} % of one core ({100 * job_cpu_share / cores:.1f} % of {cores} cores; "
        "the engine runs inside the daemon, the fake cell does not)"
    )
    for name, t in (("CLI   ", c_t), ("daemon", d_t)):
        print(
            f"{name} run: wall {t['wall_s']:.1f} s, overhead over motion+dwell "
            f"{100 * t['overhead_fraction']:.2f} %, "
            f"with connect/outputs {100 * t['overhead_fraction_with_io']:.2f} %"
        )
    delta_pp = 100 * (d_t["overhead_fraction"] - c_t["overhead_fraction"])
    delta_io_pp = 100 * (d_t["overhead_fraction_with_io"] - c_t["overhead_fraction_with_io"])
    print(
        f"daemon minus CLI: {delta_pp:+.2f} percentage points ({delta_io_pp:+.2f} with connect/outputs; "
        "target <= +1)"
    )


if __name__ == "__main__":
    main()
