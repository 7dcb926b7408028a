"""``lasercal remote`` prints text for people and JSON only with ``--json``: against an
in-process daemon (fake engine) served by uvicorn on a loopback port, as the real one is."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from lasercal_hw.cli.main import main
from lasercal_hw.cli.remote_text import event_line, finished_job_lines, job_line
from lasercal_hw.service.client import DaemonClient, DaemonRequestError
from lasercal_hw.service.config import load_daemon_config
from lasercal_hw.service.daemon import Daemon
from tests.cli_helpers import assert_one_line_error
from tests.daemon_helpers import FakeEngine, fake_runners, served_in_thread


@pytest.fixture(scope="module")
def daemon_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, str]]:
    """``(url, token)`` of a daemon with a fake engine on 127.0.0.1 (a free port)."""
    config = load_daemon_config(None, {"data_dir": tmp_path_factory.mktemp("remote") / "data"})
    daemon = Daemon(config, runners=fake_runners(FakeEngine(waypoints=3)))
    with served_in_thread(daemon) as url:
        yield url, daemon.token


@pytest.fixture
def remote(
    daemon_url: tuple[str, str], capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> Callable[..., tuple[int, str, str]]:
    """``lasercal remote ARGS --daemon URL``: (exit code, stdout, stderr), output not a terminal."""
    url, token = daemon_url
    monkeypatch.setenv("LASERCAL_TOKEN", token)

    def run(*args: str) -> tuple[int, str, str]:
        capsys.readouterr()
        monkeypatch.setattr(sys, "argv", ["lasercal", "remote", *args, "--daemon", url])
        with pytest.raises(SystemExit) as exited:
            main()
        out, err = capsys.readouterr()
        return int(exited.value.code or 0), out, err

    return run


def test_every_remote_command_prints_text_and_json_only_when_asked(remote) -> None:
    code, out, err = remote("calibrate", "--dry-run", "--yes", "--wait", "--activate")
    assert code == 0, err
    assert not out.lstrip().startswith("{") and len(out.splitlines()) <= 8, out
    assert "succeeded" in out and "translation (300.0, 500.0, 200.0) mm" in out
    assert "std (largest component) 0.50 mm" in out
    code, out, _ = remote("calibrate", "--dry-run", "--yes", "--wait", "--json")
    document = json.loads(out)
    assert code == 0 and document["state"] == "succeeded" and document["calibration_id"]
    newer, older = (c["id"] for c in json.loads(remote("history", "--json")[1])["calibrations"][:2])

    code, out, _ = remote("status")
    assert code == 0 and not out.lstrip().startswith("{") and len(out.splitlines()) <= 12, out
    assert f"active calibration {older}: passed" in out and "192.168.0.10" not in out
    assert json.loads(remote("status", "--json")[1])["active_calibration"]["id"] == older

    code, out, _ = remote("activate", newer, "--reason", "roll forward")
    assert code == 0 and out.startswith(f"active now: {newer} (roll forward)\n"), out
    assert json.loads(remote("activate", newer, "--json")[1])["active"] is True

    code, out, _ = remote("diff", older, newer)
    assert code == 0 and "significant: no" in out and "translation (0.00, 0.00, 0.00) mm" in out, out
    assert json.loads(remote("diff", older, newer, "--json")[1])["significant"] is False

    code, out, _ = remote("health")
    assert code == 0 and out.startswith(f"default: {newer} passed, ") and "never verified" in out, out
    assert "robot calibration matches: unknown" in out
    assert "range error: the active calibration estimated no range-error curve" in out, out
    assert json.loads(remote("health", "--json")[1])["scanners"][0]["calibration_id"] == newer

    code, out, _ = remote("mark-bad", newer, "--by", "qa@cell-7", "--reason", "rod bent")
    assert code == 0 and out.startswith(f"marked bad: {newer} by qa@cell-7 at ") and "(rod bent)" in out, out
    assert json.loads(remote("status", "--json")[1])["active_calibration"] is None
    code, _, err = remote("activate", newer)
    assert code != 0 and "marked bad by qa@cell-7" in err, err

    code, out, _ = remote("calibrate", "--dry-run", "--yes")
    assert code == 0 and out.startswith("job job-") and "see how it goes with" in out, out
    assert json.loads(remote("jobs", "--json")[1])["jobs"][0]["kind"] == "dry_run"


def test_a_followed_job_shows_each_waypoint_once() -> None:
    """The engine sends a waypoint's progress and its centre with the same message: one line."""
    events = [
        ("stage", {"message": "measuring the background"}),
        ("progress", {"message": "waypoint 3 of 10: centre found", "stage": "centre", "waypoint": 3}),
        ("scan", {"message": "averaged scan of waypoint 3", "waypoint": 3}),
        ("centre", {"message": "waypoint 3 of 10: centre found", "waypoint": 3}),
        ("progress", {"message": "waypoint 4 of 10: moving", "stage": "move", "waypoint": 4}),
        ("progress", {"message": "waypoint 4 of 10: rod not seen", "stage": "skip", "waypoint": 4}),
        ("skip", {"message": "waypoint 4 of 10: rod not seen", "waypoint": 4}),
        ("state", {"state": "failed", "error": {"code": "device_error", "message": "scanner gone"}}),
    ]
    lines = [line for kind, data in events if (line := event_line(kind, data)) is not None]
    assert lines == [
        "[stage] measuring the background",
        "[centre] waypoint 3 of 10: centre found",
        "[skip] waypoint 4 of 10: rod not seen",
        "[state] failed: scanner gone",
    ]


