"""Do two scanners of a cell agree where both saw the rod at one waypoint?

At a shared waypoint scanner ``a`` measured the rod's centre ``x_a`` in its plane and
scanner ``b`` its centre ``x_b`` in its own. Mapped to the base frame by each scanner's pose,
``p_a = T_base_a x_a`` and ``p_b = T_base_b x_b`` are two points of the one rod axis, so
their difference is along the rod: its two components across the rod (in the plane normal
to the rod's direction, which the TCP pose gives) are zero up to noise. The test uses only
the rod's direction, not where the robot says the rod is, so the robot's absolute position
error, common to both points, drops out: it tests the two poses against each other.

Over all shared waypoints the residuals are stacked and whitened with their covariance:
each centre's covariance, and the two poses' covariances (6x6 each, the left perturbation of
``result.json``, taken as independent), which correlate the waypoints. The chi-square has
``2 k`` degrees of freedom; the poses disagree when it exceeds the 99 % quantile. With fewer
than ``MIN_SHARED_WAYPOINTS`` shared waypoints the verdict is ``inconclusive``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.stats import chi2

from lasercal_hw.models import FloatArray

MIN_SHARED_WAYPOINTS = 3
SIGNIFICANCE = 0.01


@dataclass(frozen=True)
class SharedCentre:
    """One waypoint both scanners saw: the two centres (u, v) [m] with their 2x2
    covariances [m^2], and the rod's unit direction in the base frame there."""

    waypoint: str  # whose waypoint and which ("front 3")
    centre_a_uv_m: FloatArray
    covariance_a_uv_m2: FloatArray
    centre_b_uv_m: FloatArray
    covariance_b_uv_m2: FloatArray
    rod_direction: FloatArray


def _across(direction: FloatArray) -> FloatArray:
    """A 2x3 orthonormal basis of the plane normal to ``direction``."""
    d = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    helper = np.eye(3)[int(np.argmin(np.abs(d)))]
    first = np.cross(d, helper)
    first /= np.linalg.norm(first)
    return np.vstack([first, np.cross(d, first)])


def _skew(v: FloatArray) -> FloatArray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _in_base(T: FloatArray, centre_uv_m: FloatArray, covariance_uv_m2: FloatArray) -> tuple[FloatArray, ...]:
    """The centre in the base frame, its 3x3 covariance, and its 3x6 Jacobian in the pose."""
    u, v = (float(c) for c in centre_uv_m)
    rotation, translation = T[:3, :3], T[:3, 3]
    lever = rotation @ np.array([u, v, 0.0])
    in_plane = rotation[:, :2]
    jacobian = np.hstack([np.eye(3), -_skew(lever)])  # p' = exp(e) R x + t + dt
    return lever + translation, in_plane @ np.asarray(covariance_uv_m2, dtype=float) @ in_plane.T, jacobian


def shared_residuals(
    T_base_a: FloatArray, T_base_b: FloatArray, shared: list[SharedCentre]
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """At each shared waypoint the two components across the rod of ``p_a - p_b`` (2k), their
    noise covariance from the two centres' (2k x 2k), and their Jacobians in a left
    perturbation of each pose (2k x 6 each)."""
    k = len(shared)
    T_a, T_b = np.asarray(T_base_a, dtype=float), np.asarray(T_base_b, dtype=float)
    residual = np.zeros(2 * k)
    noise = np.zeros((2 * k, 2 * k))
    jacobian_a = np.zeros((2 * k, 6))
    jacobian_b = np.zeros((2 * k, 6))
    for i, centre in enumerate(shared):
        across = _across(centre.rod_direction)
        p_a, cov_a, j_a = _in_base(T_a, centre.centre_a_uv_m, centre.covariance_a_uv_m2)
        p_b, cov_b, j_b = _in_base(T_b, centre.centre_b_uv_m, centre.covariance_b_uv_m2)
        rows = slice(2 * i, 2 * i + 2)
        residual[rows] = across @ (p_a - p_b)
        noise[rows, rows] = across @ (cov_a + cov_b) @ across.T
        jacobian_a[rows] = across @ j_a
        jacobian_b[rows] = -across @ j_b
    return residual, noise, jacobian_a, jacobian_b


def agreement_test(
    T_base_a: FloatArray, covariance_a: FloatArray, T_base_b: FloatArray, covariance_b: FloatArray,
    shared: list[SharedCentre],
) -> dict[str, Any]:
    """The chi-square test of the module docstring: ``verdict`` (``agree``, ``disagree`` or
    ``inconclusive``), ``shared_waypoints``, ``chi_square``, ``dof``, ``threshold`` and the
    RMS distance across the rod between the two centres in mm."""
    k = len(shared)
    document: dict[str, Any] = {
        "shared_waypoints": k, "waypoints": [s.waypoint for s in shared],
        "min_shared_waypoints": MIN_SHARED_WAYPOINTS,
    }
    if k < MIN_SHARED_WAYPOINTS:
        return document | {
            "verdict": "inconclusive", "chi_square": None, "dof": 2 * k, "threshold": None,
            "rms_across_rod_mm": None,
            "reason": f"{k} waypoints seen by both scanners; the test needs {MIN_SHARED_WAYPOINTS}",
        }
    residual, noise, jacobian_a, jacobian_b = shared_residuals(T_base_a, T_base_b, shared)
    covariance = (
        noise
        + jacobian_a @ np.asarray(covariance_a, dtype=float) @ jacobian_a.T
        + jacobian_b @ np.asarray(covariance_b, dtype=float) @ jacobian_b.T
    )
    statistic = float(residual @ np.linalg.solve(covariance, residual))
    threshold = float(chi2.ppf(1.0 - SIGNIFICANCE, 2 * k))
    verdict = "agree" if statistic <= threshold else "disagree"
    return document | {
        "verdict": verdict,
        "chi_square": statistic,
        "dof": 2 * k,
        "threshold": threshold,
        "rms_across_rod_mm": 1000.0 * float(np.sqrt(np.mean(residual.reshape(k, 2) ** 2) * 2)),
        "reason": f"chi-square {statistic:.1f} {'<=' if verdict == 'agree' else '>'} {threshold:.1f} "
        f"({2 * k} dof, {k} shared waypoints)",
    }
