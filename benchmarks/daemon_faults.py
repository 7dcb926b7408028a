"""The daemon under faults, repeated (issue 21): the long runs the fault suite does once or
not at all, against real ``lasercal serve --dry-run`` processes on loopback. Not collected
by pytest.

Run from the repository root (as root for the full-disk rows: a tmpfs is mounted)::

    .venv/bin/python -m benchmarks.daemon_faults [--repeat 3] [--only hostile,kill9]

Rows:

* ``hostile``: every request of ``tests/hostile_inputs.py`` (bad inputs, file paths, sizes,
  ids, Host headers, token variants) over a real socket; clean = its status and JSON code.
* ``kill9 <state>``: a dry run killed with SIGKILL once it is in ``preflight``, ``running``
  or ``solving``, then the daemon restarted; clean = the job ``interrupted`` (or finished if
  it got there first), its recording readable; lost = the job or an earlier calibration
  missing after the restart.
* ``sigterm``: SIGTERM during a followed dry run; clean = the follower's last event is the
  ``interrupted`` state.
* ``full disk``: a dry run on a 3 MB tmpfs; clean = ``failed``/``storage_full`` sent to the
  follower, a 507 JSON for the next job, a 202 once space is freed.
* ``damaged history <kind>``: each damage of ``tests/fault_helpers.DAMAGES``; clean = the start
  refused in one line and ``--rebuild-history`` giving back every calibration.
* ``fake cell killed``: the dry-run daemon's idle cell killed; clean = a new cell served.

Printed: a table of cases tried, clean, other (a 4xx other than the expected one: uvicorn
itself answers a malformed Content-Length with a plain-text 400 before the app sees it), 500
(a 5xx answer, a traceback or a harness error), hang (no answer or end within its time) and
lost (data missing or leaked afterwards).
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx

from lasercal_hw.service.store import DB_FILE
from lasercal_hw.session.reader import read_session
from tests.daemon_helpers import QUICK_DRY_RUN, DaemonProcess, read_sse
from tests.fault_helpers import DAMAGES, FILLER_BYTES, child_pids, follow_to_the_end, small_disk
from tests.hostile_inputs import CASES, SECRET, Hostile, send

FINISHED = ("succeeded", "failed", "cancelled", "interrupted")
OUTCOMES = ("clean", "other", "500", "hang", "lost")


@dataclass
class Row:
    """One row of the table."""

    name: str
    counts: dict[str, int]

    def add(self, outcome: str) -> None:
        self.counts[outcome] = self.counts.get(outcome, 0) + 1


def _poll(
    client: httpx.Client, job_id: str, done: Callable[[dict[str, Any]], bool], timeout_s: float
) -> dict[str, Any] | None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job_id}").json()
        if done(job):
            return job
        time.sleep(0.05)
    return None


def _follow(url: str, job_id: str, into: list[tuple[int, str, dict[str, Any]]]) -> threading.Thread:
    def follow() -> None:
        with httpx.stream("GET", f"{url}/v1/jobs/{job_id}/events", timeout=120.0) as stream:
            into.extend(read_sse(stream))

    thread = threading.Thread(target=follow, daemon=True)
    thread.start()
    return thread


def hostile(root: Path, row: Row) -> None:
    outside = root / "outside"
    outside.mkdir()
    (outside / "secret.csv").write_text(f"index,x,y,z,rx,ry,rz\n0,{SECRET},0,0,0,0,0\n")
    daemon = DaemonProcess(root / "data").start()
    try:
        with daemon.client() as client:
            job = client.post("/v1/jobs", json=QUICK_DRY_RUN | {"dwell_s": 0.2}).json()
            job = _poll(client, job["id"], lambda j: j["state"] in FINISHED, 300.0) or job
            names = {
                "job": job["id"],
                "cal": str(job.get("calibration_id")),
                "outside": str(outside),
                "token": daemon.token,
                "token_prefix": daemon.token[:-1],
            }
            for case in CASES:
                try:
                    status, text = _answer(client, daemon.url, case, names)
                except (httpx.TimeoutException, TimeoutError):
                    row.add("hang")
                    continue
                if status >= 500:
                    row.add("500")
                elif status == case.status and f'"code":"{case.code}"' in text and SECRET not in text:
                    row.add("clean")
                else:
                    print(f"  {case.name}: {status} {text[:200]}")
                    row.add("lost" if SECRET in text else "other")
    finally:
        daemon.stop()


def _answer(client: httpx.Client, url: str, case: Hostile, names: dict[str, str]) -> tuple[int, str]:
    """Status and body of one case; one httpx will not send (a bad Content-Length) goes
    over a raw socket."""
    try:
        answer = send(client, case, names)
        return answer.status_code, answer.text
    except httpx.LocalProtocolError:
        host, port = url.removeprefix("http://").split(":")
        head = [f"{case.method} {case.path} HTTP/1.1", f"Host: {host}:{port}", "Connection: close"]
        head += [f"{key}: {value}" for key, value in case.headers.items()]
        with socket.create_connection((host, int(port)), timeout=30.0) as connection:
            connection.sendall(("\r\n".join(head) + "\r\n\r\n").encode("latin-1") + (case.content or b""))
            reply = b""
            while chunk := connection.recv(65536):
                reply += chunk
        status_line, _, rest = reply.decode("latin-1").partition("\r\n")
        return int(status_line.split()[1]), rest.partition("\r\n\r\n")[2]


def kill9(root: Path, row: Row, state: str) -> None:
    data_dir = root / "data"
    daemon = DaemonProcess(data_dir).start()
    try:
        with daemon.client() as client:
            calibrations = len(client.get("/v1/calibrations").json()["calibrations"])
            job_id = client.post("/v1/jobs", json=QUICK_DRY_RUN).json()["id"]
            reached = _poll(client, job_id, lambda j: j["state"] in (state, *FINISHED), 300.0)
        daemon.kill()
    finally:
        daemon.stop()
    if reached is None:
        row.add("hang")
        return
    again = DaemonProcess(data_dir).start()
    try:
        with again.client() as client:
            answer = client.get(f"/v1/jobs/{job_id}")
            after = len(client.get("/v1/calibrations").json()["calibrations"])
        if answer.status_code != 200 or after < calibrations:
            row.add("lost")
            return
        job = answer.json()
        session = data_dir / "jobs" / job_id / "session.mcap"
        readable = not session.exists() or read_session(session, include_scans=False) is not None
        row.add("clean" if job["state"] in FINISHED and readable else "lost")
    finally:
        again.stop()


def sigterm(root: Path, row: Row) -> None:
    daemon = DaemonProcess(root / "data").start()
    try:
        with daemon.client() as client:
            job_id = client.post("/v1/jobs", json=QUICK_DRY_RUN).json()["id"]
            followed: list[tuple[int, str, dict[str, Any]]] = []
            follower = _follow(daemon.url, job_id, followed)
            _poll(client, job_id, lambda j: j["progress"]["completed"] >= 1 or j["state"] in FINISHED, 300.0)
        assert daemon.process is not None
        daemon.process.send_signal(signal.SIGTERM)
        follower.join(30.0)
        if follower.is_alive():
            row.add("hang")
        elif followed and followed[-1][1] == "state" and followed[-1][2]["state"] in FINISHED:
            row.add("clean")
        else:
            row.add("lost")
    finally:
        daemon.stop()


def full_disk(root: Path, row: Row) -> None:
    with small_disk(root / "small") as disk:
        if disk.how != "tmpfs":
            print("  full disk: mount refused; using RLIMIT_FSIZE (no 507/recovery check)")
        else:
            disk.filler.write_bytes(b"\0" * FILLER_BYTES)
        daemon = DaemonProcess(disk.root / "data", file_size_limit_bytes=disk.file_size_limit_bytes).start()
        try:
            with daemon.client() as client:
                job_id = client.post("/v1/jobs", json=QUICK_DRY_RUN).json()["id"]
                try:
                    job, followed = follow_to_the_end(client, job_id)
                except httpx.TimeoutException:
                    row.add("hang")
                    return
                ok = job["error"] is not None and job["error"]["code"] == "storage_full"
                ok = ok and bool(followed) and followed[-1][2].get("state") == "failed"
                if not ok:
                    print(f"  full disk: {job['state']} {job['error']}, last event {followed[-1:]}")
                if disk.how == "tmpfs":
                    refused = client.post("/v1/jobs", json=QUICK_DRY_RUN)
                    if refused.status_code >= 500 and refused.status_code != 507:
                        row.add("500")
                        return
                    disk.filler.unlink()
                    again = client.post("/v1/jobs", json=QUICK_DRY_RUN)
                    if refused.status_code != 507 or again.status_code != 202:
                        print(f"  full disk: then {refused.status_code}, after freeing {again.status_code}")
                    ok = ok and refused.status_code == 507 and again.status_code == 202
                    if again.status_code == 202:
                        client.post(f"/v1/jobs/{again.json()['id']}/cancel")
                        _poll(client, again.json()["id"], lambda j: j["state"] in FINISHED, 120.0)
                row.add("clean" if ok else "lost")
        finally:
            daemon.stop()


def damaged_history(root: Path, row: Row, damage: str, template: Path) -> None:
    data_dir = root / "data"
    shutil.copytree(template, data_dir)
    harm, says = DAMAGES[damage]
    harm(data_dir / DB_FILE)
    serve = [sys.executable, "-m", "lasercal_hw.cli.main", "serve", "--data-dir", str(data_dir)]
    try:
        start = subprocess.run(
            [*serve, "--listen", "127.0.0.1:0"], capture_output=True, text=True, timeout=60
        )
        rebuilt = subprocess.run([*serve, "--rebuild-history"], capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        row.add("hang")
        return
    if "Traceback" in start.stderr + rebuilt.stderr:
        row.add("500")
    elif start.returncode == 0 or says not in start.stderr or rebuilt.returncode != 0:
        row.add("lost")
    else:
        calibrations = len(list((data_dir / "jobs").glob("*/result.json")))
        row.add("clean" if f"{calibrations} calibrations" in rebuilt.stdout else "lost")


def history_template(root: Path) -> Path:
    """A data folder with two finished dry runs, for the damaged-history rows to copy."""
    daemon = DaemonProcess(root / "template").start()
    try:
        with daemon.client() as client:
            for _ in range(2):
                job_id = client.post("/v1/jobs", json=QUICK_DRY_RUN | {"activate_on_pass": True}).json()["id"]
                _poll(client, job_id, lambda j: j["state"] in FINISHED, 300.0)
    finally:
        daemon.stop()
    return root / "template"


def fake_cell_killed(root: Path, row: Row) -> None:
    daemon = DaemonProcess(root / "data").start()
    try:
        with daemon.client() as client:
            before = client.get("/v1/status").json()["robot"]["host"]
            cells = [
                pid
                for pid in child_pids(daemon.pid)
                if b"fakes.cell" in Path(f"/proc/{pid}/cmdline").read_bytes()
            ]
            os.kill(cells[0], signal.SIGKILL)
            deadline = time.monotonic() + 60.0
            while time.monotonic() < deadline:
                robot = client.get("/v1/status").json()["robot"]
                if robot["host"] != before and robot["connected"]:
                    row.add("clean")
                    return
                time.sleep(0.3)
            row.add("hang")
    finally:
        daemon.stop()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs of each long case")
    parser.add_argument(
        "--only", default="", help="comma-separated rows: hostile,kill9,sigterm,disk,history,cell"
    )
    args = parser.parse_args()
    only = set(filter(None, args.only.split(",")))
    rows: list[Row] = []

    def run(name: str, group: str, work: Callable[[Path, Row], None], times: int) -> None:
        if only and group not in only:
            return
        row = Row(name, {})
        rows.append(row)
        for _ in range(times):
            with tempfile.TemporaryDirectory() as folder:
                try:
                    work(Path(folder), row)
                except Exception as exc:  # a case that breaks the harness is counted, not hidden
                    print(f"  {name}: {type(exc).__name__}: {exc}")
                    row.add("500")

    started = time.monotonic()
    run("hostile inputs", "hostile", hostile, 1)
    for state in ("preflight", "running", "solving"):
        run(f"kill -9 in {state}", "kill9", lambda root, row, s=state: kill9(root, row, s), args.repeat)
    run("SIGTERM with a follower", "sigterm", sigterm, args.repeat)
    run("full disk mid-job", "disk", full_disk, args.repeat)
    if not only or "history" in only:
        with tempfile.TemporaryDirectory() as folder:
            template = history_template(Path(folder))
            for damage in DAMAGES:
                run(
                    f"history {damage}",
                    "history",
                    lambda root, row, d=damage: damaged_history(root, row, d, template),
                    1,
                )
    run("fake cell killed", "cell", fake_cell_killed, args.repeat)

    print(f"\n{'case':28s} {'tried':>6s} " + " ".join(f"{o:>6s}" for o in OUTCOMES))
    for row in rows:
        tried = sum(row.counts.values())
        print(f"{row.name:28s} {tried:6d} " + " ".join(f"{row.counts.get(o, 0):6d}" for o in OUTCOMES))
    totals = {o: sum(r.counts.get(o, 0) for r in rows) for o in OUTCOMES}
    print(f"{'all':28s} {sum(totals.values()):6d} " + " ".join(f"{totals[o]:6d}" for o in OUTCOMES))
    print(f"({time.monotonic() - started:.0f} s)")


if __name__ == "__main__":
    main()
