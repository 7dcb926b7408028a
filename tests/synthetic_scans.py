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


def real_like_scans(
    centre_uv_m: Sequence[float],
    radius_m: float,
    rng: np.random.Generator,
    *,
    background_m: float,
    ramp_beams: tuple[int, int] = (0, 0),
    ramp_step_m: float = 0.05,
    reading_sigma_m: float = 0.004,
    ramp_sigma_m: float = 0.003,
    range_bias_m: float = 0.0,
    edge_valid_fraction: float = 1.0,
    others: Sequence[tuple[Sequence[float], float]] = (),
    count: int = 120,
    rod_intensity: float = 8000.0,
    background_intensity: float = 1500.0,
) -> list[LaserScan]:
    """Scans of a rod as the issue 18 real data show it: a wall ``background_m`` from the
    scanner behind the rod; ``ramp_beams`` (left, right) steady mixed pixels on each side
    stepping ``ramp_step_m`` from the rod's edge range out towards the wall, at the wall's
    intensity; per-reading noise ``reading_sigma_m`` (``ramp_sigma_m`` on the ramps); a
    range bias added to every reading; the rod's two edge beams valid in only
    ``edge_valid_fraction`` of the scans; ``others``: (centre, radius) of other rods in
    view. Intensities ride along (SCIP ME)."""
    rod = rod_ranges(centre_uv_m, radius_m)
    wall = np.full(ANGLES.shape, background_m)
    clean = np.fmin(np.nan_to_num(rod, nan=np.inf), wall)
    for other_centre, other_radius in others:
        clean = np.fmin(clean, np.nan_to_num(rod_ranges(other_centre, other_radius), nan=np.inf))
    on_rod = np.flatnonzero(np.isfinite(rod) & (rod <= clean))
    first, last = int(on_rod[0]), int(on_rod[-1])
    intensity = np.where(clean < background_m, rod_intensity, background_intensity)
    sigma = np.full(ANGLES.shape, reading_sigma_m)
    for side, edge in ((-1, first), (1, last)):
        for k in range(1, ramp_beams[0 if side < 0 else 1] + 1):
            beam = edge + side * k
            clean[beam] = min(clean[edge] + k * ramp_step_m, clean[beam])
            intensity[beam], sigma[beam] = background_intensity, ramp_sigma_m
    out = []
    for k in range(count):
        wire_intensity = np.round(intensity * rng.normal(1.0, 0.02, clean.shape)).astype(np.int64)
        ranges = clean + range_bias_m + rng.normal(0.0, 1.0, clean.shape) * sigma
        lost = rng.random(2) > edge_valid_fraction
        ranges[[first, last]] = np.where(lost, np.nan, ranges[[first, last]])
        raw = np.where(np.isfinite(ranges), np.round(ranges * 1000.0), 1).astype(np.int64)
        out.append(
            LaserScan(
                sequence=k, geometry=UTM_GEOMETRY, ranges_m=np.where(raw >= 23, raw / 1000.0, np.nan),
                raw_ranges_mm=raw, intensities=wire_intensity, device_time_s=0.025 * k, host_time_s=0.025 * k,
            )
        )
    return out
