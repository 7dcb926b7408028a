"""The semicircle generator: arc geometry, tilt pattern, seeding, parameter errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import rotation_angle_rad
from lasercal_hw.models import RodLine
from trajectories.plane_crossing import horizontal_plane, rod_plane_crossings
from trajectories.semicircles import (
    SemicircleParameters,
    hint_plane,
    parse_semicircle_parameters,
    semicircle_waypoints,
    tool_orientation,
)
from trajectories.waypoint import waypoint_matrices

PARAMS = SemicircleParameters(
    centre_m=(0.6, -0.1), radii_m=(0.2, 0.3), heights_m=(0.35, 0.3), start_deg=90.0, end_deg=270.0
)


def test_two_semicircles_every_20_degrees_give_ten_waypoints_each() -> None:
    waypoints = semicircle_waypoints(PARAMS)
    assert [w.index for w in waypoints] == list(range(20))
    positions = np.array([w.tcp_pose[:3] for w in waypoints])
    radii = np.hypot(positions[:, 0] - 0.6, positions[:, 1] + 0.1)
    np.testing.assert_allclose(radii[:10], 0.2, atol=1e-12)
    np.testing.assert_allclose(radii[10:], 0.3, atol=1e-12)
    np.testing.assert_allclose(positions[:10, 2], 0.35)
    np.testing.assert_allclose(positions[10:, 2], 0.3)
    angles = np.degrees(np.arctan2(positions[:, 1] + 0.1, positions[:, 0] - 0.6)) % 360.0
    np.testing.assert_allclose(angles[:10], np.arange(90.0, 271.0, 20.0), atol=1e-9)
    # The second arc runs back, so the robot continues from where the first one ended.
    np.testing.assert_allclose(angles[10:], np.arange(270.0, 89.0, -20.0), atol=1e-9)


def test_arc_angles_include_the_end_only_when_the_step_lands_on_it() -> None:
    assert PARAMS.model_copy(update={"step_deg": 60.0}).arc_angles_deg() == [90.0, 150.0, 210.0, 270.0]
    assert PARAMS.model_copy(update={"step_deg": 50.0}).arc_angles_deg() == [90.0, 140.0, 190.0, 240.0]
    backwards = PARAMS.model_copy(update={"start_deg": 270.0, "end_deg": 90.0, "step_deg": 90.0})
    assert backwards.arc_angles_deg() == [270.0, 180.0, 90.0]


def test_every_tool_points_down_tilted_by_exactly_tilt_deg() -> None:
    matrices = waypoint_matrices(semicircle_waypoints(PARAMS))
    tool_z = matrices[:, :3, 2]
    tilt_deg = np.degrees(np.arccos(np.clip(-tool_z[:, 2], -1.0, 1.0)))
    np.testing.assert_allclose(tilt_deg, PARAMS.tilt_deg, atol=1e-9)


def test_tilt_directions_change_and_cover_all_sides() -> None:
    matrices = waypoint_matrices(semicircle_waypoints(PARAMS))
    # Direction in which each rod end swings, in the base x-y plane.
    swing = np.degrees(np.arctan2(matrices[:, 1, 2], matrices[:, 0, 2]))
    steps = np.abs((np.diff(swing) + 180.0) % 360.0 - 180.0)
    assert np.all(steps > 90.0), "neighbouring waypoints must tilt in clearly different directions"
    sectors = set(np.floor(((swing + 360.0) % 360.0) / 45.0).astype(int))
    assert sectors == set(range(8)), "the tilts must point into all eight 45-degree sectors"


def test_untilted_tool_points_straight_down_with_x_along_the_yaw() -> None:
    rotation = tool_orientation(30.0, 0.0, 0.0)
    np.testing.assert_allclose(rotation[:, 2], [0.0, 0.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(rotation[:, 0], [math.cos(math.radians(30)), math.sin(math.radians(30)), 0.0])


def test_tilt_about_tool_x_swings_the_rod_towards_tool_minus_y() -> None:
    rotation = tool_orientation(0.0, 10.0, 0.0)
    # tool y is base -y when pointing down with zero yaw, so the rod end swings to base +y
    assert rotation[1, 2] > 0.0
    assert rotation_angle_rad(tool_orientation(0.0, 0.0, 0.0).T @ rotation) == pytest.approx(math.radians(10))


def test_seeded_tilts_are_reproducible_and_within_the_limit() -> None:
    seeded = PARAMS.model_copy(update={"seed": 42})
    first, again = semicircle_waypoints(seeded), semicircle_waypoints(seeded)
    assert first == again
    other = semicircle_waypoints(PARAMS.model_copy(update={"seed": 43}))
    assert first != other
    tool_z = waypoint_matrices(first)[:, :3, 2]
    tilt_deg = np.degrees(np.arccos(np.clip(-tool_z[:, 2], -1.0, 1.0)))
    assert np.all(tilt_deg <= PARAMS.tilt_deg + 1e-9)
    assert np.all(tilt_deg >= PARAMS.tilt_deg / 2 - 1e-9)


def test_default_pattern_is_deterministic() -> None:
    assert semicircle_waypoints(PARAMS) == semicircle_waypoints(PARAMS)


def test_labels_say_arc_angle_and_tilt() -> None:
    first = semicircle_waypoints(PARAMS)[0]
    assert first.label == "arc 1 at +90 deg, tilt 20.0 deg toward 0.0 deg"


def test_scan_plane_hint_is_checked_against_the_rod() -> None:
    ok = PARAMS.model_copy(update={"scan_plane_z_m": 0.2})
    waypoints = semicircle_waypoints(ok)
    crossings = rod_plane_crossings(waypoint_matrices(waypoints), RodLine(), horizontal_plane(0.2))
    assert crossings.within_rod.all()
    too_low_plane = PARAMS.model_copy(update={"scan_plane_z_m": -0.1})
    with pytest.raises(
        ConfigError, match=r"does not cross the scan plane hint z = -0\.100 m at waypoint\(s\) 0 "
    ):
        semicircle_waypoints(too_low_plane)
    # A longer rod reaches it.
    semicircle_waypoints(too_low_plane, RodLine(length_m=0.6))


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        ({"centre_m": [0.5, 0.0], "radii_m": [0.2, 0.3], "heights_m": [0.3]}, "give one height per radius"),
        ({"centre_m": [0.5, 0.0], "radii_m": [-0.2], "heights_m": [0.3]}, "radii_m must be positive"),
        (
            {"centre_m": [0.5, 0.0], "radii_m": [0.2], "heights_m": [0.3], "step_deg": 0},
            "step_deg: Input should be greater than 0",
        ),
        (
            {"centre_m": [0.5, 0.0], "radii_m": [0.2], "heights_m": [0.3], "tilt_deg": 80},
            "tilt_deg: Input should be less than or equal to 60",
        ),
        (
            {"centre_m": [0.5, 0.0], "radii_m": [0.2], "heights_m": [0.3], "end_deg": 10},
            "shorter than step_deg",
        ),
        (
            {"centre_m": [0.5, 0.0], "radii_m": [0.2], "heights_m": [0.3], "radius": 1},
            "radius: Extra inputs are not permitted",
        ),
        ({"radii_m": [0.2], "heights_m": [0.3]}, "centre_m: Field required"),
    ],
)
def test_bad_parameters_give_config_errors_naming_the_field(data: dict, expected: str) -> None:
    with pytest.raises(ConfigError, match=expected):
        parse_semicircle_parameters(data, source="job.toml [trajectory]")


def test_parameters_parse_from_plain_data() -> None:
    params = parse_semicircle_parameters({"centre_m": [0.5, 0.0], "radii_m": [0.2], "heights_m": [0.3]})
    assert len(semicircle_waypoints(params)) == 10


def test_height_slope_lays_the_arcs_parallel_to_a_sloping_plane() -> None:
    sloped = PARAMS.model_copy(update={"height_slope": (-0.12, 0.04), "scan_plane_z_m": 0.2})
    positions = np.array([w.tcp_pose[:3] for w in semicircle_waypoints(sloped)])
    flat = np.array([w.tcp_pose[:3] for w in semicircle_waypoints(PARAMS)])
    np.testing.assert_allclose(positions[:, :2], flat[:, :2])
    expected_z = flat[:, 2] - 0.12 * (flat[:, 0] - 0.6) + 0.04 * (flat[:, 1] + 0.1)
    np.testing.assert_allclose(positions[:, 2], expected_z, atol=1e-12)
    # The hint plane slopes with the arcs: every vertical rod of the sloped arcs crosses it at
    # the same distance along the rod as the flat arcs' rods cross the flat plane.
    plane = hint_plane(sloped)
    normal = plane[:3, 2]
    assert normal @ [0.12, -0.04, 1.0] / np.linalg.norm([0.12, -0.04, 1.0]) == pytest.approx(1.0)
    assert normal @ (positions[0] - plane[:3, 3]) > 0.0
    flat_plane = hint_plane(PARAMS.model_copy(update={"scan_plane_z_m": 0.2}))
    np.testing.assert_allclose(flat_plane, horizontal_plane(0.2) @ _shift(0.6, -0.1))
    down = RodLine(direction=np.array([0.0, 0.0, 1.0]))
    plain = PARAMS.model_copy(update={"tilt_deg": 0.0})
    sloped_plain = sloped.model_copy(update={"tilt_deg": 0.0})
    along_flat = rod_plane_crossings(waypoint_matrices(semicircle_waypoints(plain)), down, flat_plane)
    along_sloped = rod_plane_crossings(waypoint_matrices(semicircle_waypoints(sloped_plain)), down, plane)
    np.testing.assert_allclose(along_sloped.along_rod_m, along_flat.along_rod_m, atol=1e-9)


def _shift(x_m: float, y_m: float) -> np.ndarray:
    shift = np.eye(4)
    shift[:2, 3] = (x_m, y_m)
    return shift
