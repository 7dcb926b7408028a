"""Running the ``lasercal`` command as a user does, for the CLI tests."""

from __future__ import annotations

import os
import subprocess
import sys


def run_cli(
    *args: str, timeout_s: float = 120.0, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    """``lasercal ARGS`` in a fresh interpreter, no stdin (as in CI), output captured; ``env``
    adds to the environment."""
    return subprocess.run(
        [sys.executable, "-m", "lasercal_hw.cli.main", *args],
        capture_output=True, text=True, timeout=timeout_s, stdin=subprocess.DEVNULL,
        env=None if env is None else os.environ | env,
    )


def assert_one_line_error(result: subprocess.CompletedProcess[str], code: int, *fragments: str) -> None:
    """The command failed with exit ``code`` and one stderr line holding every fragment."""
    assert result.returncode == code, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "Traceback" not in result.stderr
    for fragment in fragments:
        assert fragment in lines[0]
