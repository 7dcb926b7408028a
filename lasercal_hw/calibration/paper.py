"""The paper's own formulation (section 3.3), kept for comparison.

Unknowns: ZYX Euler angles (yaw, pitch, roll) and translation of ``T_base_laser`` plus one
line parameter gamma_i per waypoint.  Error per waypoint (3D, base frame):
``E_i = R (u_i, v_i, 0) + t - (o_i + gamma_i d_i)``; minimise ``sum |E_i|^2`` starting from
all zeros with bounds t in [-2, 2] m and angles in [-2 pi, 2 pi] (gamma unbounded),
by scipy's trust-region-reflective method with a sparse Jacobian (the paper used Matlab's
fmincon, an interior-point method).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.optimize import least_squares

from lasercal_hw.calibration.model import euler_zyx_axes
from lasercal_hw.geometry import FloatArray, euler_zyx_to_matrix

TRANSLATION_BOUND_M = 2.0
ANGLE_BOUND_RAD = 2.0 * np.pi


@dataclass(frozen=True)
class PaperSolution:
    """Outcome of the paper's optimisation."""

    rotation: FloatArray
    translation_m: FloatArray
    line_parameters_m: FloatArray
    converged: bool
    evaluations: int
    message: str


def solve_paper(
    origins: FloatArray, directions: FloatArray, centres_uv_m: FloatArray, *, max_evaluations: int = 2000
) -> PaperSolution:
    """Run the paper's bounded 6 + N parameter problem from the zero start."""
    n = len(origins)
    points = np.column_stack([centres_uv_m, np.zeros(n)])
    rows = np.arange(3 * n)
    gamma_cols = 6 + np.repeat(np.arange(n), 3)
    pose_rows = np.repeat(rows, 6)
    pose_cols = np.tile(np.arange(6), 3 * n)

    def residual(x: FloatArray) -> FloatArray:
        rotation = euler_zyx_to_matrix(x[0], x[1], x[2])
        error = points @ rotation.T + x[3:6] - origins - x[6:, None] * directions
        return error.reshape(-1)

    def jacobian(x: FloatArray) -> sparse.csr_matrix:
        rotation = euler_zyx_to_matrix(x[0], x[1], x[2])
        rotated = points @ rotation.T  # (N, 3)
        axes = euler_zyx_axes(x[0], x[1])  # columns: d R / d angle_k = [axis_k]x R
        pose_block = np.empty((n, 3, 6))
        for k in range(3):
            pose_block[:, :, k] = np.cross(axes[:, k], rotated)
        pose_block[:, :, 3:] = np.eye(3)
        values = np.concatenate([pose_block.reshape(-1), -directions.reshape(-1)])
        return sparse.csr_matrix(
            (values, (np.concatenate([pose_rows, rows]), np.concatenate([pose_cols, gamma_cols]))),
            shape=(3 * n, 6 + n),
        )

    lower = np.concatenate([[-ANGLE_BOUND_RAD] * 3, [-TRANSLATION_BOUND_M] * 3, np.full(n, -np.inf)])
    upper = -lower
    fit = least_squares(
        residual,
        np.zeros(6 + n),
        jac=jacobian,
        bounds=(lower, upper),
        method="trf",
        x_scale="jac",
        max_nfev=max_evaluations,
        tr_solver="lsmr",  # sparse and iterative: no dense SVD of the (3N, 6+N) Jacobian
    )
    x = fit.x
    return PaperSolution(
        rotation=euler_zyx_to_matrix(x[0], x[1], x[2]),
        translation_m=x[3:6].copy(),
        line_parameters_m=x[6:].copy(),
        converged=bool(fit.success),
        evaluations=int(fit.nfev),
        message=str(fit.message),
    )
