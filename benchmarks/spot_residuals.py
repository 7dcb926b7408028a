"""How far the physical scanner model's noise-free readings of a rod lie from a ray's hit and
from what the extraction's spot model predicts (issue 18: the fit treated each beam as a ray).

    .venv/bin/python -m benchmarks.spot_residuals [--materials matte,painted,retro_tape,dark]

Rods of 4, 10, 20 and 45 mm at 0.15-3 m (a bearing of 0.3 rad), a wall 2.5 m behind (its echo
does not merge with the rod's), the model's range bias switched off so that what is left is
the spot's averaging alone. Per rod, over the beams whose centre ray meets it and whose reading
is the rod's: the reading minus the ray's hit (its middle beam, its two edge beams, RMS), beside
``sigma^2 / 2r`` (the spot's sagitta: sigma a quarter of the spot's 1/e^2 width), and the
reading minus the extraction's spot model at the true centre (``_spot_readings_m``: a gaussian
spot and its halo, each part of it returning by Lambert's cosine), RMS and worst. Figures in
mm; docs/extraction.md quotes their ranges, docs/lab/extraction-log.md ("The fit against the
spot") their table.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from fakes.scanner_model.dwell import simulate_dwell
from fakes.scene import PhysicsSettings
from lasercal_hw.scan.extraction import ExtractionSettings
from lasercal_hw.scan.extraction.section import _Section
from lasercal_hw.scan.extraction.spot import _spot_readings_m

RADII_M = (0.004, 0.010, 0.020, 0.045)
RANGES_M = (0.15, 0.3, 0.75, 1.5, 3.0)
BEARING_RAD = 0.3
NO_BIAS = PhysicsSettings(unit_bias_m=0.0, near_bias_m=0.0, walk_m_per_efold=0.0)


def residuals_mm(range_m: float, radius_m: float, material: str) -> tuple[np.ndarray, np.ndarray] | None:
    """Per beam on the rod: the noise-free reading minus the ray's hit, and minus the spot model."""
    centre = range_m * np.array([np.cos(BEARING_RAD), np.sin(BEARING_RAD)])
    dwell = simulate_dwell(
        centre, radius_m, material=material, background_m=2.5, scan_count=0, physics=NO_BIAS,  # type: ignore[arg-type]
    )
    readings = dwell.world.scan_ranges_m(dwell.T_base_tcp)
    angles = dwell.world.angles_rad
    directions = np.column_stack([np.cos(angles), np.sin(angles)])
    along = directions @ centre
    miss = directions[:, 0] * centre[1] - directions[:, 1] * centre[0]
    ray_m = along - np.sqrt(np.fmax(radius_m**2 - miss**2, 0.0))
    on_rod = (np.abs(miss) < radius_m) & np.isfinite(readings) & (np.abs(readings - ray_m) < radius_m)
    if not on_rod.any():
        return None
    points = readings[on_rod, None] * directions[on_rod]
    section = _Section(np.array([0.0, 0.0, 1.0]), radius_m)
    spot = _spot_readings_m(points, centre, section, radius_m, ExtractionSettings())
    assert spot is not None
    return 1000.0 * (readings[on_rod] - ray_m[on_rod]), 1000.0 * (readings[on_rod] - spot[0])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--materials", default="matte,painted,retro_tape,dark")
    args = parser.parse_args(argv)
    settings = ExtractionSettings()
    print(
        f"{'rod':>6s} {'range':>6s} {'material':10s} {'beams':>5s} | reading - ray: middle  edges        "
        "RMS  sigma^2/2r | reading - spot model: RMS  worst"
    )
    for radius_m in RADII_M:
        for range_m in RANGES_M:
            sigma_mm = 250.0 * (settings.spot_width_at_scanner_m + settings.spot_divergence_rad * range_m)
            sagitta_mm = sigma_mm**2 / (2000.0 * radius_m)
            for material in args.materials.split(","):
                label = f"{radius_m * 1000:4.0f} mm {range_m:4.2f} m {material:10s}"
                found = residuals_mm(range_m, radius_m, material)
                if found is None:
                    print(f"{label}     - (no beam reads the rod)")
                    continue
                ray, spot = found
                ray_rms, spot_rms = np.sqrt(np.mean(ray**2)), np.sqrt(np.mean(spot**2))
                print(
                    f"{label} {ray.size:5d} | {ray[ray.size // 2]:+18.2f} {ray[0]:+6.2f} {ray[-1]:+6.2f} "
                    f"{ray_rms:6.2f}  {sagitta_mm:10.2f} | {spot_rms:25.2f} {np.max(np.abs(spot)):6.2f}"
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
