"""Per-beam robust averaging of a dwell's scans."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lasercal_hw.errors import CalibrationError
from lasercal_hw.scan.average import average_scans
from tests.synthetic_scans import ANGLES, UTM_GEOMETRY, rod_ranges, scans


@pytest.fixture
def truth() -> np.ndarray:
    return rod_ranges([0.8, 0.1], 0.02, wall_behind_m=0.7)


def test_mean_and_standard_deviations_follow_the_noise(truth: np.ndarray) -> None:
    rng = np.random.default_rng(3)
    result = average_scans(scans(truth, 0.010, 120, rng))
    valid = np.isfinite(truth)
    assert result.scan_count == 120
    np.testing.assert_array_equal(result.angles_rad, ANGLES)
    error = result.ranges_m[valid] - truth[valid]
    assert np.sqrt(np.mean(error**2)) == pytest.approx(0.010 / np.sqrt(120), rel=0.15)
    assert np.median(result.reading_std_m[valid]) == pytest.approx(0.010, rel=0.1)
    assert np.median(result.std_m[valid]) == pytest.approx(0.010 / np.sqrt(120), rel=0.1)
    assert np.all(result.count[valid] >= 115)


def test_spikes_and_dropouts_are_rejected(truth: np.ndarray) -> None:
    rng = np.random.default_rng(4)
    raw = scans(truth, 0.003, 60, rng)
    spiked = []
    for scan in raw:
        ranges = scan.ranges_m.copy()
        hit = rng.random(ranges.size) < 0.05
        ranges[hit] += 1.0  # mixed-pixel or multipath spikes
        ranges[rng.random(ranges.size) < 0.05] = np.nan  # dropouts
        spiked.append(dataclasses.replace(scan, ranges_m=ranges))
    result = average_scans(spiked)
    valid = np.isfinite(truth)
    assert np.all(np.isfinite(result.ranges_m[valid]))
    assert np.max(np.abs(result.ranges_m[valid] - truth[valid])) < 0.003
    assert np.mean(result.count[valid]) < 0.92 * 60


def test_beams_valid_in_too_few_scans_are_nan(truth: np.ndarray) -> None:
    rng = np.random.default_rng(5)
    raw = scans(truth, 0.003, 10, rng)
    beam_rare, beam_common = 500, 501
    edited = []
    for k, scan in enumerate(raw):
        ranges = scan.ranges_m.copy()
        if k >= 2:
            ranges[beam_rare] = np.nan
        if k >= 6:
            ranges[beam_common] = np.nan
        edited.append(dataclasses.replace(scan, ranges_m=ranges))
    result = average_scans(edited)
    assert np.isnan(result.ranges_m[beam_rare])
    assert not result.valid[beam_rare]
    assert result.count[beam_rare] == 2
    assert np.isfinite(result.ranges_m[beam_common])
    assert result.count[beam_common] == 6


def test_single_scan_has_unknown_spread(truth: np.ndarray) -> None:
    result = average_scans(scans(truth, 0.003, 1, np.random.default_rng(6)))
    assert np.all(np.isnan(result.std_m))
    assert np.isfinite(result.ranges_m[np.isfinite(truth)]).all()


def test_no_scans_is_a_clear_error() -> None:
    with pytest.raises(CalibrationError, match="no scans"):
        average_scans([])


def test_scans_of_different_layout_are_refused(truth: np.ndarray) -> None:
    raw = scans(truth, 0.003, 2, np.random.default_rng(7))
    other = dataclasses.replace(raw[1], geometry=dataclasses.replace(UTM_GEOMETRY, cluster=2))
    with pytest.raises(CalibrationError, match="different beam layout"):
        average_scans([raw[0], other])


def test_intensities_and_valid_counts_are_averaged_over_the_kept_readings() -> None:
    _replace = dataclasses.replace
    rng = np.random.default_rng(3)
    ranges = np.full(UTM_GEOMETRY.angles_rad().size, 2.0)
    dwell = scans(ranges, 0.005, 40, rng)
    # Real intensities differ from beam to beam: equal neighbours would be a repeated step.
    intensity = 1000 + np.arange(ranges.size, dtype=np.int64)
    dwell = [_replace(s, intensities=intensity + 100 * (k % 2)) for k, s in enumerate(dwell)]
    spiked = dwell[0].ranges_m.copy()
    spiked[7] = 5.0  # an outlier reading: its intensity is left out with it
    bright = np.where(np.arange(ranges.size) == 7, 9999, intensity)
    dwell[0] = _replace(dwell[0], ranges_m=spiked, intensities=bright)
    lost = dwell[1].ranges_m.copy()
    lost[9] = np.nan
    dwell[1] = _replace(dwell[1], ranges_m=lost)
    result = average_scans(dwell)
    assert result.intensities is not None
    assert result.intensities[7] == pytest.approx((19 * 1007 + 20 * 1107) / 39)
    # The mean's std: of the kept readings, over the square root of their count.
    assert result.intensity_std is not None
    assert result.intensity_std[7] == pytest.approx(np.std([1007] * 19 + [1107] * 20, ddof=1) / np.sqrt(39))
    assert result.intensity_std[3] == pytest.approx(50.0 * np.sqrt(40 / 39) / np.sqrt(40))
    assert result.valid_count[9] == 39 and result.valid_count[7] == 40 and result.count[7] == 39
    without = average_scans([_replace(s, intensities=None) for s in dwell])
    assert without.intensities is None and without.intensity_std is None


def test_a_step_repeating_its_neighbours_reading_and_intensity_is_left_out() -> None:
    # A UTM-30LX-EW sometimes sends the previous step's reading again; averaged in, it drags
    # the beam towards its neighbour's direction. Told by its equal intensity, it is left out
    # and the beam counts only the scans that measured it.
    rng = np.random.default_rng(5)
    ranges = np.linspace(1.0, 1.2, UTM_GEOMETRY.angles_rad().size)
    dwell = scans(ranges, 0.002, 10, rng)
    intensity = 1000 + np.arange(ranges.size, dtype=np.int64)
    dwell = [dataclasses.replace(s, intensities=intensity) for s in dwell]
    for k in range(6):  # beam 101 repeats beam 100 in 6 of 10 scans
        copied, bright = dwell[k].ranges_m.copy(), dwell[k].intensities.copy()
        copied[101], bright[101] = copied[100], bright[100]
        dwell[k] = dataclasses.replace(dwell[k], ranges_m=copied, intensities=bright)
    result = average_scans(dwell)
    assert result.valid_count[101] == 4 and result.count[101] == 4
    assert result.ranges_m[101] == pytest.approx(ranges[101], abs=0.003)
    without = average_scans([dataclasses.replace(s, intensities=None) for s in dwell])
    assert without.valid_count[101] == 10  # no intensities: a repeat is not told from a chance equal range
