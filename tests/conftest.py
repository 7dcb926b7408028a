"""Set-ups shared by several test modules because they are expensive: each is made once
per test session and only read by the tests that use it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

#: Where a finished ``lasercal run --dry-run --json`` wrote its files, and how it ended.
DryRunResult = tuple[Path, subprocess.CompletedProcess[str]]


@pytest.fixture(scope="session")
def scanner_drop_dry_run(tmp_path_factory: pytest.TempPathFactory) -> DryRunResult:
    """One ``lasercal run --dry-run --json`` of the tests' short job whose scanner drops its
    connection during waypoint 2's dwell (a scene fault). The scanner-drop test checks the
    repeated dwell; the engine test compares its document and files with the engine's."""
    from tests.test_dry_run import write_job

    folder = tmp_path_factory.mktemp("scanner-drop")
    scene = folder / "scene.toml"
    scene.write_text("[faults]\nscanner_drop_at_waypoint = 2\n")
    out = folder / "out"
    command = [sys.executable, "-m", "lasercal_hw.cli.main", "run", "--dry-run", "--json",
               "--config", str(write_job(folder)), "--scene", str(scene), "--out", str(out)]
    result = subprocess.run(
        command, capture_output=True, text=True, timeout=200, stdin=subprocess.DEVNULL, cwd=folder
    )
    return out, result
