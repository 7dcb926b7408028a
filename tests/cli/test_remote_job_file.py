"""``lasercal remote calibrate --config FILE`` sends FILE's job as ``lasercal run --config FILE``
reads it: a relative waypoint file is the one beside FILE, not one in the daemon's folder."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from lasercal_hw.service.client import DaemonClient
from lasercal_hw.service.config import load_daemon_config
from lasercal_hw.service.daemon import Daemon
from tests.cli_helpers import run_cli
from tests.daemon_helpers import FakeEngine, fake_runners, served_in_thread

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def test_a_job_files_relative_waypoint_file_is_the_one_beside_it(tmp_path: Path) -> None:
    """docs/daemon.md's drill recalibration: the daemon's default job is a copy of
    examples/drill.toml with its waypoints beside it, and the script sends that job file. Its
    `waypoints_file = "drill-waypoints.csv"` went as written and the daemon read it against its
    own working folder, so the request was refused (422) though the file lies where it must."""
    jobs = tmp_path / "jobs"
    jobs.mkdir()
    for name in ("drill.toml", "drill-waypoints.csv"):
        shutil.copy(EXAMPLES / name, jobs / name)
    settings = {"data_dir": tmp_path / "data", "default_job": jobs / "drill.toml", "robot_host": "127.0.0.1"}
    config = load_daemon_config(None, settings)
    daemon = Daemon(config, runners=fake_runners(FakeEngine(waypoints=2)))
    with served_in_thread(daemon) as url:
        taken = run_cli("remote", "calibrate", "--config", str(jobs / "drill.toml"), "--activate", "--yes",
                        "--json", "--daemon", url, env={"LASERCAL_TOKEN": daemon.token})
        assert taken.returncode == 0, taken.stderr
        job = json.loads(taken.stdout)
        waypoints_file = job["request"]["resolved_job"]["trajectory"]["waypoints_file"]
        assert Path(waypoints_file) == (jobs / "drill-waypoints.csv").resolve()
        DaemonClient(url, daemon.token).wait(job["id"])
