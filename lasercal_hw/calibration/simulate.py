"""Monte Carlo study of the paper's simulation protocol (section 4.2).

Protocol as implemented (the paper leaves details open; these are our choices):

* ground truth ``T_base_laser``: translation (0.30, 0.50, 0.20) m, ZYX (yaw, pitch, roll)
  = (5, 7, 3) deg;
* ``points`` TCP positions evenly spaced on a full circle of radius 0.8 m about the base z
  axis (random phase per trial), TCP height uniform in [0.45, 0.65] m (20 cm variation;
  the scan plane lies between 0.02 and 0.38 m on that circle, so every TCP is above it);
* the tool z axis (the rod) points down (-z of the base) tilted by independent uniform
  angles in [-tilt, tilt] about the base x and y axes, plus a random spin about the tool
  axis (which the rod cannot see).  The rod thus crosses the scan plane in its positive
  direction (``s > 0``, checked), 0.1-0.6 m below the TCP;
* the scanner sees the exact crossing plus N(0, laser_noise^2) on u and v; the robot
  reports the TCP position with N(0, robot_noise^2) per axis (orientation exact).  The
  field of view and occlusion are ignored, as in the paper.

Errors per trial: translation ``t_true - t_est`` (mm) and ZYX angle differences (deg),
reported as ``rot_x`` = roll, ``rot_y`` = pitch, ``rot_z`` = yaw difference, as in the
paper.  The Cramér-Rao bound is evaluated per trial at the truth for that trial's
waypoints and noise model; ``crb_*`` statistics are of N(0, CRB) draws, so they are
what an efficient estimator would show in the same table.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np

from lasercal_hw.calibration.model import (
    euler_zyx_axes,
    fisher_information,
    plane_crossing,
    rod_lines_in_base,
)
from lasercal_hw.calibration.solver import SolverOptions, solve
from lasercal_hw.geometry import (
    FloatArray,
    euler_zyx_to_matrix,
    make_transform,
    matrix_to_euler_zyx,
    matrix_to_pose,
)
from lasercal_hw.models import Observation, RodLine

PAPER_TRANSLATION_M = (0.30, 0.50, 0.20)
PAPER_EULER_ZYX_DEG = (5.0, 7.0, 3.0)
METRICS = ("x", "y", "z", "xyz", "rot_x", "rot_y", "rot_z", "rot")
PAPER_TABLE1_MEAN = dict(zip(METRICS, (3.338, 3.110, 7.169, 9.581, 0.494, 0.470, 0.192, 0.800), strict=True))
PAPER_TABLE1_STD = dict(zip(METRICS, (6.736, 4.973, 28.193, 20.434, 0.147, 0.108, 0.018, 0.132), strict=True))
_CRB_DRAWS_PER_TRIAL = 64


@dataclass(frozen=True)
class Protocol:
    """Settings of the simulated calibration run."""

    points: int = 75
    radius_m: float = 0.8
    tcp_height_min_m: float = 0.45
    tcp_height_range_m: float = 0.20
    tilt_deg: float = 20.0
    laser_noise_m: float = 0.010
    robot_noise_m: float = 0.001


def paper_ground_truth() -> FloatArray:
    """``T_base_laser`` of the paper's simulation."""
    yaw, pitch, roll = np.radians(PAPER_EULER_ZYX_DEG)
    return make_transform(euler_zyx_to_matrix(yaw, pitch, roll), np.array(PAPER_TRANSLATION_M))


def protocol_tcp_poses(protocol: Protocol, rng: np.random.Generator) -> FloatArray:
    """True TCP poses (N, 6) of one trial (see the module docstring)."""
    n = protocol.points
    angle = rng.uniform(0.0, 2.0 * np.pi) + 2.0 * np.pi * np.arange(n) / n
    height = protocol.tcp_height_min_m + rng.uniform(0.0, protocol.tcp_height_range_m, n)
    position = np.column_stack([protocol.radius_m * np.cos(angle), protocol.radius_m * np.sin(angle), height])
    tilt = np.radians(protocol.tilt_deg)
    tilt_x, tilt_y = rng.uniform(-tilt, tilt, n), rng.uniform(-tilt, tilt, n)
    spin = rng.uniform(-np.pi, np.pi, n)
    zeros = np.zeros(n)
    # R = Rx(tilt_x) Ry(tilt_y) Rx(pi) Rz(spin): tool z points down, then tilted.
    rotation = (
        euler_zyx_to_matrix(zeros, zeros, tilt_x)
        @ euler_zyx_to_matrix(zeros, tilt_y, zeros)
        @ euler_zyx_to_matrix(zeros, zeros, np.full(n, np.pi))
        @ euler_zyx_to_matrix(spin, zeros, zeros)
    )
    return matrix_to_pose(make_transform(rotation, position))


def simulate_observations(
    truth: FloatArray, rod: RodLine, protocol: Protocol, rng: np.random.Generator
) -> tuple[list[Observation], FloatArray]:
    """Noisy observations of one trial and the true TCP poses."""
    poses = protocol_tcp_poses(protocol, rng)
    origins, directions = rod_lines_in_base(poses, rod)
    crossing, _, s = plane_crossing(truth[:3, :3], truth[:3, 3], origins, directions)
    if (s <= 0).any():
        raise AssertionError("protocol produced a rod that does not cross the plane in +z of the tool")
    n = protocol.points
    centres = crossing + rng.normal(0.0, protocol.laser_noise_m, (n, 2))
    reported = poses.copy()
    reported[:, :3] += rng.normal(0.0, protocol.robot_noise_m, (n, 3))
    covariance = np.eye(2) * protocol.laser_noise_m**2 if protocol.laser_noise_m > 0 else None
    observations = [
        Observation(index=i, tcp_pose=reported[i], centre_uv_m=centres[i], covariance_uv_m2=covariance)
        for i in range(n)
    ]
    return observations, poses


