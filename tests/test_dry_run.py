"""``lasercal run --dry-run`` end to end: a fake cell child process, the real drivers,
the whole procedure, and every exit path stopping the child."""

from __future__ import annotations

import json
import os
import pty
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lasercal_hw.errors import ExitCode
from lasercal_hw.run.dry_run import FakeCellProcess, free_loopback_address, ports_free
from lasercal_hw.session.reader import read_session
from tests.conftest import DryRunResult
from trajectories.presets import preset_waypoints

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(240)]

WAYPOINTS = len(preset_waypoints("quick"))


def write_job(folder: Path) -> Path:
    job = folder / "job.toml"
    job.write_text(
        "dwell_s = 1.0\n"
        "[trajectory]\npreset = \"quick\"\n"
        "[background]\nscans = 10\n"
        # the job file's highest joint speed and acceleration: motion is most of a dry run's time
        "[motion]\njoint_speed_rad_s = 1.5\njoint_accel_rad_s2 = 4.0\n"
        # A short test trajectory: gates sized for it, not for a real run.
        "[quality]\nmax_std_translation_mm = 100.0\nmax_std_rotation_deg = 10.0\nmin_observations = 6\n"
    )
    return job


def lasercal(*args: str) -> list[str]:
    return [sys.executable, "-m", "lasercal_hw.cli.main", "run", *args]


def process_gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


def test_free_address_is_random_loopback_with_free_ports() -> None:
    address = free_loopback_address()
    assert address.startswith("127.") and address != "127.0.0.1"
    assert ports_free(address)


def test_fake_cell_child_reports_truth_and_is_stopped() -> None:
    with FakeCellProcess() as cell:
        pid = cell.pid
        assert cell.scanner_url == f"scip+tcp://{cell.address}:10940"
        assert cell.robot_host == cell.address
        assert np.allclose(cell.ground_truth[:3, 3], [0.30, 0.50, 0.20])
        assert not ports_free(cell.address)
    assert process_gone(pid)


def test_dry_run_interrupted_by_sigint_then_resumed_recovers_the_truth(tmp_path: Path) -> None:
    """One dry run, interrupted and resumed: every exit path stops the fake cell, the
    recording survives the interrupt, and the resumed run reports estimate and truth."""
    job = write_job(tmp_path)
    out = tmp_path / "out"
    process = subprocess.Popen(
        lasercal("--dry-run", "--json", "--config", str(job), "--out", str(out)),
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True, cwd=tmp_path,
    )
    cell_pid = None
    lines = []
    try:
        assert process.stderr is not None
        for line in process.stderr:
            lines.append(line)
            if match := re.search(r"\(pid (\d+)\)", line):
                cell_pid = int(match.group(1))
            if re.search(r"waypoint 3:? (rod at|skipped)", line):
                process.send_signal(signal.SIGINT)
                break
        _, rest = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    stderr = "".join(lines) + rest
    assert process.returncode == ExitCode.INTERRUPTED, stderr[-3000:]
    assert "interrupted" in stderr and "--resume" in stderr
    assert cell_pid is not None and process_gone(cell_pid)
    recording = read_session(out / "session.mcap")
    done = [event["index"] for event in recording.events_of("observation")]
    done += [event["index"] for event in recording.events_of("waypoint_skipped")]
    assert set(range(3)) <= set(done) and len(done) < WAYPOINTS
    assert recording.events_of("abort")[-1]["cause"] == "interrupted"
    assert not (out / "result.json").exists()

    resumed = subprocess.run(
        lasercal("--dry-run", "--json", "--resume", str(out / "session.mcap")),
        capture_output=True, text=True, timeout=200, stdin=subprocess.DEVNULL, cwd=tmp_path,
    )
    assert resumed.returncode == ExitCode.OK, resumed.stderr[-3000:]
    document = json.loads(resumed.stdout)
    estimate = np.array(document["T_base_laser"])
    truth = np.array(document["ground_truth"]["T_base_laser"])
    assert estimate.shape == truth.shape == (4, 4)
    assert np.allclose(truth[:3, 3], [0.30, 0.50, 0.20])
    # The error against the truth is consistent with the uncertainty the run reports.
    error = document["ground_truth"]["error"]
    assert error["translation_mm"] == pytest.approx(1000 * np.linalg.norm(estimate[:3, 3] - truth[:3, 3]))
    assert error["translation_mm"] < 4 * np.linalg.norm(document["std_translation_mm"]) + 5.0
    assert error["rotation_deg"] < 4 * np.linalg.norm(document["std_rotation_deg"]) + 0.5
    # Every waypoint gave an observation or a recorded reason (the world has mixed pixels).
    assert document["observations"] >= WAYPOINTS - 3
    assert all(skip["reason"] for skip in document["skipped"])
    assert process_gone(document["fake_cell"]["pid"])
    for name in ("session.mcap", "observations.csv", "result.json", "report.png",
                 "base_to_laser.urdf.xml", "static_transform_publisher.args"):
        assert (out / name).stat().st_size > 0, name
    assert "--child-frame-id laser" in (out / "static_transform_publisher.args").read_text()
    final = read_session(out / "session.mcap")
    observed = {event["index"] for event in final.events_of("observation")}
    skipped = {event["index"] for event in final.events_of("waypoint_skipped")}
    assert observed | skipped == set(range(WAYPOINTS))
    assert document["observations"] == len(observed)
    assert document["observations"] + len(document["skipped"]) == WAYPOINTS
    assert final.meta["dry_run"] is True and not final.truncated
    assert final.meta["scanner"]["url"] == f"scip+tcp://{final.meta['robot']['host']}:10940"
    assert final.meta["scanner"]["product"] and final.meta["robot"]["model"]
    # A retried dwell (a stream gap under load) is attempt 2; a re-measured one would be attempt 1 again.
    first_attempts = [e["index"] for e in final.events_of("dwell_start") if e["attempt"] == 1]
    assert first_attempts.count(0) == 1, "a resumed run must not measure finished waypoints again"
    live = json.loads((out / "result.json").read_text())
    assert live["run"]["resumed_after_waypoints"] == len(done)

    # `lasercal solve session.mcap` replays extraction and solve: the live transform to 1e-9.
    replay = subprocess.run(
        [sys.executable, "-m", "lasercal_hw.cli.main", "solve", str(out / "session.mcap"), "--json"],
        capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL, cwd=tmp_path,
    )
    assert replay.returncode == ExitCode.OK, replay.stderr[-3000:]
    np.testing.assert_allclose(
        np.array(json.loads(replay.stdout)["T_base_laser"]), np.array(live["T_base_laser"]), rtol=0, atol=1e-9
    )


