"""``Scene.to_toml`` writes the scene file the fake cell reads: every scene round-trips."""

from __future__ import annotations

from pathlib import Path

import pytest

from fakes.scene import load_scene, parse_scene, scene_from_mapping
from lasercal_hw.errors import ConfigError
from lasercal_hw.models import RodLine
from lasercal_hw.run.dry_run_scene import write_rod_scene


def test_default_scene_round_trips() -> None:
    scene = load_scene(None)
    assert parse_scene(scene.to_toml()) == scene


def test_a_changed_scene_round_trips_with_faults_strings_and_exact_floats() -> None:
    scene = scene_from_mapping(
        {
            "rod": {"radius_m": 0.1 + 0.2, "origin_m": [1e-7, -0.0, 3.0]},
            "faults": {"protective_stop_at_waypoint": 3, "scanner_stale_field": 'AFRT="560"'},
            "walls": [{"name": "only", "start_m": [0.0, 0.0], "end_m": [1.0, 0.0]}],
        }
    )
    read = parse_scene(scene.to_toml())
    assert read == scene and read.rod.radius_m == 0.1 + 0.2 and len(read.walls) == 1


def test_the_dry_run_scene_is_the_default_scene_holding_the_jobs_rod(tmp_path: Path) -> None:
    rod = RodLine(origin_m=[0.0, 0.0, 0.12], direction=[0.0, 0.0, 1.0], radius_m=0.0025, length_m=0.1)
    scene = load_scene(write_rod_scene(rod, tmp_path / "scene.toml"))
    default = load_scene(None)
    assert scene.rod.radius_m == 0.0025 and scene.rod.origin_m == [0.0, 0.0, 0.12]
    assert scene.model_copy(update={"rod": default.rod}) == default
    assert (scene.rod.shape, scene.rod.material) == ("cylinder", default.rod.material)


def test_the_dry_run_scene_of_a_fluted_rod_holds_a_steel_twist_drill(tmp_path: Path) -> None:
    rod = RodLine(radius_m=0.005, length_m=0.1, fluted=True)
    scene = load_scene(write_rod_scene(rod, tmp_path / "scene.toml"))
    assert (scene.rod.shape, scene.rod.material, scene.rod.radius_m) == ("twist_drill", "steel_drill", 0.005)


def test_a_bad_mapping_names_the_field() -> None:
    with pytest.raises(ConfigError, match=r"scene file request is invalid: rod\.radius_m"):
        scene_from_mapping({"rod": {"radius_m": -1}}, "request")
