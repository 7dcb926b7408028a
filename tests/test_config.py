"""The job file: defaults, examples, and errors that name the file and the field."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from lasercal_hw.config import JobConfig, load_job, with_overrides
from lasercal_hw.errors import ConfigError
from lasercal_hw.run.waypoints import job_waypoint_list, job_waypoints

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def test_defaults_fit_the_papers_rod() -> None:
    job = JobConfig()
    assert job.dwell_s == 3.0
    assert job.rod.radius_m == 0.02
    assert job.trajectory.preset == "paper"
    assert job.scanner.url == "scip+tcp://192.168.0.10:10940"
    assert job.background_lift_m() == pytest.approx(0.35)
    assert load_job(None) == job


@pytest.mark.parametrize("name", ["rod.toml", "drill.toml"])
def test_examples_load(name: str) -> None:
    job = load_job(EXAMPLES / name)
    assert job.rod.rod_line().radius_m == job.rod.radius_m


def _field_paths(document: dict[str, Any], prefix: str = "") -> list[str]:
    """Dotted names of a job document's fields (a table's own, not the table)."""
    paths = []
    for key, value in document.items():
        if isinstance(value, dict) and value and key != "parameters":
            paths += _field_paths(value, f"{prefix}{key}.")
        else:
            paths.append(prefix + key)
    return paths


def test_the_rod_example_names_every_field() -> None:
    """The README: "examples/rod.toml lists every field with its default". It lacked 18 (the
    whole [verify] table, rod.polished and fluted, robot.model, the adaptive run's ...); a
    field without a default, or one another excludes, may be a commented line. A cell's
    [scanners.NAME] tables are examples/cell.toml's."""
    text = (EXAMPLES / "rod.toml").read_text(encoding="utf-8")
    fields = [path for path in _field_paths(JobConfig().model_dump(mode="json")) if path != "scanners"]
    missing = [
        path for path in fields
        if not re.search(rf"^#? *{re.escape(path.split('.')[-1])} += ", text, re.MULTILINE)
        and f"[{path}]" not in text
    ]
    assert missing == []


def test_drill_example_describes_an_offset_tilted_bit() -> None:
    rod = load_job(EXAMPLES / "drill.toml").rod.rod_line()
    assert rod.radius_m == 0.005
    assert np.allclose(rod.origin_m, [0.0, 0.03, 0.15])
    tilt_deg = np.degrees(np.arccos(rod.unit_direction() @ [0, 0, 1]))
    assert 0.5 < tilt_deg < 10


def test_unknown_field_names_file_and_field(tmp_path: Path) -> None:
    path = tmp_path / "job.toml"
    path.write_text("[rod]\nradius = 0.01\n")
    with pytest.raises(ConfigError) as caught:
        load_job(path)
    assert f"{path}: rod.radius: unknown field" in str(caught.value)


def test_every_bad_value_is_listed(tmp_path: Path) -> None:
    path = tmp_path / "job.toml"
    path.write_text(
        "dwell_s = -1\n[motion]\nspeed_m_s = 3.0\n[rod]\ndirection = [0, 0, 0]\n"
        "[workspace]\nmin_m = [0, 0, 0]\nmax_m = [1, 1]\n"
    )
    with pytest.raises(ConfigError) as caught:
        load_job(path)
    message = str(caught.value)
    for field in ("dwell_s", "motion.speed_m_s", "rod.direction", "workspace.max_m"):
        assert f"{path}: {field}:" in message


def test_not_toml_and_missing_file_are_config_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("dwell_s = = 3\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_job(bad)
    with pytest.raises(ConfigError, match="does not exist"):
        load_job(tmp_path / "missing.toml")


def test_preset_and_waypoint_file_are_exclusive(tmp_path: Path) -> None:
    path = tmp_path / "job.toml"
    path.write_text('[trajectory]\npreset = "paper"\nwaypoints_file = "w.csv"\n')
    with pytest.raises(ConfigError, match="either preset or waypoints_file"):
        load_job(path)


def test_waypoint_file_is_relative_to_the_job_file(tmp_path: Path) -> None:
    (tmp_path / "w.csv").write_text(
        "index,x,y,z,rx,ry,rz\n0,0.5,0,0.3,3.14159,0,0\n# comment\n\n1,0.6,0.1,0.3,3.1,0.1,0\n"
    )
    path = tmp_path / "job.toml"
    path.write_text('[trajectory]\nwaypoints_file = "w.csv"\n')
    job = load_job(path)
    assert job.trajectory.preset is None
    waypoints = job_waypoints(job)
    assert waypoints.shape == (2, 6)
    assert waypoints[1, 0] == pytest.approx(0.6)


def test_presets_give_waypoints_and_parameters_override_them(tmp_path: Path) -> None:
    assert job_waypoints(JobConfig()).shape == (20, 6)
    path = tmp_path / "job.toml"
    path.write_text('[trajectory]\npreset = "paper"\nparameters = { step_deg = 60.0 }\n')
    assert len(job_waypoint_list(load_job(path))) == 8
    path.write_text('[trajectory]\npreset = "nonesuch"\n')
    with pytest.raises(ConfigError, match="unknown trajectory preset 'nonesuch'"):
        job_waypoints(load_job(path))
    path.write_text('[trajectory]\npreset = "paper"\nparameters = { step_deg = -1.0 }\n')
    with pytest.raises(ConfigError, match="step_deg"):
        job_waypoints(load_job(path))


def test_bad_waypoint_file_names_the_line(tmp_path: Path) -> None:
    (tmp_path / "w.csv").write_text("index,x,y,z,rx,ry,rz\n0,0.5,0,0.3,3.14,0,0\n1,0.5,0,0.3,3.14,0\n")
    path = tmp_path / "job.toml"
    path.write_text('[trajectory]\nwaypoints_file = "w.csv"\n')
    with pytest.raises(ConfigError, match=r"w.csv line 3: expected 7 fields"):
        job_waypoints(load_job(path))


def test_overrides_are_validated() -> None:
    overrides = {"scanner.url": "scip+tcp://127.0.0.5:10940", "dwell_s": 0.5, "robot.host": None}
    job = with_overrides(JobConfig(), overrides)
    assert job.scanner.url == "scip+tcp://127.0.0.5:10940" and job.dwell_s == 0.5
    with pytest.raises(ConfigError, match="command line: dwell_s"):
        with_overrides(JobConfig(), {"dwell_s": 0})
    with pytest.raises(ConfigError, match=r"scanner\.url"):
        with_overrides(JobConfig(), {"scanner.url": "http://x"})
