"""How wide a rod looks at a range, and whether a run of beams spans that (the size check of
segments and cores)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from lasercal_hw.models import FloatArray
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction.beams import _beam_step_rad
from lasercal_hw.scan.extraction.section import _Section
from lasercal_hw.scan.extraction.settings import ExtractionSettings
from lasercal_hw.scan.extraction.spot import _spot_sigma_m


def _widest_rad(range_m: float, section: _Section, settings: ExtractionSettings) -> float:
    """Widest angle a rod whose nearest point is at ``range_m`` may cover (range error allowed)."""
    return float(_widest_rad_array(np.array([range_m]), section, settings)[0])


def _widest_rad_array(range_m: FloatArray, section: _Section, settings: ExtractionSettings) -> FloatArray:
    """``_widest_rad`` for each of several nearest ranges."""
    nearest_centre_m = range_m + section.radius_m - settings.range_bias_allowance_m
    centre_m = np.fmax(nearest_centre_m, section.widest_semi_axis_m)
    return 2.0 * np.arcsin(np.fmin(1.0, section.widest_semi_axis_m / centre_m))


def _size_mismatch(
    scan: AveragedScan,
    beams: NDArray[np.int64],
    section: _Section,
    settings: ExtractionSettings,
    visible_fraction: float | None = None,
    *,
    partial: bool = False,
) -> float | None:
    """How far the segment's angular width is from the rod's (in beams); None if implausible.

    It must span ``visible_fraction`` (default ``settings.min_visible_fraction``) of the rod's
    angle; ``partial`` accepts any width up to the rod's (a rod cut by the field of view)."""
    step = _beam_step_rad(scan)
    centre_range = float(np.min(scan.ranges_m[beams])) + section.radius_m
    if centre_range <= section.widest_semi_axis_m:
        return None
    width_min = 2.0 * np.arcsin(min(1.0, section.radius_m / (centre_range + settings.range_bias_allowance_m)))
    width_max = _widest_rad(float(np.min(scan.ranges_m[beams])), section, settings)
    # Each beam stands for one step of angle: n beams cover n steps (a far rod's 3 beams
    # cover 3 steps, not the 2 between their centres).
    width = abs(float(scan.angles_rad[beams[-1]] - scan.angles_rad[beams[0]])) + step
    if visible_fraction is None:
        visible_fraction = settings.min_visible_fraction
    low = 0.0 if partial else visible_fraction * width_min - 2.0 * step
    nearest_m = float(np.min(scan.ranges_m[beams]))
    spot_rad = 4.0 * float(_spot_sigma_m(np.array([nearest_m]), settings)[0]) / max(nearest_m, 1e-3)
    high = width_max + spot_rad + 3.0 * step  # a near rod's echo wins while its spot touches it
    if not low <= width <= high:
        return None
    return abs(width - 0.5 * (width_min + width_max)) / max(step, 1e-9)