def test_scanner_drop_at_a_waypoint_repeats_that_waypoint(scanner_drop_dry_run: DryRunResult) -> None:
    """The scene fault drops the scanner's connection during waypoint 2's dwell: the driver
    reconnects, the dwell is repeated and the run completes."""
    out, result = scanner_drop_dry_run
    assert result.returncode == ExitCode.OK, result.stderr[-3000:]
    recording = read_session(out / "session.mcap")
    dwells = [event["index"] for event in recording.events_of("dwell_start")]
    assert dwells.count(2) == 2, dwells
    assert all(dwells.count(i) == 1 for i in set(dwells) - {2})
    assert json.loads(result.stdout)["observations"] >= WAYPOINTS - 3


def test_protective_stop_aborts_with_device_error_and_no_further_motion(tmp_path: Path) -> None:
    job = write_job(tmp_path)
    scene = tmp_path / "scene.toml"
    scene.write_text("[faults]\nprotective_stop_at_waypoint = 1\n")
    out = tmp_path / "out"
    result = subprocess.run(
        lasercal("--dry-run", "--config", str(job), "--scene", str(scene), "--out", str(out)),
        capture_output=True, text=True, timeout=200, stdin=subprocess.DEVNULL, cwd=tmp_path,
    )
    assert result.returncode == ExitCode.DEVICE_ERROR, result.stderr[-3000:]
    assert "protective stop at waypoint 1" in result.stderr
    assert "will not resume by itself" in result.stderr
    assert f"lasercal run --resume {out / 'session.mcap'}" in result.stderr.replace("\n", "")
    recording = read_session(out / "session.mcap")
    assert [event["index"] for event in recording.events_of("dwell_start")] == [0]
    abort = recording.events_of("abort")
    assert len(abort) == 1 and abort[0]["cause"] == "protective_stop" and abort[0]["index"] == 1


def _read_until(fd: int, text: str, timeout_s: float) -> str:
    """Bytes from ``fd`` until ``text`` appears (the prompt has no line end)."""
    import selectors
    import time

    seen = b""
    deadline = time.monotonic() + timeout_s
    with selectors.DefaultSelector() as selector:
        selector.register(fd, selectors.EVENT_READ)
        while text.encode() not in seen and time.monotonic() < deadline:
            if selector.select(timeout=deadline - time.monotonic()):
                chunk = os.read(fd, 4096)
                if not chunk:
                    break
                seen += chunk
    return seen.decode(errors="replace")


@pytest.mark.parametrize("answer", ["no", "sigterm"])
def test_operator_declining_or_terminating_at_the_prompt_moves_nothing(tmp_path: Path, answer: str) -> None:
    job = write_job(tmp_path)
    with job.open("a") as file:  # a live run needs to know roughly where the scanner is
        file.write("[scanner.nominal]\ntranslation_m = [0.30, 0.50, 0.20]\neuler_zyx_deg = [5.0, 7.0, 3.0]\n")
    out = tmp_path / "out"
    with FakeCellProcess() as cell:
        controller, terminal = pty.openpty()
        try:
            process = subprocess.Popen(
                lasercal("--robot", cell.robot_host, "--scanner", cell.scanner_url, "--config", str(job),
                         "--out", str(out)),
                stdin=terminal, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=tmp_path,
            )
            os.close(terminal)
            assert process.stderr is not None
            stderr = _read_until(process.stderr.fileno(), "Start the motion?", 90)
            if answer == "no":
                os.write(controller, b"n\n")
            else:
                process.send_signal(signal.SIGTERM)
            rest = process.communicate(timeout=60)[1].decode(errors="replace")
        finally:
            os.close(controller)
            if process.poll() is None:
                process.kill()
                process.wait()
    stderr += rest
    assert process.returncode == ExitCode.INTERRUPTED, stderr[-3000:]
    assert "Start the motion?" in stderr
    assert ("declined" if answer == "no" else "interrupted at the confirmation prompt") in stderr
    recording = read_session(out / "session.mcap")
    assert recording.events_of("dwell_start") == []
    assert recording.events_of("background") == []
    assert recording.events_of("abort")[0]["cause"] == "interrupted"
