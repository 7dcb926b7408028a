"""A provisional pose from the run's first waypoints, for runs without a nominal mounting."""

from __future__ import annotations

import dataclasses

import numpy as np

from lasercal_hw.calibration.consensus import CONSENSUS_WAYPOINTS, provisional_pose
from lasercal_hw.calibration.solver import SolverOptions
from lasercal_hw.models import RodLine
from tests.calibration.test_solver_helpers import observations, translation_error_mm

OPTIONS = SolverOptions(default_sigma_uv_m=0.002)


def test_the_first_waypoints_give_a_pose_once_there_are_enough_of_them() -> None:
    obs = observations(4, points=20, laser_noise_m=0.002)
    assert provisional_pose(obs[: CONSENSUS_WAYPOINTS - 1], RodLine(), OPTIONS) is None
    pose = provisional_pose(obs, RodLine(), OPTIONS)
    assert pose is not None and translation_error_mm(pose) < 20.0


def test_first_waypoints_that_cannot_determine_a_pose_give_none() -> None:
    obs = observations(4, points=20, laser_noise_m=0.002)
    same_tool = [dataclasses.replace(o, tcp_pose=np.r_[o.tcp_pose[:3], obs[0].tcp_pose[3:]]) for o in obs]
    assert provisional_pose(same_tool, RodLine(), OPTIONS) is None  # parallel rods: no pose
    noisy = observations(4, points=20, laser_noise_m=0.2)
    assert provisional_pose(noisy, RodLine(), SolverOptions(default_sigma_uv_m=0.2)) is None  # too uncertain
