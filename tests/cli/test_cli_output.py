"""What a person sees of a run in a terminal and in a log: lines that stand alone, no progress
bar glued to a message, no spinner before an early error, paths never broken."""

from __future__ import annotations

import io
from pathlib import Path

import pytest
from rich.console import Console

from lasercal_hw.cli import run as cli_run
from lasercal_hw.run.events import RunEvent
from tests.cli_helpers import assert_one_line_error, run_cli

PROGRESS = {
    "stage": "dwell", "waypoint": 3, "waypoint_count": 20, "completed": 3, "scans_averaged": None,
    "time_left_s": 159.0,
}


def _events() -> list[RunEvent]:
    return [
        RunEvent(1, "stage", "connecting to the scanner and the robot", {"stage": "connect"}),
        RunEvent(2, "progress", "dwelling 3 s at waypoint 3", PROGRESS),
        RunEvent(3, "centre", "waypoint 3: rod at (+0.1000, +1.2000) m from 120 scans", {}),
        RunEvent(4, "progress", "moving to waypoint 4", PROGRESS | {"stage": "move", "waypoint": 4}),
        RunEvent(5, "stopped", "recording kept in out/session.mcap; resume this run from its recording",
                 {"session": "out/session.mcap", "resumable": True, "interrupted": True, "dry_run": True}),
    ]


def _render(monkeypatch: pytest.MonkeyPatch, *, terminal: bool) -> str:
    """stdout and stderr as two consoles writing into one buffer, as a terminal shows them."""
    screen = io.StringIO()
    console = Console(file=screen, force_terminal=terminal, width=80, soft_wrap=True)
    monkeypatch.setattr(cli_run, "err_console", Console(file=screen, force_terminal=terminal, soft_wrap=True))
    with cli_run.ProgressView(console) as view:
        for event in _events():
            view(event)
    return screen.getvalue()


def test_on_a_terminal_the_stopped_line_is_never_glued_to_the_bar(monkeypatch: pytest.MonkeyPatch) -> None:
    screen = _render(monkeypatch, terminal=True)
    assert "s left" in screen  # the bar was shown
    lines = screen.splitlines()
    stopped = [line for line in lines if "recording kept in" in line]
    assert len(stopped) == 1 and stopped[0].lstrip("\x1b[?25h\r").startswith("recording kept in"), lines[-3:]


def test_a_log_gets_the_lines_and_no_bar(monkeypatch: pytest.MonkeyPatch) -> None:
    screen = _render(monkeypatch, terminal=False)
    assert screen.splitlines() == [
        "connecting to the scanner and the robot",
        "waypoint 3: rod at (+0.1000, +1.2000) m from 120 scans",
        "recording kept in out/session.mcap; continue with: lasercal run --resume out/session.mcap",
    ]


def test_an_early_error_is_one_line_without_a_spinner(tmp_path: Path) -> None:
    result = run_cli("run", "--dry-run", "--yes", "--resume", str(tmp_path / "missing" / "session.mcap"))
    assert_one_line_error(result, 2, "session.mcap")
    assert result.stdout == ""


def test_a_long_path_is_never_broken_in_a_log(tmp_path: Path) -> None:
    deep = tmp_path.joinpath(*[f"folder-{i:02d}-with-a-long-name" for i in range(6)], "observations.csv")
    result = run_cli("solve", str(deep))
    assert_one_line_error(result, 2, str(deep))


def test_a_cell_jobs_lines_name_their_scanner(monkeypatch: pytest.MonkeyPatch) -> None:
    """Two scanners' runs print alike: each line is led by the scanner its run is of, and the
    cell's own result line, which names it, is left as it is."""
    screen = io.StringIO()
    monkeypatch.setattr(cli_run, "err_console", Console(file=screen, force_terminal=False, soft_wrap=True))
    with cli_run.ProgressView(Console(file=screen, force_terminal=False, width=80, soft_wrap=True)) as view:
        centre = "waypoint 3: rod at (+0.1000, +1.2000) m from 40 scans"
        view(RunEvent(1, "centre", centre, {"scanner": "rear"}))
        view(RunEvent(2, "scanner_result", "scanner rear: passed", {"scanner": "rear", "passed": True}))
    assert screen.getvalue().splitlines() == [
        "rear: waypoint 3: rod at (+0.1000, +1.2000) m from 40 scans",
        "scanner rear: passed",
    ]
