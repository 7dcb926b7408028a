"""``lasercal run``: refusals that must happen before anything connects or moves."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fakes.world import World
from lasercal_hw.config import load_job
from lasercal_hw.errors import ExitCode
from lasercal_hw.run.dry_run_scene import write_rod_scene
from tests.cli_helpers import assert_one_line_error

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def run_cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "lasercal_hw.cli.main", "run", *args],
        capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL, cwd=cwd,
    )


def test_refuses_to_move_without_yes_when_stdin_is_not_a_terminal(tmp_path: Path) -> None:
    result = run_cli("--robot", "127.0.0.9", cwd=tmp_path)
    assert result.returncode == ExitCode.BAD_INPUT
    assert "standard input is not a terminal" in result.stderr
    assert "--yes" in result.stderr
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "lasercal-out").exists()


def test_bad_job_file_is_reported_with_file_and_field(tmp_path: Path) -> None:
    job = tmp_path / "job.toml"
    job.write_text("[rod]\nradius_mm = 20\n")
    result = run_cli("--robot", "127.0.0.9", "--yes", "--config", str(job), cwd=tmp_path)
    assert result.returncode == ExitCode.BAD_INPUT
    assert "rod.radius_mm: unknown field" in result.stderr
    assert str(job) in result.stderr


def test_resume_refuses_a_new_job(tmp_path: Path) -> None:
    result = run_cli("--yes", "--resume", str(tmp_path / "session.mcap"), "--dwell", "1", cwd=tmp_path)
    assert result.returncode == ExitCode.BAD_INPUT
    assert "--resume continues the recorded job" in result.stderr


def test_scene_needs_dry_run(tmp_path: Path) -> None:
    result = run_cli("--yes", "--robot", "127.0.0.9", "--scene", "x.toml", cwd=tmp_path)
    assert result.returncode == ExitCode.BAD_INPUT
    assert "--scene only applies to --dry-run" in result.stderr



@pytest.mark.parametrize("command", ["run", "verify"])
@pytest.mark.parametrize(
    ("scene_text", "fragments"),
    [(None, ("nope.toml", "does not exist")), ("[rod\n", ("nope.toml", "not valid TOML"))],
)
def test_a_scene_file_is_checked_before_a_fake_cell_starts(
    tmp_path: Path, command: str, scene_text: str | None, fragments: tuple[str, ...]
) -> None:
    """A missing or broken --scene is bad input (exit 2) naming the file, not a device error
    after a fake cell started."""
    if scene_text is not None:
        (tmp_path / "nope.toml").write_text(scene_text)
    calibration = ("--calibration", str(tmp_path / "result.json")) if command == "verify" else ()
    result = subprocess.run(
        [sys.executable, "-m", "lasercal_hw.cli.main", command, "--dry-run", "--yes", "--scene", "nope.toml",
         *calibration],
        capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL, cwd=tmp_path,
    )
    assert_one_line_error(result, ExitCode.BAD_INPUT, "--scene", *fragments)
    assert not (tmp_path / "lasercal-out").exists()

def test_dry_run_scene_gives_the_fake_cell_the_jobs_rod(tmp_path: Path) -> None:
    job = load_job(Path(__file__).parents[2] / "examples" / "drill.toml")
    scene = write_rod_scene(job.rod.rod_line(), tmp_path / "dry_run_scene.toml")
    world_rod = World.from_scene(scene).rod
    job_rod = job.rod.rod_line()
    np.testing.assert_array_equal(world_rod.origin_m, job_rod.origin_m)
    np.testing.assert_array_equal(world_rod.direction, job_rod.direction)
    assert (world_rod.radius_m, world_rod.length_m) == (job_rod.radius_m, job_rod.length_m) == (0.005, 0.10)


def test_the_stopped_line_gives_the_command_that_resumes_the_recording() -> None:
    from lasercal_hw.cli.run import stopped_line

    interrupted_dry_run = {
        "session": "out/session.mcap", "resumable": True, "interrupted": True, "dry_run": True,
    }
    assert stopped_line("", interrupted_dry_run) == (
        "recording kept in out/session.mcap; continue with: lasercal run --resume out/session.mcap"
    )
    failed_live = interrupted_dry_run | {"interrupted": False, "dry_run": False}
    assert stopped_line("", failed_live).endswith(
        "after fixing the cause, continue with: lasercal run --resume out/session.mcap"
    )
    not_resumable = failed_live | {"resumable": False}
    assert stopped_line("", not_resumable) == "recording kept in out/session.mcap; start again"
    assert stopped_line("nothing was recorded", {"error": "boom"}) == "nothing was recorded"


@pytest.mark.parametrize(
    ("args", "fragments"),
    [
        (("--dry-run", "--scanner", "front"), ("one scanner, 'default', not 'front'",)),
        (("--dry-run", "--config", str(EXAMPLES / "cell.toml"), "--scanner", "side"),
         ("no scanner 'side'", "front, rear")),
        (("--dry-run", "--config", str(EXAMPLES / "cell.toml")), ("needs --scene", "two_scanners.toml")),
    ],
)
def test_a_scanner_named_on_the_command_line_must_be_the_jobs(
    tmp_path: Path, args: tuple[str, ...], fragments: tuple[str, ...]
) -> None:
    """``--scanner NAME`` picks one of the job's scanners (a one-scanner job's is 'default'),
    and a dry run of a cell job needs a scene of its scanners; nothing moves otherwise."""
    assert_one_line_error(run_cli(*args, cwd=tmp_path), ExitCode.BAD_INPUT, *fragments)
    assert not any(tmp_path.iterdir())
