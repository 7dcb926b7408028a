"""Helpers for the daemon tests: a fake engine runner for in-process tests and a real
``lasercal serve --dry-run`` process on a loopback port for the integration tests."""

from __future__ import annotations

import contextlib
import copy
import functools
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import uvicorn

from lasercal_hw.config import load_job
from lasercal_hw.errors import DeviceError, InterruptedRunError
from lasercal_hw.run.events import EventSink, Stage
from lasercal_hw.service.app import create_app
from lasercal_hw.service.daemon import Daemon
from lasercal_hw.service.jobs import RunContext, Runner, RunResult
from tests.verify_helpers import calibration_document, fake_robot_calibration, fast_job

# A short dry run: the quick preset (10 waypoints), 0.25 s dwell (10 scans; the daemon's tests
# check the service, not the accuracy a longer dwell buys), 10 background scans, a verify of its
# calibration on the fewest waypoints (2), fast joint moves, and acquisition settings that ride
# out the scan gaps a loaded CI machine causes.
QUICK_JOB: dict[str, Any] = {
    "trajectory": {"preset": "quick"},
    "background": {"scans": 10},
    "verify": {"waypoints": 2},
    "motion": {"joint_speed_rad_s": 1.5, "joint_accel_rad_s2": 4.0},
    "acquisition": {"max_missed_scans": 10000, "max_attempts": 10},
}
QUICK_DWELL_S = 0.25
QUICK_DRY_RUN = {"kind": "dry_run", "confirm_motion": True, "job": QUICK_JOB, "dwell_s": QUICK_DWELL_S}


@functools.cache
def _solved_result() -> dict[str, Any]:
    """A real solver result (a short job, noise-free centres), as the template of fake ones."""
    return calibration_document(fast_job())


def fake_result(
    translation_m: list[float], std_mm: float = 0.5, passed: bool = True, job: dict[str, Any] | None = None
) -> dict[str, Any]:
    """A result.json as the engine writes it, of a scanner at ``translation_m`` unturned, made
    with ``job`` (None: the default job), which it records as a run does."""
    T = [
        [1.0, 0.0, 0.0, translation_m[0]],
        [0.0, 1.0, 0.0, translation_m[1]],
        [0.0, 0.0, 1.0, translation_m[2]],
        [0.0, 0.0, 0.0, 1.0],
    ]
    return copy.deepcopy(_solved_result()) | {
        "T_base_laser": T,
        "translation_m": translation_m,
        "euler_zyx_deg": [0.0, 0.0, 0.0],
        "std_translation_mm": [std_mm] * 3,
        "std_rotation_deg": [0.05] * 3,
        "crb_translation_mm": [std_mm / 2] * 3,
        "crb_rotation_deg": [0.02] * 3,
        "rms_residual_mm": 0.3,
        "verdict": {"passed": passed, "checks": []},
        "run": {
            "robot": {"model": "UR5"},
            "scanner": {},
            "robot_calibration": fake_robot_calibration().as_dict(),
            "job": load_job(None).model_dump(mode="json") if job is None else job,
        },
    }


class FakeEngine:
    """A runner that emits engine-like events for ``waypoints`` waypoints, waits ``step_s``
    each (stopping on cancel like the engine: InterruptedRunError), then writes result.json."""

    def __init__(self, waypoints: int = 4, step_s: float = 0.01, fail: bool = False) -> None:
        self.waypoints, self.step_s, self.fail = waypoints, step_s, fail
        self.translation_m = [0.3, 0.5, 0.2]
        self.range_offset: dict[str, Any] | None = None  # result.json's range-error curve, when set
        self.started = threading.Event()
        self.release = threading.Event()
        self.release.set()
        self.contexts: list[RunContext] = []

    def __call__(self, ctx: RunContext) -> RunResult:
        self.contexts.append(ctx)
        events = EventSink(ctx.on_event)
        events.emit("stage", "connecting", stage=Stage.CONNECT)
        ctx.confirm(None)
        events.emit("progress", "background", stage=Stage.BACKGROUND, completed=0)
        (ctx.out_dir / "session.mcap").write_bytes(b"recording")
        self.started.set()
        first = 2 if ctx.resume_from is not None else 0
        for k in range(first, self.waypoints):
            self.release.wait(10.0)
            if ctx.cancel.cancelled:
                raise InterruptedRunError(f"{ctx.cancel.reason}: arm stopped, recording kept")
            time.sleep(self.step_s)
            events.emit(
                "progress",
                f"waypoint {k}",
                stage=Stage.CENTRE,
                waypoint=k,
                completed=k + 1,
                waypoint_count=self.waypoints,
                time_left_s=1.0,
            )
        if self.fail:
            raise DeviceError("the scanner went away")
        events.emit("progress", "solving", stage=Stage.SOLVE, completed=self.waypoints)
        job = ctx.job.model_dump(mode="json")
        result = fake_result(self.translation_m, job=job) | {"range_offset": self.range_offset}
        (ctx.out_dir / "result.json").write_text(json.dumps(result))
        return RunResult(
            document={"passed": True, "verdict": result["verdict"]},
            passed=True,
            verdict=result["verdict"],
            calibration_dir=ctx.out_dir,
        )


