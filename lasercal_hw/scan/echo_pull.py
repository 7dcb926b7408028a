"""How far a surface a pulse length behind a rod pulls the rod's echo peak towards it.

Beyond ``echo_merge_m`` the surface behind returns a lobe of its own, but the laser pulse is
long (about 1 m of range, docs/scanner-model.md), and the flank of that lobe still lifts the
far side of the rod's: the peak the scanner reports lies a little behind the rod.  A polished
10 mm drill bit at 0.54 m, the floor 0.99 m behind it with 11-20 % of each beam's power, read
8.6-18.7 mm long (docs/lab/solver-log.md, "The drill job's outliers").

The surface's power in a beam is its share of the spot (the part passing beside the rod)
times what it returns over the whole spot (its intensity in the background scan, squared:
the UTM's intensity grows like the square root of the peak power).  Beyond the merge the
beam's own intensity is the rod's lobe, whose peak carries only the pulse's tail of the
surface's power, so the rod's power is the beam's squared intensity less that tail.
"""

from __future__ import annotations

import numpy as np

from lasercal_hw.models import FloatArray

_FWHM_TO_SIGMA = 1.0 / (2.0 * np.sqrt(2.0 * np.log(2.0)))
#: Mean-shift steps (a surface share under a half converges in a few dozen).
_MEAN_SHIFT_STEPS = 60


def surface_share(
    beside_share: FloatArray,
    intensity: FloatArray,
    behind_intensity: FloatArray,
    depth_m: FloatArray,
    pulse_fwhm_m: float,
) -> FloatArray:
    """The surface's share of the power a beam returns (surface over rod plus surface) where
    it lies ``depth_m`` behind the rod, beyond the merge: ``beside_share`` of the spot passes
    beside the rod, the beam reads ``intensity`` and the surface alone ``behind_intensity``."""
    sigma_m = pulse_fwhm_m * _FWHM_TO_SIGMA
    surface = beside_share * behind_intensity**2
    tail = np.exp(-0.5 * (depth_m / sigma_m) ** 2)
    rod = np.fmax(intensity**2 - tail * surface, 1e-12)
    return surface / (rod + surface)


def tail_pull_m(share: FloatArray, depth_m: FloatArray, pulse_fwhm_m: float) -> FloatArray:
    """How far behind the rod's surface the rod's echo peak lies when a surface ``depth_m``
    behind it has ``share`` of the power: the peak of the two gaussian pulses nearest the rod,
    found by mean shift from the rod's range as the scanner finds its lobes.  About
    ``share / (1 - share) * depth * exp(-depth^2 / 2 sigma^2)`` for a small share: 6 mm for
    11 % 1.05 m behind, 26 mm for 30 % (the scanner model's: 5 and 24 mm); nothing from 2.5 m."""
    sigma_m = pulse_fwhm_m * _FWHM_TO_SIGMA
    pull = np.zeros_like(depth_m)
    for _ in range(_MEAN_SHIFT_STEPS):
        rod = (1.0 - share) * np.exp(-0.5 * (pull / sigma_m) ** 2)
        surface = share * np.exp(-0.5 * ((depth_m - pull) / sigma_m) ** 2)
        pull = depth_m * surface / np.fmax(rod + surface, 1e-300)
    return pull
