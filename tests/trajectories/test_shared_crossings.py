"""Shared crossings of a cell (trajectories/shared.py): waypoints of one scanner whose rod also
crosses another scanner's plane inside the distances that scanner is calibrated at, so the
cell's agreement test has centres it can use; and the example cell's waypoint file has them."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from lasercal_hw.cli.main import app
from lasercal_hw.config import load_job
from lasercal_hw.errors import ExitCode
from lasercal_hw.models import ScanGeometry
from lasercal_hw.run.watchers import Watcher, expected_crossing
from lasercal_hw.run.waypoints import job_waypoint_list
from lasercal_hw.ur_kinematics import UR5, inverse_kinematics_pose
from tests.doubles import UTM_GEOMETRY
from trajectories.candidates import END_MARGIN_M
from trajectories.checks import check_waypoints
from trajectories.plane_crossing import rod_plane_crossings
from trajectories.waypoint import waypoint_matrices
from trajectories.waypoint_file import load_waypoints

REPO = Path(__file__).resolve().parents[2]
CELL = REPO / "examples" / "cell.toml"
runner = CliRunner()


def _crossings_in(name: str, waypoints: list, job_file: Path = CELL):
    """Where the rod of each waypoint crosses scanner ``name``'s nominal plane."""
    job = load_job(job_file).for_scanner(name)
    assert job.scanner.nominal is not None
    return rod_plane_crossings(waypoint_matrices(waypoints), job.rod.rod_line(), job.scanner.nominal.matrix())


class _Beams:
    """A UTM-30LX-EW's beam layout, for ``expected_crossing``."""

    def geometry(self) -> ScanGeometry:
        return UTM_GEOMETRY


@pytest.fixture(scope="module")
def designed(tmp_path_factory: pytest.TempPathFactory) -> tuple[list, tuple[float, float]]:
    """The documented command, 12 of front's own waypoints and 3 shared with rear (about 10 s)."""
    out = tmp_path_factory.mktemp("shared") / "front.csv"
    result = runner.invoke(app, ["trajectory", "design", "--config", str(CELL), "--scanner", "front",
                                 "--shared-with", "rear", "--shared", "3", "--waypoints", "12",
                                 "--out", str(out), "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["notes"] == []
    rear_span = _crossings_in("rear", job_waypoint_list(load_job(CELL).for_scanner("rear"))).range_m
    return load_waypoints(out), (float(rear_span.min()), float(rear_span.max()))


def test_shared_waypoints_cross_the_other_plane_inside_its_span_and_keep_every_rule(designed) -> None:
    waypoints, (low, high) = designed
    labelled = [w for w in waypoints if w.label.startswith("shared with rear")]
    assert len(labelled) == 3 and len(waypoints) == 12 + 3
    assert [w.index for w in waypoints] == list(range(len(waypoints)))
    rear = _crossings_in("rear", labelled)
    assert np.all((rear.range_m >= low) & (rear.range_m <= high))
    job = load_job(CELL)
    assert np.all((rear.along_rod_m >= END_MARGIN_M) & (rear.along_rod_m <= job.rod.length_m - END_MARGIN_M))
    front = _crossings_in("front", labelled)
    assert np.all(front.within_rod)
    report = check_waypoints(
        waypoints, inverse_kinematics=lambda pose: inverse_kinematics_pose(pose, model=UR5),
        workspace=job.workspace, rod=job.rod.rod_line(),
    )
    assert report.ok, report.summary()


def test_the_example_cells_front_waypoints_let_rear_watch_inside_its_span() -> None:
    """examples/cell/front-waypoints.csv (made with the command in docs/cell.md) has at least
    3 waypoints where rear's nominal pose puts the rod in its view at the distances rear's own
    waypoints span: where the agreement test uses rear's centre."""
    cell = load_job(CELL)
    front_waypoints = job_waypoint_list(cell.for_scanner("front"))
    rear_span = _crossings_in("rear", job_waypoint_list(cell.for_scanner("rear"))).range_m
    rear = _crossings_in("rear", front_waypoints)
    nominal = cell.for_scanner("rear").scanner.nominal
    assert nominal is not None
    watcher = Watcher("rear", _Beams(), nominal.matrix())  # type: ignore[arg-type]
    rod = cell.rod.rod_line()
    seen = [
        w for w, range_m in zip(front_waypoints, rear.range_m, strict=True)
        if expected_crossing(watcher, w.pose_array(), rod) is not None
        and rear_span.min() <= range_m <= rear_span.max()
    ]
    assert len(seen) >= 3
    assert all(w.label.startswith("shared with rear") for w in seen)


def test_shared_with_the_scanner_itself_is_refused_in_one_line(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "lasercal_hw.cli.main", "trajectory", "design", "--config", str(CELL),
         "--scanner", "front", "--shared-with", "front", "--out", str(tmp_path / "w.csv")],
        capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL,
    )
    assert result.returncode == ExitCode.BAD_INPUT
    assert "--shared-with front: name another scanner of the job than --scanner" in result.stderr
    assert "Traceback" not in result.stderr and not (tmp_path / "w.csv").exists()