def test_the_status_of_a_cell_is_a_line_per_scanner() -> None:
    from lasercal_hw.cli.remote_text import status_lines

    scanners = [
        {"name": "front", "url": "scip+tcp://127.0.0.2:10940", "connected": True, "identity": None,
         "error": None, "in_use_by_job": "job-1"},
        {"name": "rear", "url": "scip+tcp://127.0.0.3:10940", "connected": False, "identity": None,
         "error": "connection refused", "in_use_by_job": None},
    ]
    status = {"daemon": {"version": "0", "started_utc": "t", "data_dir": "d"}, "robot": {},
              "scanner": scanners[0], "scanners": scanners, "active_calibration": None, "job": None}
    lines = status_lines(status)
    assert "scanner front: scip+tcp://127.0.0.2:10940, connected yes, in use by job-1" in lines
    assert "scanner rear: scip+tcp://127.0.0.3:10940, connected no" in lines
    assert "  scanner rear: connection refused" in lines


def test_a_job_line_says_each_thing_once() -> None:
    """A queued job's progress repeats its state, and an error's code may be its state: neither
    is printed twice; another code is."""
    queued = {"id": "job-1", "kind": "calibrate", "state": "queued", "progress": {"message": "queued"}}
    assert job_line(queued) == "job job-1 (calibrate): queued"
    error = {"code": "interrupted", "message": "run interrupted at waypoint 3 (Ctrl-C)"}
    stopped = {"id": "job-2", "kind": "dry_run", "state": "interrupted", "error": error}
    assert job_line(stopped) == "job job-2 (dry_run): interrupted, run interrupted at waypoint 3 (Ctrl-C)"
    no_scanner = {"code": "device_error", "message": "no"}
    failed = {"id": "job-3", "kind": "verify", "state": "failed", "error": no_scanner}
    assert job_line(failed) == "job job-3 (verify): failed, device_error: no"
    moving = {"id": "job-4", "kind": "calibrate", "state": "running", "progress": {"message": "waypoint 3"}}
    assert job_line(moving) == "job job-4 (calibrate): running, waypoint 3"


def _interrupted(url: str, token: str, engine: FakeEngine, *args: str) -> tuple[int, str, str]:
    """``lasercal remote ARGS --wait --daemon URL`` as its own process, Ctrl-C (SIGINT) once the
    job it follows runs: (exit code, stdout, stderr)."""
    engine.started.clear()
    command = [sys.executable, "-m", "lasercal_hw.cli.main", "remote", *args, "--wait", "--daemon", url]
    process = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env=os.environ | {"LASERCAL_TOKEN": token},
    )
    try:
        assert engine.started.wait(60.0), "the job never started"
        time.sleep(0.5)  # the client is following the events by now
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=30.0)
    finally:
        if process.poll() is None:
            process.kill()
    return process.returncode, out, err


def test_ctrl_c_while_waiting_cancels_the_job_the_command_started(tmp_path: Path) -> None:
    """Safety first: the arm must not keep moving after Ctrl-C; calibrate and resume alike."""
    engine = FakeEngine(waypoints=5)
    engine.release.clear()  # the job runs until it is cancelled
    daemon = Daemon(load_daemon_config(None, {"data_dir": tmp_path / "data"}), runners=fake_runners(engine))
    with served_in_thread(daemon) as url:
        client = DaemonClient(url, daemon.token)
        job_id = ""
        for command in ("calibrate", "resume"):
            args = ("--dry-run", "--dwell", "0.5") if command == "calibrate" else (job_id,)
            code, _out, err = _interrupted(url, daemon.token, engine, command, *args, "--yes")
            job_id = client.jobs()[0]["id"]
            assert code == 130, err
            said = [line for line in err.splitlines() if line.startswith("interrupted")]
            assert len(said) == 1 and job_id in said[0] and "arm is being stopped" in said[0], err
            engine.release.set()  # the fake engine looks at the cancel between waypoints
            job = client.wait(job_id)
            engine.release.clear()
            assert job["state"] == "cancelled", job


class _UnreachableDaemon:
    url = "http://127.0.0.1:9"
    token_file = None

    def cancel(self, job_id: str) -> dict[str, str]:
        raise DaemonRequestError(f"cannot reach the lasercal daemon at {self.url}: connection refused")


