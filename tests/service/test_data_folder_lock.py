"""One process at a time in a data folder: a second ``lasercal serve`` or a
``--rebuild-history`` on a folder a daemon holds is refused in one line and touches nothing;
a killed daemon's folder is free again at once."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from lasercal_hw.errors import ExitCode
from lasercal_hw.service.app import create_app
from lasercal_hw.service.config import load_daemon_config
from lasercal_hw.service.daemon import Daemon
from lasercal_hw.service.store import DB_FILE
from tests.daemon_helpers import QUICK_DRY_RUN, DaemonProcess, FakeEngine, fake_runners


def serve(data_dir: Path, *options: str, timeout_s: float = 30.0) -> subprocess.CompletedProcess[str]:
    """``lasercal serve --data-dir DATA_DIR OPTIONS`` in its own process group, killed whole if it
    has not ended after ``timeout_s`` (a daemon that started instead of refusing)."""
    command = [sys.executable, "-m", "lasercal_hw.cli.main", "serve", "--data-dir", str(data_dir), *options]
    process = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )
    try:
        out, err = process.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
        out, err = process.communicate()
        raise AssertionError(f"lasercal serve {' '.join(options)} did not refuse: {err[-2000:]}") from None
    return subprocess.CompletedProcess(command, process.returncode, out, err)


@pytest.fixture
def running(tmp_path: Path) -> Iterator[tuple[TestClient, str, Path]]:
    """A daemon (in this process) on ``tmp_path/data`` with a job held running."""
    data_dir = tmp_path / "data"
    engine = FakeEngine()
    daemon = Daemon(load_daemon_config(None, {"data_dir": data_dir}), runners=fake_runners(engine))
    with TestClient(create_app(daemon), base_url="http://127.0.0.1") as client:
        client.headers["Authorization"] = f"Bearer {daemon.token}"
        engine.release.clear()
        job_id = client.post("/v1/jobs", json=QUICK_DRY_RUN).json()["id"]
        assert engine.started.wait(5.0)
        try:
            yield client, job_id, data_dir
        finally:
            engine.release.set()


def _refused_in_one_line(done: subprocess.CompletedProcess[str], data_dir: Path) -> None:
    assert done.returncode == ExitCode.BAD_INPUT, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in done.stderr, done.stderr
    assert str(data_dir) in lines[0] and f"process {os.getpid()}" in lines[0], lines[0]


def _stamps(data_dir: Path) -> dict[Path, int]:
    """Every file's modification time but the running daemon's own database's."""
    files = [path for path in data_dir.rglob("*") if not path.name.startswith(DB_FILE)]
    return {path: path.stat().st_mtime_ns for path in files}


def test_a_second_daemon_on_the_folder_is_refused_and_touches_nothing(
    running: tuple[TestClient, str, Path],
) -> None:
    client, job_id, data_dir = running
    before = _stamps(data_dir)
    done = serve(data_dir, "--dry-run", "--listen", "127.0.0.1:0")
    _refused_in_one_line(done, data_dir)
    job = client.get(f"/v1/jobs/{job_id}").json()
    assert job["state"] not in ("interrupted", "failed") and job["error"] is None, job
    assert _stamps(data_dir) == before  # the token, the reserve, the lock file: nothing rewritten


def test_a_rebuild_is_refused_while_a_daemon_holds_the_folder(running: tuple[TestClient, str, Path]) -> None:
    client, job_id, data_dir = running
    done = serve(data_dir, "--rebuild-history")
    _refused_in_one_line(done, data_dir)
    assert not list(data_dir.glob(f"{DB_FILE}.before-rebuild-*"))  # the daemon's database stays in place
    assert client.get(f"/v1/jobs/{job_id}").json()["state"] not in ("interrupted", "failed")


def test_a_rebuild_of_a_missing_folder_says_so(tmp_path: Path) -> None:
    missing = tmp_path / "nonexistent"
    done = serve(missing, "--rebuild-history")
    assert done.returncode == ExitCode.BAD_INPUT and "Traceback" not in done.stderr, done.stderr
    assert "does not exist" in done.stderr and str(missing) in done.stderr, done.stderr
    assert "--rebuild-history" not in done.stderr, done.stderr  # not the command just run
    assert not missing.exists()


def test_a_killed_daemons_folder_is_free_at_once(tmp_path: Path) -> None:
    """kill -9 leaves the lock file and the fake cell's children alive; the OS frees the lock."""
    first = DaemonProcess(tmp_path / "data").start()
    try:
        first.kill()
        daemon = Daemon(load_daemon_config(None, {"data_dir": first.data_dir}))
        daemon.stop()
    finally:
        first.stop()
