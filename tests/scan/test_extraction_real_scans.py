"""Issue 18's real-scan failures as synthetic scans: each gives a found rod or a clear skip,
never a wrong centre (steady mixed-pixel ramps, a near rod with range bias, a far rod with
flaky edge beams, a rod-sized object elsewhere)."""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np
import pytest

from lasercal_hw.scan.average import average_scans
from lasercal_hw.scan.extraction import RodCentre, RodNotFoundError, find_rod_centre
from tests.synthetic_scans import real_like_scans

RADIUS_M = 0.045  # the retro-reflective rod
Z_AXIS = np.array([0.0, 0.0, 1.0])


def _at(range_m: float, bearing_deg: float) -> np.ndarray:
    return range_m * np.array([np.cos(np.radians(bearing_deg)), np.sin(np.radians(bearing_deg))])


def _mahalanobis2(found: RodCentre, truth: np.ndarray) -> float:
    error = found.centre_uv_m - truth
    return float(error @ np.linalg.solve(found.covariance_uv_m2, error))


@pytest.mark.parametrize("with_intensity", [True, False])
@pytest.mark.parametrize(
    ("range_m", "ramps", "step_m"),
    [(0.5, (4, 16), 0.025), (0.8, (8, 8), 0.05), (1.1, (16, 4), 0.1), (1.1, (12, 12), 0.025)],
)
def test_steady_mixed_pixel_ramps_are_cut_off_and_the_rod_found(
    range_m: float, ramps: tuple[int, int], step_m: float, with_intensity: bool
) -> None:
    rng = np.random.default_rng(int(range_m * 100) + ramps[0])
    truth = _at(range_m, 17.0)
    dwell = real_like_scans(truth, RADIUS_M, rng, background_m=3.4, ramp_beams=ramps, ramp_step_m=step_m)
    if not with_intensity:
        dwell = [replace(scan, intensities=None) for scan in dwell]
    averaged = average_scans(dwell)
    for expected in (None, truth):
        found = find_rod_centre(averaged, radius_m=RADIUS_M, axis_in_scanner=Z_AXIS, expected_uv_m=expected)
        assert np.linalg.norm(found.centre_uv_m - truth) < 0.001
        assert _mahalanobis2(found, truth) < 13.8  # chi-square 2 dof, 99.9 %
        if step_m < 0.06:  # steps this small join the ramps to the rod's segment: cut off, counted
            assert found.quality.mixed_pixels_dropped >= min(ramps)


@pytest.mark.parametrize("range_m", [0.13, 0.2, 0.3, 0.44])
def test_a_near_rod_with_noisy_biased_readings_is_found_with_an_honest_covariance(range_m: float) -> None:
    rng = np.random.default_rng(int(range_m * 1000))
    truth = _at(range_m, -11.0)
    bias_m = 0.012  # the issue's +12 mm at 0.15 m
    averaged = average_scans(real_like_scans(
        truth, RADIUS_M, rng, background_m=1.2, ramp_beams=(6, 6), ramp_step_m=0.04, reading_sigma_m=0.003,
        range_bias_m=bias_m,
    ))
    # What the scanner shows: the centre pushed out along its bearing by the bias (the
    # solver's range curve takes that part); the rest must be in the reported covariance.
    seen = truth * (1.0 + bias_m / np.linalg.norm(truth))
    found = find_rod_centre(averaged, radius_m=RADIUS_M, axis_in_scanner=Z_AXIS, expected_uv_m=truth)
    assert found.quality.beams_used >= 40
    assert _mahalanobis2(found, seen) < 13.8
    assert np.linalg.norm(found.centre_uv_m - seen) < 0.004


@pytest.mark.parametrize("radius_m", [0.045, 0.03])
def test_a_far_rod_whose_edge_beams_are_valid_in_70_percent_of_scans_keeps_them(radius_m: float) -> None:
    rng = np.random.default_rng(5)
    truth = _at(2.95, 3.0)
    averaged = average_scans(real_like_scans(
        truth, radius_m, rng, background_m=6.0, edge_valid_fraction=0.7, reading_sigma_m=0.005
    ))
    on_rod = np.flatnonzero(averaged.ranges_m < 4.0)
    assert 5 <= on_rod.size <= 7  # 5 beams for the 30 mm rod as the 2.95 m scans
    found = find_rod_centre(averaged, radius_m=radius_m, axis_in_scanner=Z_AXIS)
    assert set(found.beam_indices.tolist()) >= {int(on_rod[0]), int(on_rod[-1])}
    assert _mahalanobis2(found, truth) < 13.8


def test_a_rod_sized_object_elsewhere_is_a_clear_skip_without_an_expected_position() -> None:
    rng = np.random.default_rng(8)
    truth = _at(0.82, 14.0)
    other = _at(0.80, -58.0)  # the wrong answer: 653 mm away at -58 deg
    dwell = real_like_scans(truth, RADIUS_M, rng, background_m=3.4, others=[(other, RADIUS_M)])
    averaged = average_scans(dwell)
    with pytest.raises(RodNotFoundError, match=r"2 rod-like objects in view .*-58 deg.*nominal mounting"):
        find_rod_centre(averaged, radius_m=RADIUS_M)
    found = find_rod_centre(averaged, radius_m=RADIUS_M, expected_uv_m=truth + 0.05)
    assert np.linalg.norm(found.centre_uv_m - truth) < 0.002


def test_a_rod_sized_object_far_from_the_expected_position_is_refused_and_named() -> None:
    rng = np.random.default_rng(9)
    other = _at(0.80, -58.0)
    expected = _at(0.82, 14.0)  # the rod is not there (dropped, or the waypoint is off)
    averaged = average_scans(real_like_scans(other, RADIUS_M, rng, background_m=3.4))
    with pytest.raises(RodNotFoundError) as refused:
        find_rod_centre(averaged, radius_m=RADIUS_M, expected_uv_m=expected)
    message = str(refused.value)
    named = r"rod-like object at \(\+0\.42\d, -0\.6\d\d\) m, 0\.80 m at -58 deg was refused"
    assert re.search(named, message)
    assert "m from where the rod should be (limit 0.15 m)" in message


def test_with_intensities_a_dark_edge_beam_beside_a_bright_rod_is_left_out() -> None:
    rng = np.random.default_rng(11)
    truth = _at(0.7, 5.0)
    dwell = real_like_scans(truth, RADIUS_M, rng, background_m=2.0, reading_sigma_m=0.003)
    on_rod = np.flatnonzero(average_scans(dwell).ranges_m < 1.5)
    edge = int(on_rod[0])
    # The edge beam's spot is mostly on the wall: its range blends in only 2 mm (inside the
    # surface tolerance), but its intensity is the wall's.
    dark = [
        replace(s, ranges_m=np.where(np.arange(s.ranges_m.size) == edge, s.ranges_m + 0.002, s.ranges_m),
                intensities=np.where(np.arange(s.ranges_m.size) == edge, 1500, s.intensities))
        for s in dwell
    ]
    with_intensity = find_rod_centre(average_scans(dark), radius_m=RADIUS_M, axis_in_scanner=Z_AXIS)
    ranges_only = find_rod_centre(
        average_scans([replace(s, intensities=None) for s in dark]), radius_m=RADIUS_M, axis_in_scanner=Z_AXIS
    )
    assert edge not in with_intensity.beam_indices.tolist()
    assert edge in ranges_only.beam_indices.tolist()
