"""The dry run under signals and failures as a terminal and the kernel deliver them
(issue 14 items 1-3): Ctrl-C to the whole process group, SIGKILL of the run, death of
the fake cell, a scanner whose PP reply carries a stale checksum."""

from __future__ import annotations

import os
import re
import selectors
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from lasercal_hw.errors import ExitCode
from tests.run.test_dry_run import process_gone, write_job

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(240)]

CELL_PID = re.compile(r"fake cell on \S+ \(pid (\d+)\)")


class DryRun:
    """``lasercal run --dry-run`` in a session of its own (as a terminal's foreground job)."""

    def __init__(self, tmp_path: Path, *extra: str) -> None:
        args = [sys.executable, "-m", "lasercal_hw.cli.main", "run", "--dry-run", "--json", "--config",
                str(write_job(tmp_path)), "--out", str(tmp_path / "out"), *extra]
        self.process = subprocess.Popen(
            args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
            cwd=tmp_path, start_new_session=True,  # its own process group, as a terminal's job
        )
        self.stderr = ""
        self.cell_pid: int | None = None

    def read_until(self, pattern: str, timeout_s: float = 120.0) -> None:
        """Collect stderr until a line matches ``pattern``; fail with what was seen if not."""
        assert self.process.stderr is not None
        deadline = time.monotonic() + timeout_s
        with selectors.DefaultSelector() as selector:
            selector.register(self.process.stderr, selectors.EVENT_READ)
            while time.monotonic() < deadline and selector.select(deadline - time.monotonic()):
                line = self.process.stderr.readline()
                if not line:
                    break
                self.stderr += line
                if match := CELL_PID.search(line):
                    self.cell_pid = int(match.group(1))
                if re.search(pattern, line):
                    return
        pytest.fail(f"no line matching {pattern!r} in:\n{self.stderr[-3000:]}")

    def finish(self, timeout_s: float) -> float:
        """Wait for the exit; the seconds it took."""
        started = time.monotonic()
        _, rest = self.process.communicate(timeout=timeout_s)
        self.stderr += rest
        return time.monotonic() - started


@contextmanager
def dry_run(tmp_path: Path, *extra: str) -> Iterator[DryRun]:
    run = DryRun(tmp_path, *extra)
    try:
        yield run
    finally:
        for pid in (run.process.pid, run.cell_pid):
            if pid is not None and not process_gone(pid):
                os.kill(pid, signal.SIGKILL)
        run.process.wait()


def eventually_gone(pid: int, timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while not process_gone(pid):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def group_gone(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return True
    return False


def test_sigint_to_the_process_group_twice_exits_130_within_5_s_and_leaves_nothing(tmp_path: Path) -> None:
    """Needs the engine to stop the arm on the first SIGINT and ignore the second."""
    with dry_run(tmp_path) as run:
        run.read_until(r"waypoint 1:? (rod at|skipped)")
        os.killpg(run.process.pid, signal.SIGINT)
        time.sleep(0.2)
        os.killpg(run.process.pid, signal.SIGINT)
        took_s = run.finish(timeout_s=60)
        assert run.process.returncode == ExitCode.INTERRUPTED, run.stderr[-3000:]
        assert took_s < 5.0, run.stderr[-3000:]
        assert "interrupted" in run.stderr and "--resume" in run.stderr
        assert "Traceback" not in run.stderr and "stopJ did not return" not in run.stderr
        assert group_gone(run.process.pid)
        assert run.cell_pid is not None and eventually_gone(run.cell_pid, 5.0)
    assert (tmp_path / "out" / "session.mcap").stat().st_size > 0


def test_sigkill_of_the_run_stops_its_fake_cell_within_5_s(tmp_path: Path) -> None:
    with dry_run(tmp_path) as run:
        run.read_until(CELL_PID.pattern)
        os.kill(run.process.pid, signal.SIGKILL)
        run.process.wait()
        assert run.cell_pid is not None and eventually_gone(run.cell_pid, 5.0)


def test_death_of_the_fake_cell_ends_the_run_with_a_device_error_naming_it(tmp_path: Path) -> None:
    with dry_run(tmp_path) as run:
        run.read_until(r"waypoint 0:? (rod at|skipped)")
        assert run.cell_pid is not None
        os.kill(run.cell_pid, signal.SIGKILL)
        took_s = run.finish(timeout_s=60)
        assert run.process.returncode == ExitCode.DEVICE_ERROR, run.stderr[-3000:]
        assert took_s < 10.0, run.stderr[-3000:]
        assert f"the fake cell (pid {run.cell_pid}) was killed by signal 9" in run.stderr
        assert "connection to the robot" in run.stderr or "scanner" in run.stderr


def test_a_stale_pp_checksum_refuses_the_dry_run_with_one_clear_message(tmp_path: Path) -> None:
    scene = tmp_path / "scene.toml"
    scene.write_text('[faults]\nscanner_stale_field = "AFRT=560"\n')
    with dry_run(tmp_path, "--scene", str(scene)) as run:
        run.finish(timeout_s=120)
        assert run.process.returncode == ExitCode.DEVICE_ERROR, run.stderr[-3000:]
        assert "PP reply line 'AFRT:560;0' fails its checksum" in run.stderr.replace("\n", "")
        assert "Traceback" not in run.stderr
