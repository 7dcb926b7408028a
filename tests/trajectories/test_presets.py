"""Every preset against the fake cell's default scene: the rod crosses the scanner's plane
inside its field of view, every waypoint is reachable by a UR5, the layout is safe, and
all six degrees of freedom of T_base_laser are observable."""

from __future__ import annotations

import numpy as np
import pytest

from lasercal_hw.config import WorkspaceConfig
from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import make_transform, rotvec_to_matrix, transform_points
from lasercal_hw.ur_kinematics import inverse_kinematics_pose
from tests.scene_geometry import FOV_HALF_RAD, T_BASE_LASER
from trajectories.checks import check_waypoints
from trajectories.plane_crossing import rod_plane_crossings
from trajectories.presets import DEFAULT_PRESET, PRESETS, get_preset, preset_names, preset_waypoints
from trajectories.waypoint import waypoint_matrices

ALL = sorted(PRESETS)
# Minimum clearances the presets promise (see trajectories/presets.py).
MIN_RANGE_M, MAX_RANGE_M = 0.30, 1.5
FOV_MARGIN_RAD = np.deg2rad(5.0)
BASE_COLUMN_CLEARANCE_M = 0.13


def test_default_preset_is_the_papers_procedure() -> None:
    assert DEFAULT_PRESET == "paper"
    waypoints = preset_waypoints()
    assert len(waypoints) == 20  # two semicircles, a stop every 20 degrees
    assert preset_names()[0] == "paper"
    assert set(preset_names()) == {"paper", "compact", "drill", "quick"}


def test_quick_preset_has_few_waypoints() -> None:
    assert 6 <= len(preset_waypoints("quick")) <= 10


def test_unknown_preset_lists_the_names() -> None:
    with pytest.raises(ConfigError, match=r"unknown trajectory preset 'fast'; choose one of: paper, compact"):
        get_preset("fast")
    assert get_preset(" Paper ").name == "paper"


@pytest.mark.parametrize("name", ALL)
def test_rod_crosses_the_default_scanner_plane_inside_its_field_of_view(name: str) -> None:
    preset = get_preset(name)
    crossings = rod_plane_crossings(waypoint_matrices(preset.waypoints()), preset.rod, T_BASE_LASER)
    assert crossings.within_rod.all(), f"rod misses the plane at {np.flatnonzero(~crossings.within_rod)}"
    assert np.all(crossings.range_m >= MIN_RANGE_M) and np.all(crossings.range_m <= MAX_RANGE_M)
    assert np.all(np.abs(crossings.bearing_rad) <= FOV_HALF_RAD - FOV_MARGIN_RAD)


@pytest.mark.parametrize("name", ALL)
def test_line_of_sight_to_each_crossing_clears_the_robot_base(name: str) -> None:
    preset = get_preset(name)
    crossings = rod_plane_crossings(waypoint_matrices(preset.waypoints()), preset.rod, T_BASE_LASER)
    points = transform_points(T_BASE_LASER, np.column_stack([crossings.uv_m, np.zeros(len(crossings.uv_m))]))
    scanner_xy, targets_xy = T_BASE_LASER[:2, 3], points[:, :2]
    beam = targets_xy - scanner_xy
    along = np.clip((-scanner_xy @ beam.T) / np.sum(beam * beam, axis=1), 0.0, 1.0)
    closest_to_base_axis = np.linalg.norm(scanner_xy + along[:, None] * beam, axis=1)
    assert np.all(closest_to_base_axis > BASE_COLUMN_CLEARANCE_M)


# Stricter than the default box: the presets keep the whole rod above the table top.
ABOVE_THE_TABLE = WorkspaceConfig(min_m=[-0.95, -0.95, 0.0], max_m=[0.95, 0.95, 1.10])


@pytest.mark.parametrize("name", ALL)
def test_every_waypoint_passes_the_offline_preflight(name: str) -> None:
    preset = get_preset(name)
    report = check_waypoints(
        preset.waypoints(),
        inverse_kinematics=inverse_kinematics_pose,
        workspace=ABOVE_THE_TABLE,
        rod=preset.rod,
    )
    assert report.ok, report.summary()


@pytest.mark.parametrize("name", ALL)
def test_the_arm_follows_the_waypoints_on_one_branch_without_big_jumps(name: str) -> None:
    # Start from an elbow-up, tool-down configuration facing +x (base joint near pi).
    q = np.array([np.pi, -np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2, 0.0])
    trajectory = []
    for waypoint in preset_waypoints(name):
        q = inverse_kinematics_pose(waypoint.pose_array(), q)
        assert q is not None
        trajectory.append(q)
    joints = np.array(trajectory)
    assert np.all(joints[:, 2] > 0.3), "elbow must stay up"
    assert np.all(joints[:, 4] < -0.5), "wrist must not flip"
    assert np.abs(np.diff(joints, axis=0)).max() < 1.6


@pytest.mark.parametrize("name", ALL)
def test_all_six_degrees_of_freedom_are_observable(name: str) -> None:
    """Singular values of d(u, v)/d(pose of the scanner): none may vanish.

    Columns: translation (m) and rotation (rad) of T_base_laser, perturbed in the scanner
    frame; rows: the crossing coordinates of every waypoint. Normalised by sqrt(n), the
    smallest singular value is the RMS shift (m) of the centres per unit of the least
    observable parameter combination.
    """
    preset = get_preset(name)
    matrices = waypoint_matrices(preset.waypoints())

    def centres(T_base_laser: np.ndarray) -> np.ndarray:
        return rod_plane_crossings(matrices, preset.rod, T_base_laser).uv_m.ravel()

    step = 1e-6
    columns = []
    for k in range(6):
        delta = np.zeros(6)
        delta[k] = step
        perturbed = T_BASE_LASER @ make_transform(rotvec_to_matrix(delta[3:]), delta[:3])
        columns.append((centres(perturbed) - centres(T_BASE_LASER)) / step)
    singular = np.linalg.svd(np.array(columns).T, compute_uv=False) / np.sqrt(len(matrices))
    assert singular.min() > 0.02, f"weakest direction moves the centres by only {singular.min():.3f} m/unit"
    if name == DEFAULT_PRESET:
        assert singular.min() > 0.05