def test_a_failed_cancel_after_ctrl_c_says_the_job_may_still_run() -> None:
    from lasercal_hw.cli.remote import cancel_after_interrupt

    line = cancel_after_interrupt(_UnreachableDaemon(), "job-1")
    assert "job-1 may still be running" in line, line
    assert line.endswith("lasercal remote cancel job-1 --daemon http://127.0.0.1:9"), line


class _Daemon:
    url = "http://127.0.0.1:9"
    token_file: Path | None = None

    def cancel(self, job_id: str) -> dict[str, str]:
        return {"id": job_id, "state": "running"}


def test_a_cancelled_verify_is_told_to_verify_again_not_to_resume() -> None:
    """A daemon does not resume a verify; a calibration goes on from its recording."""
    from lasercal_hw.cli.remote import cancel_after_interrupt

    verify = cancel_after_interrupt(_Daemon(), "job-2", "verify")
    again = "verify again with: lasercal remote verify --yes --daemon http://127.0.0.1:9)"
    assert verify.endswith(again), verify
    assert "resume" not in verify
    calibrate = cancel_after_interrupt(_Daemon(), "job-3", "calibrate")
    assert "continue with: lasercal remote resume job-3 --yes --daemon http://127.0.0.1:9" in calibrate
    named = _Daemon()
    named.token_file = Path("/srv/lasercal/token")
    verify = cancel_after_interrupt(named, "job-4", "verify")
    again = "lasercal remote verify --yes --daemon http://127.0.0.1:9 --token-file /srv/lasercal/token)"
    assert verify.endswith(again), verify


def test_a_finished_cell_job_shows_every_scanners_calibration() -> None:
    """A cell job files a calibration per scanner: each is shown under its scanner's name (only
    the first was)."""
    job = {"id": "job-5", "kind": "calibrate", "state": "succeeded", "finished_utc": "2026-11-29T00:00:00Z"}
    summaries = {
        name: {"id": f"cal-{name}", "passed": True, "translation_m": [0.3, 0.5, 0.2],
               "euler_zyx_deg": [5.0, 7.0, 3.0], "std_translation_mm": [1.0], "std_rotation_deg": [0.1],
               "rms_residual_mm": 1.5}
        for name in ("front", "rear")
    }
    text = "\n".join(finished_job_lines(job, summaries))
    assert "scanner front: calibration cal-front: passed" in text
    assert "scanner rear: calibration cal-rear: passed" in text
    one = "\n".join(finished_job_lines(job, {"": summaries["front"]}))
    assert "calibration cal-front: passed" in one and "scanner" not in one


def test_a_busy_daemon_refuses_with_the_busy_code_naming_the_running_job(tmp_path: Path) -> None:
    """Not exit 2 (a usage error: the command was right, the cell is taken) but 5, with the
    running job and the commands to watch or cancel it; calibrate and resume alike."""
    engine = FakeEngine(waypoints=5)
    engine.release.clear()  # the first job runs until released
    daemon = Daemon(load_daemon_config(None, {"data_dir": tmp_path / "data"}), runners=fake_runners(engine))
    with served_in_thread(daemon) as url:
        client = DaemonClient(url, daemon.token)
        stopped = client.start_job({"kind": "dry_run", "confirm_motion": True})
        assert engine.started.wait(30.0)
        client.cancel(stopped["id"])
        engine.release.set()
        assert client.wait(stopped["id"])["state"] == "cancelled"  # resumable
        engine.release.clear()
        engine.started.clear()
        running = client.start_job({"kind": "dry_run", "confirm_motion": True})
        assert engine.started.wait(30.0)
        token_file = tmp_path / "my token"
        token_file.write_text(daemon.token, encoding="utf-8")
        without_token = {k: v for k, v in os.environ.items() if k != "LASERCAL_TOKEN"}
        # the token from the environment, then from a named file: the cancel shown names that file
        tries = (
            (("calibrate", "--dry-run"), (), os.environ | {"LASERCAL_TOKEN": daemon.token}, ""),
            (("resume", stopped["id"]), ("--token-file", str(token_file)), without_token,
             f" --token-file '{token_file}'"),
        )
        try:
            for args, token_args, env, named in tries:
                result = subprocess.run(
                    [sys.executable, "-m", "lasercal_hw.cli.main", "remote", *args, "--yes", "--daemon", url,
                     *token_args],
                    capture_output=True, text=True, timeout=60.0, stdin=subprocess.DEVNULL, env=env,
                )
                assert_one_line_error(
                    result, 5, f"job {running['id']} (dry_run)", f"lasercal remote status --daemon {url}",
                    f"lasercal remote cancel {running['id']} --daemon {url}{named};",
                )
        finally:
            engine.release.set()
            client.wait(running["id"])
