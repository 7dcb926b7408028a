"""Does a still bar's place in the physical scanner model's scan depend on where it sits
between two beams?  (A polished surface's glint, issue 18; docs/scanner-model.md.)

    .venv/bin/python -m benchmarks.scanner_glint [--positions 16] [--sub-rays 21]

A noise-free 10 mm bar 0.45 m from the scanner, open space behind, at ``--positions``
bearings spread over one beam step; for each material (and a steel bar tilted 29 deg
across the bearing, as the drill job tilts its bit) it prints how far across the bearing
the model's scan puts it (the returned power's bearing: ``SimulatedDwell.
returned_power_bearing_rad``) at worst and from position to position.  The ideal answer is
0: any error that changes with the position is the model's sampling (aliasing).
"""

from __future__ import annotations

import argparse

import numpy as np

from fakes.scanner_model.dwell import simulate_dwell
from fakes.scene import PhysicsSettings

RANGE_M = 0.45
RADIUS_M = 0.005
BEARING_RAD = np.radians(-30.0)
STEP_RAD = np.radians(0.25)
BARS = (  # (label, material, tilt across the bearing in deg)
    ("steel_drill, upright", "steel_drill", 0.0),
    ("bare_metal, upright", "bare_metal", 0.0),
    ("painted, upright", "painted", 0.0),
    ("steel_drill, tilted 29 deg across", "steel_drill", 29.0),
)


def across_errors_mm(material: str, tilt_deg: float, positions: int, physics: PhysicsSettings) -> np.ndarray:
    """The bar's across-bearing error (mm) at each position between two beams."""
    errors = []
    for shift in np.linspace(0.0, 1.0, positions, endpoint=False):
        bearing = BEARING_RAD + shift * STEP_RAD
        across = np.array([-np.sin(bearing), np.cos(bearing), 0.0])
        tilt = np.radians(tilt_deg)
        axis = np.cos(tilt) * np.array([0.0, 0.0, 1.0]) + np.sin(tilt) * across
        centre = RANGE_M * np.array([np.cos(bearing), np.sin(bearing)])
        dwell = simulate_dwell(
            centre, RADIUS_M, material=material, axis=axis, background_m=None, scan_count=0, physics=physics
        )
        errors.append((dwell.returned_power_bearing_rad() - bearing) * RANGE_M * 1e3)
    return np.array(errors)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--positions", type=int, default=16, help="bearings over one beam step")
    parser.add_argument("--sub-rays", type=int, default=PhysicsSettings().sub_rays, help="sub-rays per beam")
    args = parser.parse_args()
    physics = PhysicsSettings(sub_rays=args.sub_rays)
    print(f"10 mm bar at {RANGE_M} m, {args.positions} positions over one beam step, "
          f"{args.sub_rays} sub-rays")
    for label, material, tilt_deg in BARS:
        errors = across_errors_mm(material, tilt_deg, args.positions, physics)
        print(f"  {label:36s} worst {np.abs(errors).max():5.2f} mm, from position to position "
              f"{np.ptp(errors):5.2f} mm, mean {errors.mean():+5.2f} mm")


if __name__ == "__main__":
    main()
