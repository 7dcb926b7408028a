"""The parameters estimated besides the pose's six (``_Extras``: the rod axis, the range error curve's
terms), and the Fisher information and Cramér-Rao std of the pose with them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lasercal_hw.calibration.model import extended_fisher_information
from lasercal_hw.calibration.solver.data import _Data
from lasercal_hw.calibration.solver.options import SolverOptions
from lasercal_hw.geometry import FloatArray


@dataclass(frozen=True)
class _Extras:
    """Which parameters besides the six of the pose are estimated."""

    axis: bool = False
    range_terms: int = 0
    axis_note: str = ""
    offset_note: str = ""

    @property
    def offset(self) -> bool:
        """Whether the range error curve (at least its offset) is estimated."""
        return self.range_terms > 0

    @property
    def count(self) -> int:
        return 4 * self.axis + self.range_terms


def _extended_fisher(
    rotation: FloatArray,
    translation: FloatArray,
    data: _Data,
    used: np.ndarray,
    opts: SolverOptions,
    extras: _Extras,
) -> FloatArray:
    """Fisher information of the pose and the extra parameters over the used waypoints."""
    return extended_fisher_information(
        rotation,
        translation,
        data.tcp_transforms[used],
        data.rod,
        data.covariance[used],
        opts.robot_sigma_m,
        data.range_curve_m,
        with_axis=extras.axis,
        with_offset=extras.range_terms,
    )


def _crb_std(fisher: FloatArray) -> FloatArray:
    """Cramér-Rao std of every parameter (infinite where the information is not finite)."""
    if not np.all(np.isfinite(fisher)):
        return np.full(fisher.shape[0], np.inf)
    return np.sqrt(np.clip(np.diag(np.linalg.pinv(fisher, rcond=1e-12, hermitian=True)), 0.0, None))
