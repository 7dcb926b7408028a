"""The physical scanner model's truth for extraction tests and benchmarks: what a
calibration's range-error curve removes at a simulated rod."""

from __future__ import annotations

import numpy as np

from fakes.scanner_model.dwell import SimulatedDwell
from fakes.scanner_model.range_error import range_bias_m


def front_range_error_m(dwell: SimulatedDwell) -> float:
    """The model's range error (measured minus true) at the rod's front beam: its true range
    and noise-free intensity through the physical model's bias (what a calibration's curve
    removes at this distance for this rod; the ideal model has none by default)."""
    world = dwell.world
    if world.physical is None:
        return 0.0
    bearing = float(np.arctan2(dwell.centre_uv_m[1], dwell.centre_uv_m[0]))
    front = int(np.argmin(np.abs(np.angle(np.exp(1j * (world.angles_rad - bearing))))))
    _, intensity = world.scan_mm(dwell.T_base_tcp)
    range_m = float(np.linalg.norm(dwell.centre_uv_m)) - dwell.radius_m
    bias = range_bias_m(np.array([range_m]), intensity[[front]].astype(float), world.scene.physics)
    return float(bias[0])
