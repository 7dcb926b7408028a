"""Speed of the fake world's scans and of rod extraction (not collected by pytest).

Run from the repository root: ``.venv/bin/python -m benchmarks.world_raycast``.
Figures are absolute medians and ratios against a reference measured in the same run
(one numpy pass over a scan: beam end points from 1081 ranges), plus the share of the
scanner's 25 ms scan period.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from fakes.world import World
from lasercal_hw.geometry import make_transform
from lasercal_hw.models import LaserScan
from lasercal_hw.scan.average import average_scans
from lasercal_hw.scan.extraction import find_rod_centre


def median_s(fn: Callable[[], object], repeats: int = 7, number: int = 200) -> float:
    """Median over ``repeats`` of the mean time of ``number`` calls."""
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(number):
            fn()
        samples.append((time.perf_counter() - start) / number)
    return float(np.median(samples))


def main() -> None:
    world = World.from_scene()
    rng = np.random.default_rng(0)
    T = world.ground_truth_T_base_laser @ make_transform(np.eye(3), [0.7, 0.1, -0.15])
    ranges = world.scan_ranges_m(T)
    angles = world.angles_rad

    def reference() -> object:
        return ranges[:, None] * np.stack([np.cos(angles), np.sin(angles)], -1)

    ref = median_s(reference, number=2000)
    scans = []
    for k in range(120):
        mm, intensity = world.scan_mm(T, rng)
        ranges_m = np.where(mm >= 23, mm / 1000.0, np.nan)
        scans.append(LaserScan(k, world.geometry, ranges_m, mm, intensity, 0.025 * k, 0.025 * k))
    averaged = average_scans(scans)
    # Where the run would look: the rod's crossing of the scan plane (the scene has other
    # rod-like objects, and the extraction refuses to choose among them unguided).
    point, axis = world.rod_shape_in_scanner(T)
    expected_uv_m = (point - point[2] / axis[2] * axis)[:2]
    radius_m = world.rod.radius_m
    background_scans = []
    T_away = world.ground_truth_T_base_laser @ make_transform(np.eye(3), [0.0, 0.0, 3.0])
    for scan in scans:
        mm, _ = world.scan_mm(T_away, rng)
        background_scans.append(
            LaserScan(scan.sequence, scan.geometry, np.where(mm >= 23, mm / 1000.0, np.nan), mm, None, 0, 0)
        )
    background = average_scans(background_scans)
    rows = [
        ("world.scan_ranges_m, noise-free", lambda: world.scan_ranges_m(T)),
        ("world.scan_ranges_m, all noise models", lambda: world.scan_ranges_m(T, rng)),
        ("world.scan_mm (wire values + intensities)", lambda: world.scan_mm(T, rng)),
        ("average_scans, 120 scans x 1081 beams", lambda: average_scans(scans)),
        (
            "find_rod_centre, no background",
            lambda: find_rod_centre(averaged, radius_m=radius_m, expected_uv_m=expected_uv_m),
        ),
        (
            "find_rod_centre, with background",
            lambda: find_rod_centre(
                averaged, radius_m=radius_m, background=background, expected_uv_m=expected_uv_m
            ),
        ),
    ]
    print(f"reference (beam end points of one scan): {ref * 1e6:.1f} us")
    print(f"{'operation':45s} {'median':>10s} {'x reference':>12s} {'% of 25 ms':>11s}")
    for name, fn in rows:
        number = 20 if name.startswith("average") else 200
        seconds = median_s(fn, number=number)
        print(f"{name:45s} {seconds * 1e6:8.0f} us {seconds / ref:12.1f} {100 * seconds / 0.025:10.2f}%")


if __name__ == "__main__":
    main()
