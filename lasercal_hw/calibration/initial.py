"""Closed-form initial solution: no initial guess needed.

The measured centre is the base-frame point ``X_i = u_i r1 + v_i r2 + t`` (``r1``, ``r2``
the first two columns of R).  It lies on the rod line (origin ``o_i``, unit direction
``d_i``) exactly when ``d_i x X_i = d_i x o_i``, i.e.

    [d_i]x (u_i r1 + v_i r2 + t) = d_i x o_i

which is linear in the nine unknowns (r1, r2, t).  Each waypoint gives two independent
equations (the residual is the perpendicular distance of X_i from the line), so five
waypoints with varied rod directions suffice.  The stacked system is solved by least
squares with (u, v) centred for conditioning; ``[r1 r2]`` is then projected onto the
nearest pair of orthonormal columns (SVD), ``r3 = r1 x r2``, and t is re-solved with the
rotation fixed.
"""

from __future__ import annotations

import numpy as np

from lasercal_hw.geometry import FloatArray, skew


def linear_initial_pose(
    origins: FloatArray, directions: FloatArray, centres_uv_m: FloatArray, weights: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Rotation (3, 3) and translation (3,) of ``T_base_laser`` from the linear system above.

    ``weights`` (N,) scale each waypoint's equations (e.g. 1 / sigma).
    """
    n = len(origins)
    centre_mean = centres_uv_m.mean(axis=0)
    uv = centres_uv_m - centre_mean
    cross = skew(directions) * weights[:, None, None]  # (N, 3, 3)
    rhs = np.cross(directions, origins) * weights[:, None]
    system = np.concatenate(
        [cross * uv[:, 0, None, None], cross * uv[:, 1, None, None], cross], axis=2
    ).reshape(3 * n, 9)
    solution, *_ = np.linalg.lstsq(system, rhs.reshape(-1), rcond=None)
    columns = solution[:6].reshape(2, 3).T  # (3, 2): r1, r2
    left, _, right_t = np.linalg.svd(columns, full_matrices=False)
    r12 = left @ right_t
    rotation = np.column_stack([r12[:, 0], r12[:, 1], np.cross(r12[:, 0], r12[:, 1])])
    # Re-solve t with the rotation fixed: [d]x t = d x o - [d]x (u r1 + v r2).
    in_plane = centres_uv_m @ r12.T  # (N, 3)
    rhs_t = rhs - np.einsum("nij,nj->ni", cross, in_plane)
    translation, *_ = np.linalg.lstsq(cross.reshape(3 * n, 3), rhs_t.reshape(-1), rcond=None)
    return rotation, translation
