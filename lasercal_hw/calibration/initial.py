"""Closed-form initial solution: no initial guess needed, and no trust in every row.

The measured centre is the base-frame point ``X_i = u_i r1 + v_i r2 + t`` (``r1``, ``r2``
the first two columns of R).  It lies on the rod line (origin ``o_i``, unit direction
``d_i``) exactly when ``d_i x X_i = d_i x o_i``, i.e.

    [d_i]x (u_i r1 + v_i r2 + t) = d_i x o_i

which is linear in the nine unknowns (r1, r2, t).  Each waypoint gives two independent
equations (the residual is the perpendicular distance of X_i from the line), so five
waypoints with varied rod directions suffice.  A stacked system is solved by least
squares with (u, v) centred for conditioning; ``[r1 r2]`` is then projected onto the
nearest pair of orthonormal columns (SVD), ``r3 = r1 x r2``, and t is re-solved with the
rotation fixed.

One gross outlier (a row 5 m off) drags a least-squares start far enough that the robust
refinement settles in the wrong place, so the start is a consensus (least median of
squares): the pose of every minimal subset of five waypoints (all of them when there are
few, else ``CONSENSUS_SUBSETS`` drawn with a fixed seed) is scored by the median distance
of the centres from their rod lines (all of them, or ``SCORING_ROWS`` drawn with a fixed
seed when there are more: a median over 1,000 rows is as sharp a score as over 10,000, at a
tenth of the cost); the rows within ``INLIER_SCALES`` robust scales of the best one are
solved together.
"""

from __future__ import annotations

import math
from itertools import combinations
from typing import NamedTuple

import numpy as np

from lasercal_hw.geometry import FloatArray, skew

MINIMAL_ROWS = 5
"""Waypoints in a minimal subset (10 equations for 9 unknowns)."""
CONSENSUS_SUBSETS = 200
"""Subsets drawn when there are more combinations: with 30 % outliers one in six is clean,
so all 200 are spoilt with probability 1e-16."""
SCORING_ROWS = 1_000
"""Rows each subset's pose is scored on when there are more (the median distance's standard
error is then about 4 % of the noise scale, far below the gap an outlier-spoilt subset opens)."""
INLIER_SCALES = 2.5
"""Rows farther than this many robust scales from the consensus pose are left out of the start."""
_RANK_TOLERANCE = 1e-9
_SEED = 20140614


class InitialPose(NamedTuple):
    """The start of the solver: ``T_base_laser``'s rotation (3, 3) and translation (3,), and
    which waypoints (N,) agree with it (the refinement starts from those)."""

    rotation: FloatArray
    translation: FloatArray
    agreeing: np.ndarray


def linear_initial_pose(
    origins: FloatArray, directions: FloatArray, centres_uv_m: FloatArray, weights: FloatArray
) -> InitialPose:
    """The linear solution on the rows that agree with the best minimal-subset pose (see
    the module docstring). ``weights`` (N,) scale each waypoint's equations (e.g. 1 / sigma).
    """
    agreeing = consensus_inliers(origins, directions, centres_uv_m, weights)
    rotation, translation, _ = _batched_poses(
        origins[None, agreeing], directions[None, agreeing], centres_uv_m[None, agreeing],
        weights[None, agreeing],
    )
    return InitialPose(rotation[0], translation[0], agreeing)


def consensus_inliers(
    origins: FloatArray, directions: FloatArray, centres_uv_m: FloatArray, weights: FloatArray
) -> np.ndarray:
    """Boolean mask (N,) of the rows consistent with the least-median-of-squares pose
    (every row when no subset determines a pose)."""
    n = len(origins)
    if n <= MINIMAL_ROWS:
        return np.ones(n, dtype=bool)
    subsets = _subsets(n)
    rotation, translation, determined = _batched_poses(
        origins[subsets], directions[subsets], centres_uv_m[subsets], weights[subsets]
    )
    if not determined.any():
        return np.ones(n, dtype=bool)
    rotation, translation = rotation[determined], translation[determined]
    rows = _scoring_rows(n)
    scored = weights[rows] * line_distances(
        rotation, translation, origins[rows], directions[rows], centres_uv_m[rows]
    )
    medians = np.median(scored, axis=1)
    best = int(np.argmin(medians))
    distances = weights * line_distances(
        rotation[best, None], translation[best, None], origins, directions, centres_uv_m
    )[0]
    # Rousseeuw's LMedS scale with its small-sample correction.
    scale = 1.4826 * (1.0 + 5.0 / max(len(rows) - MINIMAL_ROWS, 1)) * medians[best]
    inliers = distances <= INLIER_SCALES * scale
    if inliers.sum() < MINIMAL_ROWS:
        inliers[np.argsort(distances)[:MINIMAL_ROWS]] = True
    return inliers


