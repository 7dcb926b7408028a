"""What a UTM-30LX-EW adds to a range: noise, bias and warm-up drift.

* noise: gaussian, ``sqrt(floor^2 + at_reference^2 * reference_intensity / intensity)``:
  shot-noise-like, so it grows with range (intensity falls) and falls with intensity;
* bias: a near-range term (the receiver's optics at the bottom of the range), the unit's
  own smooth curve over log range (seeded by ``unit_seed``), range walk with intensity
  (bright echoes read short), all within the data sheet's +-30 mm (``bias_limit_m``);
* warm-up drift: ``warmup_drift_m * exp(-elapsed / time_constant)`` after power-on.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from fakes.scene import PhysicsSettings
from lasercal_hw.models import FloatArray

_LOG_RANGE_ORIGIN_M = 0.1
_UNIT_CURVE_CYCLES_PER_EFOLD = (0.32, 0.75)


def range_sigma_m(intensity: FloatArray, physics: PhysicsSettings) -> FloatArray:
    """Per-reading standard deviation for echoes of the given intensity."""
    ratio = physics.reference_intensity / np.fmax(intensity, 1.0)
    return np.sqrt(physics.noise_floor_m**2 + physics.noise_at_reference_m**2 * ratio)


def unit_curve_m(ranges_m: FloatArray, physics: PhysicsSettings) -> FloatArray:
    """The unit's own smooth range error over distance (two sinusoids in log range)."""
    weights, phases = _unit_terms(physics.unit_seed)
    x = np.log(np.fmax(ranges_m, 1e-3) / _LOG_RANGE_ORIGIN_M)
    curve = sum(
        w * np.sin(2.0 * np.pi * f * x + phase)
        for w, f, phase in zip(weights, _UNIT_CURVE_CYCLES_PER_EFOLD, phases, strict=True)
    )
    return physics.unit_bias_m * curve


@lru_cache(maxsize=8)
def _unit_terms(unit_seed: int) -> tuple[tuple[float, float], tuple[float, float]]:
    """Weights and phases of a unit's curve: the same seed, the same unit."""
    rng = np.random.default_rng([unit_seed, 18])
    phases = rng.uniform(0.0, 2.0 * np.pi, 2)
    weights = np.array([0.75, 0.45]) * rng.choice([-1.0, 1.0], 2)
    return (float(weights[0]), float(weights[1])), (float(phases[0]), float(phases[1]))


def range_bias_m(ranges_m: FloatArray, intensity: FloatArray, physics: PhysicsSettings) -> FloatArray:
    """Systematic error (measured minus true) at these ranges and intensities."""
    near = physics.near_bias_m * np.exp(-(ranges_m - physics.near_bias_at_m) / physics.near_bias_decay_m)
    near = np.where(ranges_m < physics.near_bias_at_m, physics.near_bias_m, near)
    walk = -physics.walk_m_per_efold * np.log(np.fmax(intensity, 1.0) / physics.reference_intensity)
    walk = np.clip(walk, -physics.walk_limit_m, physics.walk_limit_m)
    total = near + unit_curve_m(ranges_m, physics) + walk
    return np.clip(total, -physics.bias_limit_m, physics.bias_limit_m)


def warmup_drift_m(elapsed_s: float | None, physics: PhysicsSettings) -> float:
    """Range drift ``elapsed_s`` after power-on (None: unknown, taken as warm)."""
    if physics.warm_at_start or elapsed_s is None:
        return 0.0
    return physics.warmup_drift_m * float(np.exp(-max(elapsed_s, 0.0) / physics.warmup_time_constant_s))
