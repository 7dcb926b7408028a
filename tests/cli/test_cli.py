"""The command line itself: version, help, and the error-to-exit-code mapping."""

from __future__ import annotations

import subprocess
import sys


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "lasercal_hw.cli.main", *args],
        capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL,
    )


def test_version_prints_package_version() -> None:
    result = run_cli("--version")
    assert result.returncode == 0
    assert result.stdout.startswith("lasercal ")


def test_help_lists_commands() -> None:
    result = run_cli("--help")
    assert result.returncode == 0
    assert "Usage" in result.stdout


def test_usage_errors_are_one_line_with_exit_code_2() -> None:
    result = run_cli("simulate", "--trials", "abc")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "--trials" in lines[0] and "lasercal simulate --help" in lines[0]
    assert "Traceback" not in result.stderr


def test_unknown_command_names_it() -> None:
    result = run_cli("calibrate-now")
    assert result.returncode == 2
    assert "calibrate-now" in result.stderr
