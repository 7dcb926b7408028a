"""``lasercal trajectory list/show/check`` end to end."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from lasercal_hw.cli.main import app
from tests.drivers.ur.robot_process import in_process_robot
from trajectories.presets import preset_waypoints
from trajectories.waypoint_file import load_waypoints

runner = CliRunner()


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "lasercal_hw.cli.main", *args],
        capture_output=True,
        text=True,
        timeout=60,
        stdin=subprocess.DEVNULL,
    )


def test_list_names_every_preset_as_json() -> None:
    result = runner.invoke(app, ["trajectory", "list", "--json"])
    assert result.exit_code == 0, result.output
    listed = {entry["name"]: entry["waypoints"] for entry in json.loads(result.stdout)}
    assert listed == {"paper": 20, "compact": 20, "drill": 20, "quick": 10}


def test_show_default_preset_json_matches_the_library() -> None:
    result = runner.invoke(app, ["trajectory", "show", "--json"])
    assert result.exit_code == 0, result.output
    document = json.loads(result.stdout)
    assert document["source"] == "paper"
    assert document["rod"]["length_m"] == pytest.approx(0.3)
    expected = [w.model_dump(mode="json") for w in preset_waypoints("paper")]
    assert document["waypoints"] == json.loads(json.dumps(expected))


def test_show_table_lists_waypoints() -> None:
    result = runner.invoke(app, ["trajectory", "show", "quick"])
    assert result.exit_code == 0, result.output
    assert "+0.6387" in result.stdout and "quick" in result.stdout


def test_show_and_check_a_waypoint_file(tmp_path: Path) -> None:
    file = tmp_path / "mine.csv"
    file.write_text("index,x,y,z,rx,ry,rz\n0,0.45,-0.2,0.35,3.1416,0,0\n1,1.6,0,0.35,3.1416,0,0\n")
    shown = runner.invoke(app, ["trajectory", "show", "--file", str(file), "--json"])
    assert [w["index"] for w in json.loads(shown.stdout)["waypoints"]] == [0, 1]
    checked = runner.invoke(app, ["trajectory", "check", "--file", str(file), "--json"])
    assert checked.exit_code == 2
    report = json.loads(checked.stdout)
    assert report["ok"] is False
    assert {p["index"] for p in report["problems"]} == {1}
    assert "0" in report["joint_solutions_rad"]


def test_check_default_preset_passes() -> None:
    result = runner.invoke(app, ["trajectory", "check"])
    assert result.exit_code == 0, result.output
    assert "all 20 waypoints are reachable" in result.stdout


def test_check_with_a_tight_box_fails_with_exit_code_2_and_lists_waypoints() -> None:
    result = run_cli("trajectory", "check", "drill", "--box-min", "0.4,-1,0")
    assert result.returncode == 2
    assert "3 of 20 waypoints fail" in result.stdout
    assert "waypoint 12" in result.stdout


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["trajectory", "show", "nope"], "unknown trajectory preset 'nope'"),
        (["trajectory", "check", "--box-min", "1,1,1"], "min 1.0 m must be below max 0.95 m"),
        (["trajectory", "show", "--file", "/nonexistent/w.csv"], "does not exist"),
    ],
)
def test_bad_input_is_one_line_and_exit_code_2(args: list[str], message: str) -> None:
    result = run_cli(*args)
    assert result.returncode == 2
    assert message in result.stderr
    assert "Traceback" not in result.stderr


def test_check_with_the_robots_own_kinematics_reads_its_primary_interface() -> None:
    """``--robot HOST``: the fake controller's calibration (read only, over its primary port)."""
    with in_process_robot() as robot:
        result = runner.invoke(app, ["trajectory", "check", "quick", "--robot", robot.address, "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["ok"] is True
    assert "kinematics: the robot's own calibration (UR5e, checksum 5ec0a1d1-" in result.stderr
    unreachable = run_cli("trajectory", "check", "--robot", "127.0.0.254")  # nothing listens there
    assert unreachable.returncode == 3, unreachable.stderr
    assert "cannot reach the robot's primary interface at 127.0.0.254:30011" in unreachable.stderr


EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.mark.parametrize(
    ("example", "choice", "table"),
    [
        ("rod.toml", ["--scanner-pose", "0.35", "-0.55", "0.15", "10", "-3", "2"], "trajectory"),
        ("cell.toml", ["--scanner", "rear"], "scanners.rear.trajectory"),
    ],
)
def test_design_prints_the_waypoints_file_line_that_the_job_resolves_to_the_written_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, example: str, choice: list[str], table: str
) -> None:
    """A job reads a relative waypoints_file from its own folder, not from where `trajectory
    design` ran: the line the design prints must point at the file it wrote."""
    (tmp_path / "jobs").mkdir()
    shutil.copy(EXAMPLES / example, tmp_path / "jobs" / example)
    monkeypatch.chdir(tmp_path)
    args = ["trajectory", "design", "--config", f"jobs/{example}", "--waypoints", "6", "--out", "new.csv"]
    result = runner.invoke(app, [*args, *choice])
    assert result.exit_code == 0, result.output
    line = re.search(rf'\[{re.escape(table)}\] waypoints_file = "([^"]+)"', " ".join(result.stdout.split()))
    assert line is not None, result.stdout
    assert (tmp_path / "jobs" / line[1]).resolve() == (tmp_path / "new.csv").resolve()


def test_design_never_overwrites_a_file_unless_forced(tmp_path: Path) -> None:
    """An existing --out (a waypoint file a job uses, say) is kept: exit 2 naming it and --force,
    before the design runs; with --force it is replaced."""
    out = tmp_path / "waypoints.csv"
    out.write_text("precious\n")
    pose = ["--scanner-pose", "0.35", "-0.55", "0.15", "10", "-3", "2", "--waypoints", "6", "--out", str(out)]
    refused = run_cli("trajectory", "design", *pose)
    assert refused.returncode == 2, refused.stderr
    lines = refused.stderr.strip().splitlines()
    assert len(lines) == 1 and f"{out} already exists" in lines[0] and "--force" in lines[0], refused.stderr
    assert out.read_text() == "precious\n"
    forced = runner.invoke(app, ["trajectory", "design", *pose, "--force"])
    assert forced.exit_code == 0, forced.output
    assert out.read_text() != "precious\n" and len(load_waypoints(out)) == 6
