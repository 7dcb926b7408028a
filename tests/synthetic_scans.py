"""Analytic scans of a rod (and a wall) for extraction tests, ray-cast exactly."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from fakes.raycast import ray_cylinder, ray_plane
from lasercal_hw.models import LaserScan, ScanGeometry
from lasercal_hw.scan.average import AveragedScan

UTM_GEOMETRY = ScanGeometry(
    first_step=0, last_step=1080, cluster=1, front_step=540, steps_per_revolution=1440,
    min_range_m=0.023, max_range_m=60.0, scan_period_s=0.025,
)
ANGLES = UTM_GEOMETRY.angles_rad()
DIRS = np.stack([np.cos(ANGLES), np.sin(ANGLES), np.zeros_like(ANGLES)], -1)


def rod_ranges(
    centre_uv_m: Sequence[float],
    radius_m: float,
    *,
    axis: Sequence[float] = (0.0, 0.0, 1.0),
    wall_behind_m: float | None = None,
) -> np.ndarray:
    """Noise-free ranges (NaN = no return) of an infinite rod piercing the plane at the
    centre, optionally with a wall facing the scanner ``wall_behind_m`` behind the centre."""
    centre = np.array([centre_uv_m[0], centre_uv_m[1], 0.0])
    a = np.asarray(axis, dtype=float)
    t = ray_cylinder(np.zeros(3), DIRS, centre, a / np.linalg.norm(a), radius_m)
    if wall_behind_m is not None:
        normal = centre / np.linalg.norm(centre)
        t = np.fmin(t, ray_plane(np.zeros(3), DIRS, centre + wall_behind_m * normal, normal))
    return np.where(np.isfinite(t), t, np.nan)


def averaged(ranges_m: np.ndarray, sigma_m: float, rng: np.random.Generator) -> AveragedScan:
    """An averaged scan whose beams carry gaussian noise of ``sigma_m`` (std of the mean)."""
    noisy = ranges_m + rng.normal(0.0, sigma_m, ranges_m.shape)
    return AveragedScan.from_ranges(noisy, ANGLES, np.full_like(ranges_m, sigma_m))


def scans(ranges_m: np.ndarray, sigma_m: float, count: int, rng: np.random.Generator) -> list[LaserScan]:
    """``count`` single scans with gaussian noise, quantised to mm like the wire format."""
    out = []
    for k in range(count):
        noisy_mm = np.round((ranges_m + rng.normal(0.0, sigma_m, ranges_m.shape)) * 1000.0)
        raw = np.where(np.isfinite(noisy_mm), noisy_mm, 1).astype(np.int64)
        out.append(
            LaserScan(
                sequence=k, geometry=UTM_GEOMETRY, ranges_m=np.where(raw >= 23, raw / 1000.0, np.nan),
                raw_ranges_mm=raw, intensities=None, device_time_s=0.025 * k, host_time_s=0.025 * k,
            )
        )
    return out