def pose_errors(truth: FloatArray, estimate: FloatArray) -> FloatArray:
    """(e_x, e_y, e_z) in mm and ZYX differences (roll, pitch, yaw) in degrees, shape (6,)."""
    e_t = (truth[:3, 3] - estimate[:3, 3]) * 1e3
    diff = np.degrees(matrix_to_euler_zyx(truth[:3, :3]) - matrix_to_euler_zyx(estimate[:3, :3]))
    diff = (diff + 180.0) % 360.0 - 180.0
    return np.concatenate([e_t, diff[::-1]])


def crb_covariance(truth: FloatArray, poses: FloatArray, rod: RodLine, protocol: Protocol) -> FloatArray:
    """CRB (6, 6) of (t [mm], roll, pitch, yaw [deg]) for these waypoints and noise model."""
    origins, directions = rod_lines_in_base(poses, rod)
    covariance = np.broadcast_to(np.eye(2) * protocol.laser_noise_m**2, (len(poses), 2, 2))
    fisher = fisher_information(
        truth[:3, :3], truth[:3, 3], origins, directions, covariance, protocol.robot_noise_m
    )
    crb = np.linalg.inv(fisher)
    yaw, pitch, _ = matrix_to_euler_zyx(truth[:3, :3])
    to_euler = np.linalg.inv(euler_zyx_axes(yaw, pitch))[::-1]  # rows: roll, pitch, yaw
    jac = np.zeros((6, 6))
    jac[:3, :3] = np.eye(3) * 1e3
    jac[3:, 3:] = np.degrees(to_euler)
    return jac @ crb @ jac.T


def metric_table(errors: FloatArray) -> FloatArray:
    """Absolute errors (T, 8) in METRICS order from (T, 6) signed errors."""
    return np.column_stack(
        [
            np.abs(errors[:, :3]),
            np.linalg.norm(errors[:, :3], axis=1),
            np.abs(errors[:, 3:]),
            np.linalg.norm(errors[:, 3:], axis=1),
        ]
    )


@dataclass(frozen=True)
class MonteCarloSummary:
    """Statistics of a Monte Carlo run (all in mm or degrees, METRICS order)."""

    trials: int
    failures: int
    mean: dict[str, float]
    std: dict[str, float]
    crb_mean: dict[str, float]
    crb_std: dict[str, float]
    rms_translation_mm: float
    rms_rotation_deg: float
    crb_rms_translation_mm: float
    crb_rms_rotation_deg: float
    median_solve_time_s: float

    def to_dict(self) -> dict[str, object]:
        """Plain-JSON form."""
        return dict(self.__dict__)


def monte_carlo(
    trials: int,
    seed: int,
    protocol: Protocol,
    *,
    formulation: Literal["ours", "paper"] = "ours",
    rod: RodLine | None = None,
    progress: Callable[[int], None] | None = None,
) -> MonteCarloSummary:
    """Run ``trials`` independent simulated calibrations and compare with the CRB."""
    rod = rod or RodLine()
    rng = np.random.default_rng(seed)
    crb_rng = np.random.default_rng([seed, 1])
    truth = paper_ground_truth()
    options = SolverOptions(default_sigma_uv_m=protocol.laser_noise_m, robot_sigma_m=protocol.robot_noise_m)
    errors, crb_draws, crbs, times = [], [], [], []
    failures = 0
    for trial in range(trials):
        observations, poses = simulate_observations(truth, rod, protocol, rng)
        result = solve(observations, rod, options=options, formulation=formulation)
        crb = crb_covariance(truth, poses, rod, protocol)
        crbs.append(crb)
        crb_draws.append(crb_rng.multivariate_normal(np.zeros(6), crb, _CRB_DRAWS_PER_TRIAL))
        times.append(result.provenance.solve_time_s)
        if not result.provenance.converged:
            failures += 1
        errors.append(pose_errors(truth, result.matrix()))
        if progress is not None:
            progress(trial + 1)
    table = metric_table(np.array(errors))
    crb_table = metric_table(np.concatenate(crb_draws))
    mean_crb = np.mean(crbs, axis=0)
    err = np.array(errors)
    return MonteCarloSummary(
        trials=trials,
        failures=failures,
        mean=dict(zip(METRICS, table.mean(axis=0).tolist(), strict=True)),
        std=dict(zip(METRICS, table.std(axis=0, ddof=1).tolist(), strict=True)),
        crb_mean=dict(zip(METRICS, crb_table.mean(axis=0).tolist(), strict=True)),
        crb_std=dict(zip(METRICS, crb_table.std(axis=0, ddof=1).tolist(), strict=True)),
        rms_translation_mm=float(np.sqrt(np.mean(np.sum(err[:, :3] ** 2, axis=1)))),
        rms_rotation_deg=float(np.sqrt(np.mean(np.sum(err[:, 3:] ** 2, axis=1)))),
        crb_rms_translation_mm=float(np.sqrt(np.trace(mean_crb[:3, :3]))),
        crb_rms_rotation_deg=float(np.sqrt(np.trace(mean_crb[3:, 3:]))),
        median_solve_time_s=float(np.median(times)),
    )
