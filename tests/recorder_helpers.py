"""Deterministic scans and poses for the recorder tests (also used by the crash child)."""

from __future__ import annotations

import numpy as np

from lasercal_hw.models import LaserScan, ScanGeometry
from lasercal_hw.session.format import ranges_m_from_raw_mm

UTM_GEOMETRY = ScanGeometry(
    first_step=0,
    last_step=1080,
    cluster=1,
    front_step=540,
    steps_per_revolution=1440,
    min_range_m=0.023,
    max_range_m=60.0,
    scan_period_s=0.025,
)
START_TIME_S = 1_763_700_000.123456


def make_scan(sequence: int, *, geometry: ScanGeometry = UTM_GEOMETRY, intensities: bool = True) -> LaserScan:
    """Scan ``sequence`` of a reproducible stream: ranges with error codes and overflow
    values, intensities, awkward float times."""
    rng = np.random.default_rng(sequence)
    raw = rng.integers(0, 30_000, geometry.beam_count)
    raw[rng.integers(0, geometry.beam_count, 20)] = rng.integers(0, 23, 20)  # error codes
    raw[:3] = [65533, 60001, 60000]  # overflow, just above and at DMAX
    return LaserScan(
        sequence=sequence,
        geometry=geometry,
        ranges_m=ranges_m_from_raw_mm(raw, geometry),
        raw_ranges_mm=raw,
        intensities=rng.integers(0, 2**18, geometry.beam_count) if intensities else None,
        device_time_s=12.345 + sequence * 0.025 + 1e-7 * rng.random(),
        host_time_s=START_TIME_S + sequence * 0.025 + 1e-7 * rng.random(),
    )


def make_pose(k: int) -> np.ndarray:
    """A reproducible UR pose vector whose rotation angle may come close to pi."""
    rng = np.random.default_rng(10_000 + k)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = rng.uniform(0.0, np.pi * 0.999999)
    return np.concatenate([rng.uniform(-0.8, 0.8, 3), axis * angle])


def assert_scans_equal(actual: LaserScan, expected: LaserScan) -> None:
    """Bit-for-bit equality of two scans (NaN equal to NaN)."""
    assert actual.sequence == expected.sequence
    assert actual.geometry == expected.geometry
    assert actual.host_time_s == expected.host_time_s
    assert actual.device_time_s == expected.device_time_s
    assert actual.raw_ranges_mm.dtype == np.int64
    np.testing.assert_array_equal(actual.raw_ranges_mm, expected.raw_ranges_mm)
    assert actual.ranges_m.dtype == np.float64
    assert actual.ranges_m.tobytes() == np.asarray(expected.ranges_m, dtype=np.float64).tobytes()
    if expected.intensities is None:
        assert actual.intensities is None
    else:
        assert actual.intensities is not None
        np.testing.assert_array_equal(actual.intensities, expected.intensities)
