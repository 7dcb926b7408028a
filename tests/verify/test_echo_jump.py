"""A twist drill's echo middle in the verify states how far it can jump: the spread of draws of
its dwell's intensities within their std, where that is wider than the levels' scatter."""

from __future__ import annotations

import numpy as np

from lasercal_hw.models import FloatArray
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction import EchoMiddle, ExtractionSettings, echo_middle
from lasercal_hw.verify.echo_reference import _jump_m2

RANGE_M = 0.4
STEP_RAD = np.radians(0.25)


class _Refit:
    """What ``_jump_m2`` asks of a second pass: the middle about a centre (a 5 mm section)."""

    def echo_middle(
        self, averaged: AveragedScan, tcp_pose: FloatArray, centre_uv_m: FloatArray
    ) -> EchoMiddle | None:
        return echo_middle(averaged, centre_uv_m, 0.005, ExtractionSettings().echo_middle_levels)


def _scan(profile: list[float], std: float) -> AveragedScan:
    """Beams 0.25 deg apart about bearing 0, the rod's ``profile`` of intensities on the middle
    ones at 0.4 m (each with ``std`` as its mean's std), a wall 1 m behind elsewhere."""
    count = 41
    angles = (np.arange(count) - count // 2) * STEP_RAD
    ranges = np.full(count, RANGE_M + 1.0)
    intensities = np.full(count, 500.0)
    start = count // 2 - len(profile) // 2
    ranges[start : start + len(profile)] = RANGE_M
    intensities[start : start + len(profile)] = profile
    zeros = np.zeros(count)
    return AveragedScan(
        ranges, zeros, zeros, np.full(count, 40), angles, 40,
        intensities=intensities, intensity_std=np.full(count, std),
    )


def test_a_middle_that_can_jump_states_the_jump() -> None:
    # Two glints almost as bright, a dip between them near the lowest level: which glint is the
    # brightest, and whether the lowest level's walk passes the dip, change with a hair of noise.
    fragile = _scan([900.0, 3000.0, 1850.0, 2000.0, 2950.0, 900.0], 40.0)
    centre = np.array([RANGE_M + 0.005, 0.0])
    assert np.sqrt(_jump_m2(_Refit(), fragile, np.zeros(6), centre)) > 0.5e-3  # type: ignore[arg-type]


def test_a_middle_of_one_clean_lobe_states_its_noise_alone() -> None:
    clean = _scan([900.0, 2000.0, 3000.0, 2000.0, 900.0], 40.0)
    centre = np.array([RANGE_M + 0.005, 0.0])
    jump_m2 = _jump_m2(_Refit(), clean, np.zeros(6), centre)  # type: ignore[arg-type]
    assert 0.0 < np.sqrt(jump_m2) < 0.05e-3
