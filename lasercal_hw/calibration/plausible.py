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


def check_physical(observations: Sequence[Observation]) -> np.ndarray:
    """``ConfigError`` naming the first row (by its index) holding an impossible value;
    else the rows (N, 8) of TCP pose and centre that were screened (NaN rows where a shape
    is wrong), for the solver to use.

    The rows are screened as one array (10,000 rows in a few ms); a row that fails the
    screen is examined on its own for the message."""
    table = _table(observations)
    with np.errstate(over="ignore", invalid="ignore"):
        suspect = np.isfinite(table).all(axis=1) & (
            (np.abs(table[:, :3]).max(axis=1) > MAX_TCP_DISTANCE_M / np.sqrt(3.0))
            | (np.abs(table[:, 3:6]).max(axis=1) > MAX_ROTATION_VECTOR_RAD / np.sqrt(3.0))
            | (np.abs(table[:, 6:]).max(axis=1) > MAX_CENTRE_DISTANCE_M)
        )
    for row in np.flatnonzero(suspect):
        problem = _problem(table[row, :6], table[row, 6:])
        if problem is not None:
            index = observations[row].index
            raise ConfigError(f"observation index {index}: {problem}; fix or remove that row")
    return table


def _table(observations: Sequence[Observation]) -> np.ndarray:
    """Rows (N, 8) of TCP pose and centre; NaN rows where a shape is wrong (the solver's own
    checks name shapes and NaN)."""
    try:
        poses = np.array([o.tcp_pose for o in observations], dtype=float)
        centres = np.array([o.centre_uv_m for o in observations], dtype=float)
        if poses.shape == (len(observations), 6) and centres.shape == (len(observations), 2):
            return np.hstack([poses, centres])
    except ValueError:  # ragged: some row has the wrong shape
        pass
    table = np.full((len(observations), 8), np.nan)
    for row, o in enumerate(observations):
        pose, centre = np.asarray(o.tcp_pose, dtype=float), np.asarray(o.centre_uv_m, dtype=float)
        if pose.shape == (6,) and centre.shape == (2,):
            table[row] = np.concatenate([pose, centre])
    return table


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
