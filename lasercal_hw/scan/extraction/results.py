"""What ``find_rod_centre`` returns or raises: the rod's centre with its covariance and quality, and
the error saying why there is none."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from lasercal_hw.errors import CalibrationError
from lasercal_hw.models import FloatArray


class RodNotFoundError(CalibrationError):
    """The rod could not be found or fitted in a scan; the message says why."""


@dataclass(frozen=True)
class RodQuality:
    """How much to trust a rod centre."""

    beams_used: int
    fit_rms_m: float
    arc_span_deg: float
    estimated_radius_m: float | None
    mixed_pixels_dropped: int


@dataclass(frozen=True)
class RodCentre:
    """Where the rod axis pierces the scan plane, in the scanner frame (metres)."""

    centre_uv_m: FloatArray
    covariance_uv_m2: FloatArray
    quality: RodQuality
    beam_indices: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    #: Why this centre may be off by more than its covariance says (empty: no doubt).
    warnings: tuple[str, ...] = ()
    #: The part of ``covariance_uv_m2`` another dwell at the same pose draws anew: the dwell's
    #: noise through the fit. The rest (the rod's shape, edges, blends, the range error across
    #: the arc) repeats at the same pose and view. None: unknown, take the whole covariance.
    noise_covariance_uv_m2: FloatArray | None = None
    #: How far the middle of the rod's echo moved the fitted centre across its bearing (m, (2,)):
    #: None where no middle was read and the fit placed it (``_across_from_echo_middle``). A
    #: plain rod's verify compares centres placed alike (``verify/across_kind``).
    echo_middle_move_uv_m: FloatArray | None = None

    def dwell_noise_covariance_uv_m2(self) -> FloatArray:
        """The part of the covariance another dwell at this pose draws anew: all of it where
        unknown, and where the extraction warns that the centre may be off by more than its
        noise (a rod blended with the surface behind it): which beams its fit keeps changes
        from dwell to dwell, and the blend moves with them, so nothing of it is known to repeat
        at the pose (verify seed 6: a 20 mm rod at 1.2 m whose 3 beams were 192-194 at the
        calibration and 191-193 at the verify, 11.7 mm apart sideways against 2-3 mm of noise
        std: an unmoved scanner flagged at chi-square 62.6)."""
        noise = self.noise_covariance_uv_m2
        return self.covariance_uv_m2 if noise is None or self.warnings else noise
