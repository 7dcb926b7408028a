"""What an averaged scan says of its beams one by one: each range's noise, the beam step, runs of
beams, and the beams that flipped between surfaces during the dwell (unstable mixed pixels)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from lasercal_hw.models import FloatArray
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction.settings import ExtractionSettings


def _range_sigma(scan: AveragedScan, settings: ExtractionSettings) -> FloatArray:
    """Per-beam sigma of the averaged range, with a fallback where it is unknown."""
    std = np.where(np.isfinite(scan.std_m), scan.std_m, settings.default_range_sigma_m)
    return np.fmax(std, settings.range_sigma_floor_m)


def _runs(mask: NDArray[np.bool_]) -> list[NDArray[np.int64]]:
    """Index arrays of the runs of consecutive True values."""
    padded = np.concatenate([[False], mask, [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return [np.arange(start, stop) for start, stop in zip(edges[::2], edges[1::2], strict=True)]


def _unstable_beams(scan: AveragedScan, settings: ExtractionSettings) -> NDArray[np.bool_]:
    """Beams whose readings did not settle on one surface during the dwell.

    At a depth edge a beam's footprint straddles rod and background and each scan returns
    one of them or a blend; the dwell average of such a beam is a value between the two with
    a spread far above the range noise, or (when the robust average rejected one mode) a
    value kept by few scans. A single scan (``scan_count`` 1) has no such evidence.
    """
    if scan.scan_count < 2:
        return np.zeros(scan.ranges_m.size, dtype=bool)
    # Readings the beam did not give at all (a weak echo at a far edge) are no flipping: only
    # the valid readings that disagree with the rest count against it.
    valid = scan.scan_count if scan.valid_count is None else scan.valid_count
    few = scan.count < settings.min_stable_fraction * valid
    spread = scan.reading_std_m
    finite = np.isfinite(spread) & np.isfinite(scan.ranges_m)
    if not finite.any():
        return few
    typical = float(np.median(spread[finite]))
    with np.errstate(invalid="ignore"):
        wide = spread > settings.max_spread_ratio * typical
    return few | wide


def _trim_unstable(beams: NDArray[np.int64], unstable: NDArray[np.bool_]) -> NDArray[np.int64]:
    """The segment without the unstable beams at its ends (mixed pixels joining the rod to
    the background); unstable beams inside it are kept."""
    stable = np.flatnonzero(~unstable[beams])
    if stable.size == 0:
        return beams[:0]
    return beams[stable[0] : stable[-1] + 1]


def _beam_step_rad(scan: AveragedScan) -> float:
    return float(np.median(np.abs(np.diff(scan.angles_rad)))) if scan.angles_rad.size > 1 else 0.0
