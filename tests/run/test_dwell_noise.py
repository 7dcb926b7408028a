"""The factor on a plain fit's stated dwell noise, from the interleaved halves of the run's own
dwells (``run.dwell_noise``); and the averaging that gives those halves."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from lasercal_hw.models import LaserScan, ScanGeometry
from lasercal_hw.run.dwell_noise import (
    MIN_WAYPOINTS,
    DwellNoiseScale,
    half_centres,
    measured_scale,
    with_measured_noise,
)
from lasercal_hw.run.records import WaypointMeasurement
from lasercal_hw.scan.average import AveragedScan, average_scans
from lasercal_hw.scan.extraction import RodCentre, RodQuality

NOISE_M2 = np.diag([1e-6, 4e-6])


def measurement(index: int, half_gap_m: float, warned: bool = False) -> WaypointMeasurement:
    """A waypoint whose two half dwells the fake refit below puts ``half_gap_m`` apart along u."""
    halves = (
        AveragedScan.from_ranges(np.array([0.0]), np.array([0.0])),
        AveragedScan.from_ranges(np.array([half_gap_m]), np.array([0.0])),
    )
    averaged = replace(AveragedScan.from_ranges(np.array([1.0]), np.array([0.0])), halves=halves)
    centre = RodCentre(
        beam_indices=np.arange(3),
        centre_uv_m=np.array([0.5, 0.0]),
        covariance_uv_m2=4.0 * NOISE_M2,
        quality=RodQuality(10, 0.001, 60.0, None, 0),
        warnings=("blended",) if warned else (),
        noise_covariance_uv_m2=NOISE_M2,
    )
    return WaypointMeasurement(index, np.zeros(6), averaged, centre)


def refit(ms: list[WaypointMeasurement]) -> tuple[list[WaypointMeasurement], list[tuple[int, str]]]:
    """Each measurement's centre at (its averaged range, 0): a half's gap becomes the centres';
    a half read at 0.5 m keeps one beam fewer than its dwell."""
    return [
        replace(
            m,
            centre=replace(
                m.centre,
                centre_uv_m=np.array([m.averaged.ranges_m[0], 0.0]),
                beam_indices=np.arange(2 if m.averaged.ranges_m[0] == 0.5 else 3),
            ),
        )
        for m in ms
    ], []


def scale_of(ms: list[WaypointMeasurement]) -> DwellNoiseScale:
    """The factor ``ms``' halves give."""
    return measured_scale(ms, half_centres(ms, refit))


def test_the_halves_scatter_pooled_over_the_waypoints_is_the_factor_on_the_stated_noise() -> None:
    """Halves 1 mm apart along u, the stated std 1 mm there: ``d^T N^-1 d / 4`` is 0.25 at each
    waypoint, the factor 0.125, with two degrees of freedom per waypoint; a warned centre (its
    whole covariance is what a dwell draws) is left out."""
    ms = [measurement(i, 0.001) for i in range(12)] + [measurement(12, 0.01, warned=True)]
    scale = scale_of(ms)
    assert scale.factor == pytest.approx(0.125)
    assert scale.dof == 24


def test_the_factor_never_widens_the_stated_noise_and_needs_enough_waypoints() -> None:
    """Halves farther apart than the stated noise allows leave it whole (factor 1); too few
    waypoints leave it whole and pool nothing."""
    assert scale_of([measurement(i, 0.01) for i in range(12)]).factor == 1.0
    few = scale_of([measurement(i, 0.001) for i in range(MIN_WAYPOINTS - 1)])
    assert (few.factor, few.dof) == (1.0, 0)


def test_a_centre_whose_halves_keep_other_beams_keeps_its_stated_noise_whole() -> None:
    """A half that keeps one beam fewer than its dwell (a fluted centre may jump by millimetres
    there from dwell to dwell): that waypoint is neither pooled nor scaled."""
    ms = [measurement(i, 0.001) for i in range(12)] + [measurement(12, 0.5)]
    halves = half_centres(ms, refit)
    scale = measured_scale(ms, halves)
    assert (scale.factor, scale.dof) == (pytest.approx(0.125), 24)
    scaled = with_measured_noise(ms, scale, halves)
    np.testing.assert_allclose(scaled[0].centre.dwell_noise_covariance_uv_m2(), 0.125 * NOISE_M2)
    np.testing.assert_allclose(scaled[12].centre.dwell_noise_covariance_uv_m2(), NOISE_M2)


def test_a_scaled_centre_keeps_its_covariance_and_a_warned_one_its_noise() -> None:
    """Only the stated dwell noise of an unwarned centre is scaled."""
    scale = DwellNoiseScale(0.25, 40)
    plain, warned = measurement(0, 0.0).centre, measurement(1, 0.0, warned=True).centre
    np.testing.assert_allclose(scale.scaled(plain).dwell_noise_covariance_uv_m2(), 0.25 * NOISE_M2)
    np.testing.assert_allclose(scale.scaled(plain).covariance_uv_m2, plain.covariance_uv_m2)
    assert scale.scaled(warned) is warned


def test_a_dwell_is_averaged_with_its_interleaved_halves_where_asked() -> None:
    """The even and the odd scans averaged apart: a drift over the dwell lies in both halves."""
    geometry = ScanGeometry(0, 1, 1, 0, 1440, 0.023, 30.0, 0.025)
    scans = [
        LaserScan(k, geometry, np.array([1.0 + k / 1000, 2.0]), np.array([1000 + k, 2000]), None, k / 40, 0.0)
        for k in range(8)
    ]
    assert average_scans(scans).halves is None
    even, odd = average_scans(scans, halves=True).halves or (None, None)
    assert even is not None and odd is not None
    assert (even.scan_count, odd.scan_count) == (4, 4)
    assert even.ranges_m[0] == pytest.approx(1.003) and odd.ranges_m[0] == pytest.approx(1.004)
