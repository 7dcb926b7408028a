"""The waypoints' residuals against the stated noise: whitened residuals, the chi-square(2) quantile of
the outlier test, degrees of freedom, the reduced chi-square and the residuals' scale."""

from __future__ import annotations

import math

import numpy as np

from lasercal_hw.calibration.model import effective_covariance, whiten_residual, whitening
from lasercal_hw.calibration.solver.data import _Data
from lasercal_hw.calibration.solver.extras import _Extras
from lasercal_hw.calibration.solver.options import SolverOptions
from lasercal_hw.geometry import FloatArray

_MEDIAN_CHI2_2DOF = 2.0 * np.log(2.0)


def _whitened(rotation: FloatArray, translation: FloatArray, data: _Data, opts: SolverOptions) -> FloatArray:
    """Whitened residual of every waypoint (N, 2); non-finite ones become infinite."""
    crossing, slope = data.predicted(rotation, translation)
    white = whitening(effective_covariance(data.covariance, slope, opts.robot_sigma_m))
    return np.nan_to_num(whiten_residual(white, crossing - data.centres), nan=np.inf)


def _chi2_2dof_quantile(probability: float) -> float:
    """The chi-square quantile with 2 degrees of freedom: that distribution is exponential with
    mean 2, so its quantile is closed-form (and scipy.stats, 0.3 s to import, is not needed)."""
    return -2.0 * math.log1p(-probability)


def _degrees_of_freedom(used: np.ndarray, extras: _Extras) -> int:
    """Two residuals per used waypoint less the pose's 6 and the extras' parameters."""
    return 2 * int(used.sum()) - 6 - extras.count


def _reduced_chi_square(m2: FloatArray, used: np.ndarray, extras: _Extras) -> float:
    """The chi-square of the waypoints' squared whitened residuals ``m2`` over the used ones,
    per degree of freedom (1 when there are none left to measure it)."""
    dof = _degrees_of_freedom(used, extras)
    return float(m2[used].sum() / dof) if dof > 0 else 1.0


def _residual_scale(
    rotation: FloatArray,
    translation: FloatArray,
    data: _Data,
    used: np.ndarray,
    opts: SolverOptions,
    extras: _Extras,
) -> float:
    """The fit's residuals in units of the stated noise: ``sqrt(reduced chi-square)``."""
    m2 = (_whitened(rotation, translation, data, opts) ** 2).sum(axis=1)
    return float(np.sqrt(_reduced_chi_square(m2, used, extras)))
