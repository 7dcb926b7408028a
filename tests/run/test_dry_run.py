"""``lasercal run --dry-run`` end to end: a fake cell child process, the real drivers,
the whole procedure, and every exit path stopping the child."""

from __future__ import annotations

import json
import os
import pty
import re
import shlex
import signal
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from fakes.cell_process import FakeCellProcess, free_loopback_address, ports_free
from lasercal_hw.config import load_job
from lasercal_hw.errors import ExitCode, TransportError
from lasercal_hw.run.engine import RunEvent, RunReport, RunRequest, calibrate
from lasercal_hw.session.reader import SessionRecording, read_session
from tests.verify_helpers import fake_robot_calibration
from trajectories.presets import preset_waypoints

# A test's time limit includes the module's dry runs it sets up (one or both).
pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(400)]

WAYPOINTS = len(preset_waypoints("quick"))


def write_job(folder: Path) -> Path:
    job = folder / "job.toml"
    job.write_text(
        "dwell_s = 0.5\n"
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


@dataclass(frozen=True)
class InterruptedDryRun:
    """A ``lasercal run --dry-run --json`` stopped by SIGINT once waypoint 3 is done, then
    continued with the command it printed (``lasercal run --resume PATH``: the recording
    alone says it is a dry run's and which scene its fake cell held)."""

    out: Path
    returncode: int
    stderr: str
    cell_pid: int | None
    recording: SessionRecording  # as the interrupt left it, read before resuming
    result_written: bool  # result.json existed after the interrupt
    resumed: subprocess.CompletedProcess[str]


@dataclass(frozen=True)
class EngineDryRun:
    """A dry run through ``lasercal_hw.run.engine.calibrate`` and every event it reported."""

    out: Path
    report: RunReport
    events: list[RunEvent]


@pytest.fixture(scope="module")
def interrupted_dry_run(tmp_path_factory: pytest.TempPathFactory) -> InterruptedDryRun:
    """The tests' short job interrupted and resumed: its own test checks both halves and the
    replay, the engine test compares the engine's document and files with the resumed CLI's."""
    folder = tmp_path_factory.mktemp("interrupted")
    job = write_job(folder)
    out = folder / "out"
    process = subprocess.Popen(
        lasercal("--dry-run", "--json", "--config", str(job), "--out", str(out)),
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True, cwd=folder,
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
    recording = read_session(out / "session.mcap")
    result_written = (out / "result.json").exists()
    printed = re.search(r"continue with: lasercal run (.+)$", "".join(lines) + rest, re.MULTILINE)
    assert printed is not None, "".join(lines) + rest
    resumed = subprocess.run(
        lasercal(*shlex.split(printed.group(1)), "--json"),
        capture_output=True, text=True, timeout=200, stdin=subprocess.DEVNULL, cwd=folder,
    )
    return InterruptedDryRun(
        out, process.returncode, "".join(lines) + rest, cell_pid, recording, result_written, resumed
    )


@pytest.fixture(scope="module")
def scanner_drop_engine_run(tmp_path_factory: pytest.TempPathFactory) -> EngineDryRun:
    """The tests' short job through the engine, its scanner dropping the connection during
    waypoint 2's dwell (a scene fault): the scanner-drop test checks the repeated dwell, the
    engine test the document, files and events."""
    folder = tmp_path_factory.mktemp("scanner-drop")
    scene = folder / "scene.toml"
    scene.write_text("[faults]\nscanner_drop_at_waypoint = 2\n")
    events: list[RunEvent] = []
    request = RunRequest(job=load_job(write_job(folder)), out_dir=folder / "out", dry_run=True, scene=scene)
    report = calibrate(request, on_event=events.append)
    return EngineDryRun(folder / "out", report, events)


def test_free_address_is_random_loopback_with_free_ports() -> None:
    address = free_loopback_address()
    assert address.startswith("127.") and address != "127.0.0.1"
    assert ports_free(address)


def test_fake_cell_child_reports_truth_and_is_stopped() -> None:
    with FakeCellProcess() as cell:
        pid = cell.pid
        assert cell.ready and cell.alive
        assert cell.scanner_url == f"scip+tcp://{cell.address}:10940"
        assert cell.robot_host == cell.address
        assert np.allclose(cell.ground_truth[:3, 3], [0.30, 0.50, 0.20])
        assert not ports_free(cell.address)
        assert "lasercal_hw.cli" not in " ".join(cell.args)  # fakes/ starts its own cell, not the CLI
    assert process_gone(pid)
    assert not cell.alive and not cell.ready


def test_fake_cell_with_a_bad_scene_says_why_in_one_line(tmp_path: Path) -> None:
    scene = tmp_path / "scene.toml"
    scene.write_text("[rod]\nradius_m = -1\n", encoding="utf-8")
    with pytest.raises(TransportError, match=r"exited before ready: fake cell: scene file .* rod\.radius_m"):
        FakeCellProcess(scene=scene).start()


def test_dry_run_interrupted_by_sigint_then_resumed_recovers_the_truth(
    interrupted_dry_run: InterruptedDryRun,
) -> None:
    """One dry run, interrupted and resumed: every exit path stops the fake cell, the
    recording survives the interrupt, and the resumed run reports estimate and truth
    (the run: the fixture above)."""
    run = interrupted_dry_run
    out, stderr, cell_pid, recording = run.out, run.stderr, run.cell_pid, run.recording
    assert run.returncode == ExitCode.INTERRUPTED, stderr[-3000:]
    assert "interrupted" in stderr and "--resume" in stderr
    assert cell_pid is not None and process_gone(cell_pid)
    done = [event["index"] for event in recording.events_of("observation")]
    done += [event["index"] for event in recording.events_of("waypoint_skipped")]
    assert set(range(3)) <= set(done) and len(done) < WAYPOINTS
    assert recording.events_of("abort")[-1]["cause"] == "interrupted"
    assert not run.result_written

    resumed = run.resumed
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
        capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL, cwd=out,
    )
    assert replay.returncode == ExitCode.OK, replay.stderr[-3000:]
    np.testing.assert_allclose(
        np.array(json.loads(replay.stdout)["T_base_laser"]), np.array(live["T_base_laser"]), rtol=0, atol=1e-9
    )


def test_scanner_drop_at_a_waypoint_repeats_that_waypoint(scanner_drop_engine_run: EngineDryRun) -> None:
    """The scene fault drops the scanner's connection during waypoint 2's dwell: the driver
    reconnects, the dwell is repeated and the run completes (the run: the fixture above)."""
    recording = read_session(scanner_drop_engine_run.out / "session.mcap")
    dwells = [event["index"] for event in recording.events_of("dwell_start")]
    retries = [event["index"] for event in recording.events_of("waypoint_retry")]
    assert dwells.count(2) == 2 and 2 in retries, (dwells, retries)
    # A loaded machine may stall the stream elsewhere too: a dwell repeats only as a recorded retry.
    assert all(dwells.count(i) == 1 + retries.count(i) for i in set(dwells)), (dwells, retries)
    assert scanner_drop_engine_run.report.document()["observations"] >= WAYPOINTS - 3


def test_engine_and_cli_give_the_same_document_and_files(
    scanner_drop_engine_run: EngineDryRun, interrupted_dry_run: InterruptedDryRun
) -> None:
    """The engine's dry run of the tests' job against the CLI's (the fixtures above; the
    engine's rides out a dropped scanner connection, the CLI's was interrupted and resumed:
    neither changes the document's fields, the files or the scene)."""
    report, events = scanner_drop_engine_run.report, scanner_drop_engine_run.events
    cli = interrupted_dry_run.resumed
    assert cli.returncode == 0, cli.stderr[-3000:]
    from_cli, from_engine = json.loads(cli.stdout), report.document()
    assert from_engine.keys() == from_cli.keys()
    assert from_engine["passed"] and from_cli["passed"]
    assert {Path(p).name for p in from_engine["outputs"].values()} == {
        Path(p).name for p in from_cli["outputs"].values()
    }
    # Two runs of one scene differ only by scan noise: within a few reported std.
    difference_mm = 1000 * np.abs(np.subtract(from_engine["translation_m"], from_cli["translation_m"]))
    combined_std_mm = np.hypot(from_engine["std_translation_mm"], from_cli["std_translation_mm"])
    assert np.all(difference_mm < 4 * combined_std_mm + 0.5)
    assert from_engine["ground_truth"]["error"]["translation_mm"] < 5.0

    seqs = [event.seq for event in events]
    assert seqs == list(range(1, len(events) + 1))
    kinds = {event.kind for event in events}
    assert {"stage", "progress", "centre", "scan", "result"} <= kinds
    scans = [event for event in events if event.kind == "scan"]
    assert len(scans) == from_engine["observations"] + len(from_engine["skipped"])
    picture = scans[0].data
    assert len(picture["ranges_m"]) == 1081 and picture["rod_beams"] and picture["circle"] is not None
    json.dumps([event.as_dict() for event in events], allow_nan=False)  # every event is JSON-ready
    last_progress = [event for event in events if event.kind == "progress"][-1].data
    assert last_progress["completed"] == last_progress["waypoint_count"]
    assert events[-1].kind == "result" and events[-1].data["passed"] is True


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


@pytest.fixture(scope="module")
def unmoved_cell() -> Iterator[FakeCellProcess]:
    """A fake cell the prompt tests connect to and never move (one start for both answers)."""
    with FakeCellProcess() as cell:
        yield cell


@pytest.mark.parametrize("answer", ["no", "sigterm"])
def test_operator_declining_or_terminating_at_the_prompt_moves_nothing(
    tmp_path: Path, answer: str, unmoved_cell: FakeCellProcess
) -> None:
    job = write_job(tmp_path)
    with job.open("a") as file:  # a live run needs to know roughly where the scanner is
        file.write("[scanner.nominal]\ntranslation_m = [0.30, 0.50, 0.20]\neuler_zyx_deg = [5.0, 7.0, 3.0]\n")
    out = tmp_path / "out"
    controller, terminal = pty.openpty()
    try:
        process = subprocess.Popen(
            lasercal("--robot", unmoved_cell.robot_host, "--scanner", unmoved_cell.scanner_url,
                     "--config", str(job), "--out", str(out)),
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


def test_a_dry_run_records_the_fake_robots_own_calibration(scanner_drop_engine_run: EngineDryRun) -> None:
    """result.json and session.mcap carry the kinematics calibration the fake controller's
    primary interface reported (the run: the fixture above)."""
    expected = fake_robot_calibration().as_dict()
    result = json.loads((scanner_drop_engine_run.out / "result.json").read_text())
    assert result["run"]["robot_calibration"] == expected
    assert read_session(scanner_drop_engine_run.out / "session.mcap").meta["robot_calibration"] == expected
    said = [e.message for e in scanner_drop_engine_run.events if e.kind == "stage"]
    assert f"robot kinematics calibration: UR5e, checksum {expected['checksum']}" in said
