"""A cell's scanners in a job file (``[scanners.NAME]``) and in a fake cell's scene."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from drivers.hokuyo.client import HokuyoScanner
from fakes.cell import FakeCell
from fakes.cell_process import free_loopback_address
from fakes.scene import ScannerSettings, Scene, load_scene, parse_scene
from fakes.scip_identity import UTM_30LX_EW, identity_of_scanner
from fakes.ur_controller.kinematics_calibration import KinematicsCalibration
from fakes.world import World
from lasercal_hw.calibration.pairs import error_in_std, relative_pose
from lasercal_hw.config import DEFAULT_SCANNER_NAME, load_job, with_overrides
from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import euler_zyx_to_matrix, make_transform, rotvec_to_matrix

REPO = Path(__file__).resolve().parents[1]


def test_a_one_scanner_job_is_a_cell_of_the_scanner_default() -> None:
    job = load_job(REPO / "examples" / "rod.toml")
    assert job.scanner_names() == [DEFAULT_SCANNER_NAME]
    assert job.for_scanner(DEFAULT_SCANNER_NAME) is job
    with pytest.raises(ConfigError, match="one scanner, 'default', not 'front'"):
        job.for_scanner("front")


def test_each_scanner_of_a_cell_job_is_a_one_scanner_job_with_its_own_tables(tmp_path: Path) -> None:
    job = load_job(REPO / "examples" / "cell.toml")
    assert job.scanner_names() == ["front", "rear"]
    rear = job.for_scanner("rear")
    assert rear.scanners == {} and rear.scanner.url == "scip+tcp://192.168.0.11:10940"
    assert rear.scanner.nominal is not None and rear.scanner.nominal.translation_m == [-0.43, -0.42, 0.29]
    # waypoint files are relative to the job file, per scanner too
    assert rear.trajectory.waypoints_file == (REPO / "examples" / "cell" / "rear-waypoints.csv").resolve()
    assert rear.rod == job.rod and rear.quality == job.quality
    # a scanner's own rod and gates replace the job's for it alone
    (tmp_path / "job.toml").write_text(
        "[scanners.a]\nurl = \"scip+tcp://127.0.0.1:10940\"\n[scanners.a.rod]\nradius_m = 0.005\n"
        "[scanners.b]\n[scanners.b.quality]\nmin_observations = 12\n"
    )
    cell = load_job(tmp_path / "job.toml")
    assert cell.for_scanner("a").rod.radius_m == 0.005 and cell.for_scanner("b").rod.radius_m == 0.02
    assert cell.for_scanner("b").quality.min_observations == 12
    assert with_overrides(cell, {"dwell_s": 2.0}).scanner_names() == ["a", "b"]
    with pytest.raises(ConfigError, match="no scanner 'c'; its scanners: a, b"):
        cell.for_scanner("c")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[scanner]\nurl = \"scip+tcp://127.0.0.1:10940\"\n[scanners.a]\n", "not both"),
        ("[scanners.Front]\n", "scanner name 'Front'"),
        ("[scanners.front-left]\n", "scanner name 'front-left'.*'-' is not allowed: e.g. 'front_left'"),
        ("[scanners.a]\nurl = \"http://x\"\n", "scanners.a.url"),
    ],
)
def test_a_bad_cell_job_names_the_problem(tmp_path: Path, text: str, message: str) -> None:
    (tmp_path / "job.toml").write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_job(tmp_path / "job.toml")


def test_a_scene_places_several_scanners_in_one_world() -> None:
    scene = load_scene(REPO / "fakes" / "scenes" / "two_scanners.toml")
    assert scene.scanner_names() == ["front", "rear"]
    assert parse_scene(scene.to_toml()) == scene
    front, rear = World(scene, "front"), World(scene, "rear")
    assert np.allclose(front.ground_truth_T_base_laser[:3, 3], [0.30, 0.50, 0.20])
    assert np.allclose(rear.ground_truth_T_base_laser[:3, 3], [-0.45, -0.40, 0.30])
    normals = front.ground_truth_T_base_laser[:3, 2], rear.ground_truth_T_base_laser[:3, 2]
    assert np.degrees(np.arccos(normals[0] @ normals[1])) > 5.0, "the scan planes are not parallel"
    assert World(scene).ground_truth_T_base_laser.tolist() == front.ground_truth_T_base_laser.tolist()
    assert load_scene(None).scanner_names() == ["default"]
    with pytest.raises(ConfigError, match="no scanner 'side'"):
        World(scene, "side")
    with pytest.raises(ConfigError, match="not both"):
        parse_scene("[scanner]\ntranslation_m = [0.0, 0.0, 0.5]\n[scanners.a]\n")
    assert scene.for_scanner("rear").scanner == ScannerSettings(
        translation_m=[-0.45, -0.40, 0.30], euler_zyx_deg=[45.0, -6.0, 5.0]
    )


def test_the_bumped_cell_moves_the_rear_5_mm_and_half_a_degree_and_leaves_the_front() -> None:
    """fakes/scenes/two_scanners_rear_moved.toml, docs/cell.md's verify example."""
    scenes = REPO / "fakes" / "scenes"
    before = load_scene(scenes / "two_scanners.toml")
    after = load_scene(scenes / "two_scanners_rear_moved.toml")

    def pose(scene: Scene, name: str) -> np.ndarray:
        return World(scene, name).ground_truth_T_base_laser

    assert pose(after, "front").tolist() == pose(before, "front").tolist()
    moved = np.linalg.inv(pose(before, "rear")) @ pose(after, "rear")
    turn_deg = np.degrees(np.arccos(np.clip((np.trace(moved[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
    shift_mm = 1000.0 * np.linalg.norm(pose(after, "rear")[:3, 3] - pose(before, "rear")[:3, 3])
    assert shift_mm == pytest.approx(5.0) and turn_deg == pytest.approx(0.5, abs=1e-6)


def test_the_recalibrated_robots_cell_changes_joint_3s_checksum_and_leaves_the_scanners() -> None:
    """fakes/scenes/two_scanners_robot_recalibrated.toml, docs/cell.md's verify of a changed robot:
    the scanners where two_scanners.toml puts them, the controller's calibration that of a
    replaced joint 3."""
    scenes = REPO / "fakes" / "scenes"
    before = load_scene(scenes / "two_scanners.toml")
    after = load_scene(scenes / "two_scanners_robot_recalibrated.toml")

    assert after.scanners == before.scanners
    replaced = KinematicsCalibration().with_joint_replaced(3)
    assert after.robot_kinematics.checksums == list(replaced.checksums)
    assert after.robot_kinematics.checksums != before.robot_kinematics.checksums


def test_the_fake_cell_serves_each_scanner_on_its_own_port_with_its_own_serial() -> None:
    cell = FakeCell(free_loopback_address(), REPO / "fakes" / "scenes" / "two_scanners.toml")
    try:
        cell.start()
        document = cell.ready_document()
        serials = {}
        for name, entry in document["scanners"].items():
            with HokuyoScanner.open(entry["scanner_url"]) as scanner:
                serials[name] = scanner.identity().serial
    finally:
        cell.close()
    assert serials == {name: identity_of_scanner(name).serial for name in ("front", "rear")}
    assert len(set(serials.values())) == 2 and UTM_30LX_EW.serial not in serials.values()
    assert identity_of_scanner(DEFAULT_SCANNER_NAME) is UTM_30LX_EW  # a one-scanner cell's, as before
    scanners = document["scanners"]
    assert list(scanners) == ["front", "rear"]
    assert scanners["front"]["scanner_url"].endswith(":10940")
    assert scanners["rear"]["scanner_url"].endswith(":10941")
    assert document["scanner_url"] == scanners["front"]["scanner_url"]
    assert document["T_base_laser"] == scanners["front"]["T_base_laser"]


def _pose(rng: np.random.Generator) -> np.ndarray:
    return make_transform(euler_zyx_to_matrix(*rng.uniform(-1.0, 1.0, 3)), rng.uniform(-1.0, 1.0, 3))


def test_the_scanner_to_scanner_covariance_matches_sampled_poses() -> None:
    """First-order propagation against Monte Carlo: sample both poses from their covariances,
    form T_a_b, and compare the spread with the propagated covariance."""
    rng = np.random.default_rng(4)
    T_a, T_b = _pose(rng), _pose(rng)
    factor_a, factor_b = rng.normal(0, 1, (6, 6)), rng.normal(0, 1, (6, 6))
    scale = np.diag([1e-3, 1e-3, 1e-3, 2e-3, 2e-3, 2e-3])
    cov_a, cov_b = scale @ factor_a @ factor_a.T @ scale, scale @ factor_b @ factor_b.T @ scale
    T_ab, covariance = relative_pose(T_a, cov_a, T_b, cov_b)
    np.testing.assert_allclose(T_ab, np.linalg.inv(T_a) @ T_b, atol=1e-12)

    def sample(T: np.ndarray, cov: np.ndarray) -> np.ndarray:
        delta = rng.multivariate_normal(np.zeros(6), cov)
        return make_transform(rotvec_to_matrix(delta[3:]) @ T[:3, :3], T[:3, 3] + delta[:3])

    errors = []
    for _ in range(4000):
        T_sample = np.linalg.inv(sample(T_a, cov_a)) @ sample(T_b, cov_b)
        errors.append(error_in_std(T_sample, covariance, T_ab)["mahalanobis"] ** 2)
    assert np.mean(errors) == pytest.approx(6.0, rel=0.08)  # chi-square with 6 dof
