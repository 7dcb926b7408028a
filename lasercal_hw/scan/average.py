"""Per-beam robust average of the scans taken during one dwell.

For every beam: the median and the MAD (scaled to a gaussian sigma) of its valid
readings, rejection of readings further than ``reject_sigmas`` MAD-sigmas from the
median (this removes dropouts' neighbours, mixed-pixel flips and spikes), then the mean
of the inliers.  A beam is NaN when fewer than ``min_valid_fraction`` of the scans gave
it an inlier reading.  When the scans carry intensities (SCIP ME), each beam's intensity
is the mean over the same inlier readings.  Everything is vectorised over beams and scans.

A UTM-30LX-EW sometimes sends a step's reading again for the next step (range and intensity
alike: 24 % of adjacent steps in a public ME log, docs/scanner-model.md); averaged in, such
repeats drag every beam towards its neighbour's direction, an angular lag of about 0.4
beam steps that moved a 45 mm rod at 1-2 m sideways by 2-4 mm. With intensities a repeat
is told from a chance equal range by its equal intensity, and left out (the beam then counts
only the scans that measured it); without intensities it cannot be told and stays.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from lasercal_hw.errors import CalibrationError
from lasercal_hw.models import FloatArray, LaserScan, ScanGeometry

logger = logging.getLogger(__name__)

_MAD_TO_SIGMA = 1.4826


@dataclass(frozen=True)
class AveragedScan:
    """A dwell's scans reduced to one value per beam.

    ``std_m`` is the standard deviation of the mean (what a fit should weight with),
    ``reading_std_m`` that of a single reading; both are NaN where fewer than two
    readings were kept.  ``ranges_m`` is NaN where the beam was valid in too few scans.
    ``valid_count`` is how many scans gave the beam any reading (``count`` of them agreed);
    ``intensities`` the mean intensity of the kept readings, None when the scanner sent none;
    ``intensity_std`` that mean's standard deviation (NaN where fewer than two readings were kept).
    """

    ranges_m: FloatArray
    std_m: FloatArray
    reading_std_m: FloatArray
    count: NDArray[np.int64]
    angles_rad: FloatArray
    scan_count: int
    valid_count: NDArray[np.int64] | None = None
    intensities: FloatArray | None = None
    intensity_std: FloatArray | None = None

    @property
    def valid(self) -> NDArray[np.bool_]:
        """True where the averaged range is usable."""
        return np.isfinite(self.ranges_m)

    def points_m(self) -> FloatArray:
        """Beam end points (N, 2) in the scanner plane; NaN rows where invalid."""
        return self.ranges_m[:, None] * np.stack([np.cos(self.angles_rad), np.sin(self.angles_rad)], -1)

    @classmethod
    def from_ranges(
        cls, ranges_m: FloatArray, angles_rad: FloatArray, std_m: FloatArray | None = None
    ) -> AveragedScan:
        """Wrap one set of ranges (for instance a single scan) as an averaged scan."""
        ranges_m = np.asarray(ranges_m, dtype=float)
        std = np.full_like(ranges_m, np.nan) if std_m is None else np.asarray(std_m, dtype=float)
        return cls(
            ranges_m=ranges_m,
            std_m=std,
            reading_std_m=std.copy(),
            count=np.isfinite(ranges_m).astype(np.int64),
            angles_rad=np.asarray(angles_rad, dtype=float),
            scan_count=1,
        )


def _check_same_layout(scans: Sequence[LaserScan]) -> ScanGeometry:
    geometry = scans[0].geometry
    for scan in scans[1:]:
        if scan.geometry != geometry:
            raise CalibrationError(
                f"scan {scan.sequence} has a different beam layout ({scan.geometry}) from scan "
                f"{scans[0].sequence} ({geometry}); average only scans of one stream"
            )
    return geometry


def average_scans(
    scans: Sequence[LaserScan],
    *,
    reject_sigmas: float = 3.5,
    mad_floor_m: float = 0.001,
    min_valid_fraction: float = 0.5,
) -> AveragedScan:
    """Robust per-beam average of a dwell's scans (median + MAD rejection, mean of inliers).

    ``mad_floor_m`` keeps the rejection threshold above the 1 mm range quantisation when
    almost all readings are equal.  Raises ``CalibrationError`` for no scans or scans with
    different beam layouts.
    """
    if len(scans) == 0:
        raise CalibrationError("no scans to average: the dwell recorded no scan; check the scanner stream")
    geometry = _check_same_layout(scans)
    ranges = np.stack([np.asarray(s.ranges_m, dtype=float) for s in scans])
    scan_count = ranges.shape[0]
    repeated = _repeated_steps(scans, ranges)
    ranges = np.where(repeated, np.nan, ranges)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN beams are expected
        median = np.nanmedian(ranges, axis=0)
        mad_sigma = _MAD_TO_SIGMA * np.nanmedian(np.abs(ranges - median), axis=0)
    threshold = reject_sigmas * np.fmax(mad_sigma, mad_floor_m)
    inlier = np.abs(ranges - median) <= threshold  # NaN compares False
    count = inlier.sum(axis=0)
    valid_count = np.isfinite(ranges).sum(axis=0)
    kept = np.where(inlier, ranges, 0.0)
    safe_count = np.maximum(count, 1)
    mean = kept.sum(axis=0) / safe_count
    squares = np.where(inlier, (ranges - mean) ** 2, 0.0).sum(axis=0)
    reading_std = np.where(count >= 2, np.sqrt(squares / np.maximum(count - 1, 1)), np.nan)
    measured = scan_count - repeated.sum(axis=0)
    min_count = np.maximum(1, np.ceil(min_valid_fraction * measured))
    usable = count >= min_count
    mean = np.where(usable, mean, np.nan)
    reading_std = np.where(usable, reading_std, np.nan)
    logger.debug(
        "averaged %d scans: %d of %d beams usable", scan_count, int(usable.sum()), usable.size
    )
    return AveragedScan(
        ranges_m=mean,
        std_m=reading_std / np.sqrt(safe_count),
        reading_std_m=reading_std,
        count=count.astype(np.int64),
        angles_rad=geometry.angles_rad(),
        scan_count=scan_count,
        valid_count=valid_count.astype(np.int64),
        **_mean_intensities(scans, inlier, safe_count, usable),
    )


def _repeated_steps(scans: Sequence[LaserScan], ranges: FloatArray) -> NDArray[np.bool_]:
    """Readings that repeat the previous step's range and intensity exactly in the same scan
    (all False without intensities: a repeat is then not told from a chance equal range)."""
    repeated = np.zeros(ranges.shape, dtype=bool)
    if any(s.intensities is None for s in scans):
        return repeated
    values = np.stack([np.asarray(s.intensities, dtype=float) for s in scans])
    if values.shape != ranges.shape:
        return repeated
    with np.errstate(invalid="ignore"):
        repeated[:, 1:] = (ranges[:, 1:] == ranges[:, :-1]) & (values[:, 1:] == values[:, :-1])
    return repeated


def _mean_intensities(
    scans: Sequence[LaserScan], inlier: NDArray[np.bool_], count: NDArray[np.int64], usable: NDArray[np.bool_]
) -> dict[str, FloatArray]:
    """``intensities``, the mean intensity of each beam's inlier readings, and ``intensity_std``,
    that mean's standard deviation (NaN where the beam is unusable; the std also where fewer
    than two readings were kept); empty unless every scan carries intensities."""
    if any(s.intensities is None for s in scans):
        return {}
    values = np.stack([np.asarray(s.intensities, dtype=float) for s in scans])
    if values.shape != inlier.shape:
        return {}
    mean = np.where(inlier, values, 0.0).sum(axis=0) / count
    squares = np.where(inlier, (values - mean) ** 2, 0.0).sum(axis=0)
    std = np.where(count >= 2, np.sqrt(squares / np.maximum(count - 1, 1)), np.nan) / np.sqrt(count)
    return {"intensities": np.where(usable, mean, np.nan), "intensity_std": np.where(usable, std, np.nan)}