def finish_job(client: httpx.Client, job_id: str, timeout_s: float = 10.0) -> dict[str, Any]:
    """Wait for a job of the in-process daemon to end; its last state."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job_id}").json()
        if job["state"] in ("succeeded", "failed", "cancelled", "interrupted"):
            return dict(job)
        time.sleep(0.02)
    raise AssertionError(f"job {job_id} did not finish")


def fake_runners(engine: FakeEngine) -> Callable[[Any], dict[str, Runner]]:
    """``Daemon(runners=...)`` giving every calibration kind to ``engine`` (verify stays out)."""
    return lambda folder_of: {"calibrate": engine, "dry_run": engine}


@contextlib.contextmanager
def served_in_thread(daemon: Daemon) -> Iterator[str]:
    """``daemon`` served by uvicorn on 127.0.0.1 (a free port) in a thread, as the real one
    is served: yields its URL."""
    server = uvicorn.Server(uvicorn.Config(create_app(daemon), host="127.0.0.1", port=0, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    for _ in range(500):
        if server.started:
            break
        threading.Event().wait(0.01)
    port = server.servers[0].sockets[0].getsockname()[1]
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(10.0)


def read_sse(
    response: httpx.Response, stop_after: int | None = None
) -> list[tuple[int, str, dict[str, Any]]]:
    """Parse ``(id, kind, data)`` from a streaming response (at most ``stop_after`` events)."""
    events: list[tuple[int, str, dict[str, Any]]] = []
    event_id, kind = 0, ""
    for line in response.iter_lines():
        if line.startswith("id: "):
            event_id = int(line[4:])
        elif line.startswith("event: "):
            kind = line[7:]
        elif line.startswith("data: "):
            events.append((event_id, kind, json.loads(line[6:])))
            if stop_after is not None and len(events) >= stop_after:
                break
    return events


class DaemonProcess:
    """``lasercal serve --dry-run --listen 127.0.0.1:0`` in its own process group."""

    def __init__(
        self, data_dir: Path, config: Path | None = None, file_size_limit_bytes: int | None = None
    ) -> None:
        self.data_dir = data_dir
        self.config = config
        self.file_size_limit_bytes = file_size_limit_bytes  # RLIMIT_FSIZE of the daemon (EFBIG beyond)
        self.log = data_dir.parent / f"{data_dir.name}-daemon.log"
        self.process: subprocess.Popen[str] | None = None
        self.url = ""

    def start(self, timeout_s: float = 120.0) -> DaemonProcess:
        """Start it and wait for its 'listening on' line."""
        with self.log.open("a") as log:
            self.process = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "lasercal_hw.cli.main",
                    "serve",
                    "--dry-run",
                    "--listen",
                    "127.0.0.1:0",
                    "--data-dir",
                    str(self.data_dir),
                    *(["--config", str(self.config)] if self.config is not None else []),
                ],
                stdout=subprocess.PIPE,
                stderr=log,
                stdin=subprocess.DEVNULL,
                text=True,
                start_new_session=True,
                preexec_fn=None if self.file_size_limit_bytes is None else self._limit_file_size,
            )
        assert self.process.stdout is not None
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            line = self.process.stdout.readline()
            found = re.search(r"listening on (http://127\.0\.0\.1:\d+)", line)
            if found:
                self.url = found.group(1)
                return self
            if not line and self.process.poll() is not None:
                break
        raise AssertionError(f"daemon did not start: {self.log.read_text()[-2000:]}")

    def _limit_file_size(self) -> None:
        import resource

        limit = int(self.file_size_limit_bytes or resource.RLIM_INFINITY)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    @property
    def pid(self) -> int:
        """The daemon's process id."""
        assert self.process is not None
        return self.process.pid

    @property
    def token(self) -> str:
        """The token the daemon created."""
        return (self.data_dir / "token").read_text().strip()

    def client(self, token: bool = True) -> httpx.Client:
        """An HTTP client for the daemon (with the bearer token unless told otherwise)."""
        headers = {"Authorization": f"Bearer {self.token}"} if token else {}
        return httpx.Client(base_url=self.url, headers=headers, timeout=30.0)

    def kill(self) -> None:
        """SIGKILL the daemon alone (its children live on, as after a crash)."""
        assert self.process is not None
        self.process.kill()
        self.process.wait(10.0)

    def stop(self) -> None:
        """SIGTERM the daemon, then kill whatever is left of its process group."""
        if self.process is None:
            return
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(30.0)
            except subprocess.TimeoutExpired:
                self.process.kill()
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.process.pid, signal.SIGKILL)
        if self.process.stdout is not None:
            self.process.stdout.close()


def wait_for(
    client: httpx.Client,
    job_id: str,
    predicate: Callable[[dict[str, Any]], bool],
    timeout_s: float = 400.0,
) -> dict[str, Any]:
    """Poll a job until ``predicate(job)``. A job a device stopped (on a loaded CI machine the
    fakes can stall: "RTDE stream stalled") is resumed, as an operator would, up to 3 times;
    any other failure ends the wait at once."""
    deadline = time.monotonic() + timeout_s
    resumed = 0
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job_id}").json()
        if predicate(job):
            return job
        if job["state"] == "failed" and job["error"]["code"] == "device_error" and resumed < 3:
            resumed += 1
            client.post(f"/v1/jobs/{job_id}/resume", json={"confirm_motion": True}).raise_for_status()
        elif job["state"] == "failed":  # it stays failed: say so now, not after the timeout
            raise AssertionError(f"job {job_id} failed: {job['error']}")
        time.sleep(0.3)
    raise AssertionError(f"job {job_id} never got there: {job}")
