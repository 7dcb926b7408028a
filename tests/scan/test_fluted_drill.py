"""A twist drill's section is no circle (issue 18, the drill job): the centres found on the
drill job's polished fluted bit must be covered by their covariance once the job says the
bit is fluted.  Short dwells of the fake cell's drill scene at the job's own waypoints, on
the physical model with its range error and the robot's error off, so that what is left is
the section's."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from benchmarks.dry_run_accuracy import dwell
from fakes.scene import load_scene
from fakes.world import World
from lasercal_hw.config import load_job
from lasercal_hw.geometry import pose_to_matrix
from lasercal_hw.run.retract import retract_candidates
from lasercal_hw.run.waypoints import listed_waypoints
from lasercal_hw.scan.extraction import ExtractionSettings, find_rod_centre

ROOT = Path(__file__).resolve().parents[2]
#: Waypoints of examples/drill.toml where a flute's hollow faces the scanner (37, 8, 13) or a
#: land (3, 22).
WAYPOINTS = (37, 8, 13, 3, 22)


@pytest.fixture(scope="module")
def drill_dwells() -> list[tuple[object, np.ndarray, np.ndarray, object]]:
    """(averaged scan, true centre, axis in the scanner, background) at each waypoint."""
    job = load_job(ROOT / "examples" / "drill.toml")
    waypoints = listed_waypoints(job)
    scene = load_scene(ROOT / "fakes" / "scenes" / "drill.toml")
    no_bias = {"unit_bias_m": 0.0, "near_bias_m": 0.0, "walk_m_per_efold": 0.0, "warm_at_start": True}
    exact_robot = {"robot_position_error_m": 0.0, "robot_rotation_error_deg": 0.0}
    scene = scene.model_copy(
        update={
            "physics": scene.physics.model_copy(update=no_bias),
            "noise": scene.noise.model_copy(update=exact_robot),
        }
    )
    world = World(scene)
    rng = np.random.default_rng(4)
    background = dwell(world, retract_candidates(job, waypoints)[0], 40, rng)
    out = []
    for index in WAYPOINTS:
        point, axis = world.rod_shape_in_scanner(pose_to_matrix(waypoints[index]))
        truth = (point - point[2] / axis[2] * axis)[:2]
        out.append((dwell(world, waypoints[index], 40, rng), truth, axis, background))
    return out


def _mahalanobis(dwells: list[tuple[object, np.ndarray, np.ndarray, object]], fluted: bool) -> np.ndarray:
    distances = []
    for averaged, truth, axis, background in dwells:
        found = find_rod_centre(
            averaged,  # type: ignore[arg-type]
            radius_m=0.005,
            background=background,  # type: ignore[arg-type]
            axis_in_scanner=axis,
            expected_uv_m=truth,
            fluted=fluted,
        )
        error = found.centre_uv_m - truth
        distances.append(float(np.sqrt(error @ np.linalg.solve(found.covariance_uv_m2, error))))
    return np.array(distances)


def test_a_flute_facing_the_scanner_puts_the_circle_fit_off_by_more_than_its_std(drill_dwells) -> None:
    # The echo comes from the flute's hollow, up to 4 mm behind the circle's front.
    as_circle = _mahalanobis(drill_dwells, fluted=False)
    assert as_circle[:3].max() > 3.0


def test_a_fluted_bits_centres_are_covered_by_their_covariance(drill_dwells) -> None:
    assert _mahalanobis(drill_dwells, fluted=True).max() < 2.5


def test_a_fluted_bits_centre_is_the_ray_fits_not_the_spot_fits(drill_dwells) -> None:
    # The spot fit models a diffuse circle; a polished drill returns its glint, and the flutes'
    # offsets were measured against ray fits (the drill job's p95 doubled with the spot's).
    rays = replace(ExtractionSettings(), fit_along_the_spot=False)
    for averaged, truth, axis, background in drill_dwells:
        common = {"background": background, "axis_in_scanner": axis, "expected_uv_m": truth}
        fluted = find_rod_centre(averaged, radius_m=0.005, fluted=True, **common)  # type: ignore[arg-type]
        as_rays = find_rod_centre(averaged, radius_m=0.005, fluted=True, settings=rays, **common)  # type: ignore[arg-type]
        assert np.allclose(fluted.centre_uv_m, as_rays.centre_uv_m, rtol=0.0, atol=1e-9)


def test_the_drill_job_says_its_bit_is_fluted() -> None:
    assert load_job(ROOT / "examples" / "drill.toml").rod.rod_line().fluted
