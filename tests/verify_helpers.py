"""A calibration to verify against the fake cell, made without running one: the default
scene's rod centres at the job's waypoints, as the fake robot really places the rod
(its absolute-accuracy error field applied), solved by the product's solver."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from fakes.scene import load_scene
from fakes.scip_identity import UTM_30LX_EW
from fakes.ur_controller.controller import ControllerConfig
from fakes.ur_controller.kinematics_calibration import KinematicsCalibration
from fakes.world import World
from lasercal_hw.calibration.model import plane_crossing, rod_lines_in_base
from lasercal_hw.calibration.solver import SolverOptions, solve
from lasercal_hw.config import JobConfig, job_from_mapping
from lasercal_hw.geometry import matrix_to_euler_zyx, matrix_to_pose, pose_to_matrix, rotvec_to_matrix
from lasercal_hw.models import Observation, RobotCalibration
from lasercal_hw.run.waypoints import job_waypoints

CENTRE_SIGMA_M = 0.0005


def fast_job() -> JobConfig:
    """A short job for tests: the quick preset, 1 s dwells, the fastest joint moves a job allows; scans the
    fake scanner misses on a loaded test machine do not fail a dwell."""
    return job_from_mapping(
        {
            "dwell_s": 1.0,
            "acquisition": {"max_missed_scans": 1000, "min_scan_fraction": 0.2},
            "trajectory": {"preset": "quick"},
            "background": {"scans": 10},
            "motion": {"joint_speed_rad_s": 1.5, "joint_accel_rad_s2": 4.0},
        }
    )


def true_centres(job: JobConfig, world: World) -> np.ndarray:
    """Where the rod really crosses the scan plane at each of the job's waypoints."""
    poses = job_waypoints(job)
    true_poses = np.array([matrix_to_pose(world.robot_error.true_pose(pose_to_matrix(p))) for p in poses])
    origins, directions = rod_lines_in_base(true_poses, job.rod.rod_line())
    T = world.ground_truth_T_base_laser
    return plane_crossing(T[:3, :3], T[:3, 3], origins, directions)[0]


def fake_robot_calibration(kinematics: KinematicsCalibration | None = None) -> RobotCalibration:
    """What a default fake controller's primary interface reports (with ``kinematics``)."""
    controller = ControllerConfig(kinematics=kinematics or KinematicsCalibration())
    theta, a, d, alpha = controller.kinematics.rows()
    return RobotCalibration(
        checksums=controller.kinematics.checksums, dh_theta_rad=theta, dh_a_m=a, dh_d_m=d, dh_alpha_rad=alpha,
        calibration_status=0, model=f"{controller.model}e", software_version=controller.version_text,
    )


def calibration_document(job: JobConfig, *, scanner_serial: str = UTM_30LX_EW.serial) -> dict[str, Any]:
    """A result.json of the default scene as ``lasercal run`` writes it (noise-free centres),
    made on a default fake controller (its kinematics calibration recorded)."""
    world = World(load_scene(None))
    poses = job_waypoints(job)
    centres = true_centres(job, world)
    observations = [
        Observation(i, pose, centre, np.eye(2) * CENTRE_SIGMA_M**2)
        for i, (pose, centre) in enumerate(zip(poses, centres, strict=True))
    ]
    options = SolverOptions(robot_sigma_m=job.robot.position_accuracy_mm / 1000.0)
    document = solve(observations, job.rod.rod_line(), options=options).to_json_dict()
    controller = ControllerConfig()
    document["run"] = {
        "robot": {"model": controller.model, "serial_number": controller.serial_number},
        "scanner": {"serial": scanner_serial, "firmware": UTM_30LX_EW.firmware},
        "robot_calibration": fake_robot_calibration().as_dict(),
        "job": job.model_dump(mode="json"),
        "timings": {"motion_s": 30.0, "dwell_s": 10.0},
    }
    return document


def write_calibration(folder: Path, job: JobConfig, **kwargs: Any) -> Path:
    """``folder/result.json`` of ``calibration_document``."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "result.json"
    path.write_text(json.dumps(calibration_document(job, **kwargs)), encoding="utf-8")
    return path


def moved_scene(path: Path, shift_m: np.ndarray, turn_rad: np.ndarray) -> Path:
    """A scene file: the default scene with the scanner shifted and turned about its origin."""
    T = World(load_scene(None)).ground_truth_T_base_laser
    rotation = rotvec_to_matrix(np.asarray(turn_rad, dtype=float)) @ T[:3, :3]
    translation = T[:3, 3] + np.asarray(shift_m, dtype=float)
    euler = np.degrees(matrix_to_euler_zyx(rotation))
    path.write_text(
        "[scanner]\n"
        f"translation_m = [{', '.join(repr(float(v)) for v in translation)}]\n"
        f"euler_zyx_deg = [{', '.join(repr(float(v)) for v in euler)}]\n",
        encoding="utf-8",
    )
    return path
