"""Physically impossible observations are refused before any solving.

A calibration from a row 1e20 m away is not a calibration: the solver would return a
translation of 1e18 m, or fail inside LAPACK. Limits are generous (any arm, any SCIP
scanner) so that only values no cell can produce are refused; gross but possible errors
(a row 5 m off) are the robust solver's job, which flags them as outliers.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lasercal_hw.errors import ConfigError
from lasercal_hw.models import Observation

MAX_TCP_DISTANCE_M = 10.0
"""No arm's TCP is this far from its base (the largest UR reaches 1.75 m)."""
MAX_ROTATION_VECTOR_RAD = 2.0 * np.pi + 1e-6
"""A UR rotation vector's norm is an angle; more than a full turn is no pose (degrees?)."""
MAX_CENTRE_DISTANCE_M = 100.0
"""No SCIP scanner measures this far (a UTM-30LX-EW: 60 m)."""


def check_physical(observations: Sequence[Observation]) -> None:
    """``ConfigError`` naming the first row (by its index) holding an impossible value."""
    for o in observations:
        pose = np.asarray(o.tcp_pose, dtype=float)
        centre = np.asarray(o.centre_uv_m, dtype=float)
        if pose.shape != (6,) or centre.shape != (2,) or not np.isfinite([*pose, *centre]).all():
            continue  # the solver's own checks name shapes and NaN
        problem = _problem(pose, centre)
        if problem is not None:
            raise ConfigError(f"observation index {o.index}: {problem}; fix or remove that row")


def _length(vector: np.ndarray) -> float:
    """Euclidean length without overflow (1e200 stays 1e200, not inf)."""
    scale = float(np.max(np.abs(vector)))
    return scale * float(np.linalg.norm(vector / scale)) if scale > 0 else 0.0


def _problem(pose: np.ndarray, centre: np.ndarray) -> str | None:
    distance_m = _length(pose[:3])
    if distance_m > MAX_TCP_DISTANCE_M:
        return (f"TCP position {distance_m:.3g} m from the robot base is impossible (no arm reaches "
                f"{MAX_TCP_DISTANCE_M:g} m; positions are in metres)")
    angle_rad = _length(pose[3:])
    if angle_rad > MAX_ROTATION_VECTOR_RAD:
        return (f"TCP rotation vector of {angle_rad:.3g} rad is more than a full turn (rotation vectors are "
                "in radians, not degrees)")
    reach_m = float(np.max(np.abs(centre)))
    if reach_m > MAX_CENTRE_DISTANCE_M:
        return (f"rod centre {reach_m:.3g} m from the scanner is impossible (no scanner measures "
                f"{MAX_CENTRE_DISTANCE_M:g} m; u and v are in metres)")
    return None