def line_distances(
    rotation: FloatArray, translation: FloatArray, origins: FloatArray, directions: FloatArray,
    centres_uv_m: FloatArray,
) -> FloatArray:
    """Distance (K, N) of each centre, mapped to the base by each of K poses, from its rod line."""
    # (K, N, 3) through one batched matrix product; the cross product written out (np.cross
    # copies its operands, three times slower at K x N = 200 x 1,000).
    rel = np.matmul(centres_uv_m, rotation[:, :, :2].transpose(0, 2, 1))
    rel += translation[:, None, :] - origins
    d = directions
    c0 = d[:, 1] * rel[..., 2] - d[:, 2] * rel[..., 1]
    c1 = d[:, 2] * rel[..., 0] - d[:, 0] * rel[..., 2]
    c2 = d[:, 0] * rel[..., 1] - d[:, 1] * rel[..., 0]
    return np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)


def _scoring_rows(n: int) -> np.ndarray:
    """Indices of the rows the subsets' poses are scored on: all, or ``SCORING_ROWS`` of them."""
    if n <= SCORING_ROWS:
        return np.arange(n)
    return np.sort(np.random.default_rng(_SEED).choice(n, SCORING_ROWS, replace=False))


def _subsets(n: int) -> np.ndarray:
    """Row indices (K, MINIMAL_ROWS) of the minimal subsets to try: all of them when there are
    few, else ``CONSENSUS_SUBSETS`` uniform draws of distinct rows (drawn with replacement and
    redrawn where a row repeats: O(K), where shuffling every row was O(K N))."""
    if math.comb(n, MINIMAL_ROWS) <= CONSENSUS_SUBSETS:
        return np.array(list(combinations(range(n), MINIMAL_ROWS)))
    rng = np.random.default_rng(_SEED)
    subsets = rng.integers(0, n, (CONSENSUS_SUBSETS, MINIMAL_ROWS))
    while True:
        ordered = np.sort(subsets, axis=1)
        repeated = (ordered[:, 1:] == ordered[:, :-1]).any(axis=1)
        if not repeated.any():
            return subsets
        subsets[repeated] = rng.integers(0, n, (int(repeated.sum()), MINIMAL_ROWS))


def _batched_poses(
    origins: FloatArray, directions: FloatArray, centres_uv_m: FloatArray, weights: FloatArray
) -> tuple[FloatArray, FloatArray, np.ndarray]:
    """The linear solution for each of K row sets: rotations (K, 3, 3), translations (K, 3)
    and whether the set determined the nine unknowns (K,)."""
    k, m = origins.shape[:2]
    uv = centres_uv_m - centres_uv_m.mean(axis=1, keepdims=True)
    cross = skew(directions) * weights[..., None, None]  # (K, M, 3, 3)
    rhs = np.cross(directions, origins) * weights[..., None]  # (K, M, 3)
    system = np.concatenate(
        [cross * uv[..., 0, None, None], cross * uv[..., 1, None, None], cross], axis=3
    ).reshape(k, 3 * m, 9)
    solution, determined = _lstsq(system, rhs.reshape(k, 3 * m))
    columns = solution[:, :6].reshape(k, 2, 3).transpose(0, 2, 1)  # (K, 3, 2): r1, r2
    left, _, right_t = np.linalg.svd(columns, full_matrices=False)
    r12 = left @ right_t
    rotation = np.concatenate([r12, np.cross(r12[..., 0], r12[..., 1])[..., None]], axis=2)
    # Re-solve t with the rotation fixed: [d]x t = d x o - [d]x (u r1 + v r2).
    in_plane = np.einsum("kij,kmj->kmi", r12, centres_uv_m)  # (K, M, 3)
    rhs_t = rhs - np.einsum("kmij,kmj->kmi", cross, in_plane)
    translation, _ = _lstsq(cross.reshape(k, 3 * m, 3), rhs_t.reshape(k, 3 * m))
    return rotation, translation, determined


def _lstsq(system: FloatArray, rhs: FloatArray) -> tuple[FloatArray, np.ndarray]:
    """Least-squares solutions (K, P) of K systems (K, E, P), small singular values cut as
    ``np.linalg.lstsq`` cuts them (one system: numpy's own, bit for bit; many: one batched
    SVD), and whether each system has full rank (smallest singular value above
    ``_RANK_TOLERANCE`` of the largest)."""
    if len(system) == 1:
        solution, _, _, singular = np.linalg.lstsq(system[0], rhs[0], rcond=None)
        return solution[None], np.array([singular[-1] > _RANK_TOLERANCE * singular[0]])
    left, singular, right_t = np.linalg.svd(system, full_matrices=False)
    largest = singular[:, :1]
    kept = singular > np.finfo(float).eps * max(system.shape[1:]) * largest
    inverse = np.divide(1.0, singular, out=np.zeros_like(singular), where=kept)
    projected = np.einsum("kep,ke->kp", left, rhs) * inverse
    return np.einsum("kpq,kp->kq", right_t, projected), singular[:, -1] > _RANK_TOLERANCE * largest[:, 0]
