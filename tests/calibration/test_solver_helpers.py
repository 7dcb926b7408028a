"""Shared helpers for the solver tests (no tests here): simulated observations of the paper setup."""

from __future__ import annotations

import numpy as np

from lasercal_hw.calibration.simulate import Protocol, paper_ground_truth, simulate_observations
from lasercal_hw.models import Observation, RodLine

TRUTH = paper_ground_truth()


def observations(
    seed: int = 0, *, points: int = 75, laser_noise_m: float = 0.01, robot_noise_m: float = 0.001,
    tilt_deg: float = 20.0,
) -> list[Observation]:
    """Observations of the paper's protocol (truth ``TRUTH``)."""
    protocol = Protocol(
        points=points, laser_noise_m=laser_noise_m, robot_noise_m=robot_noise_m, tilt_deg=tilt_deg
    )
    obs, _ = simulate_observations(TRUTH, RodLine(), protocol, np.random.default_rng(seed))
    return obs


def translation_error_mm(matrix: np.ndarray) -> float:
    return float(np.linalg.norm(matrix[:3, 3] - TRUTH[:3, 3]) * 1e3)
