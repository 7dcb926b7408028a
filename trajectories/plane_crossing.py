"""Where a rod held by the TCP pierces a plane: the measurement model's geometry.

The rod is the line ``p(s) = origin_m + s * direction`` in the TCP frame (``RodLine``),
``0 <= s <= length_m``. Moved into the plane's frame (``inv(T_base_plane) @ T_base_tcp``),
it meets the plane z = 0 at the point whose (x, y) is what a scanner with that plane
would measure as the rod centre (u, v).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from lasercal_hw.geometry import FloatArray, invert_transform, make_transform
from lasercal_hw.models import RodLine

# A rod closer to parallel with the plane than this (|cos| of its angle to the normal)
# does not cross it anywhere useful.
_PARALLEL_COS = 1e-9


@dataclass(frozen=True)
class PlaneCrossings:
    """Rod/plane intersections for a stack of TCP poses (NaN where the rod is parallel).

    ``uv_m``: (n, 2) intersection in the plane frame; ``along_rod_m``: (n,) the line
    parameter s (distance from the rod origin along its unit direction);
    ``within_rod``: True where ``0 <= s <= length_m``; ``range_m`` and ``bearing_rad``:
    polar form of ``uv_m`` (bearing 0 along the plane frame's x axis, counter-clockwise).
    """

    uv_m: FloatArray
    along_rod_m: FloatArray
    within_rod: np.ndarray
    range_m: FloatArray
    bearing_rad: FloatArray


def rod_plane_crossings(T_base_tcp: ArrayLike, rod: RodLine, T_base_plane: ArrayLike) -> PlaneCrossings:
    """Intersect the rod held at each TCP pose (n, 4, 4) with the plane z = 0 of ``T_base_plane``."""
    tcp = np.asarray(T_base_tcp, dtype=float).reshape(-1, 4, 4)
    plane_tcp = invert_transform(np.asarray(T_base_plane, dtype=float)) @ tcp
    origin = (plane_tcp[:, :3, :3] @ np.asarray(rod.origin_m, dtype=float)) + plane_tcp[:, :3, 3]
    direction = plane_tcp[:, :3, :3] @ rod.unit_direction()
    parallel = np.abs(direction[:, 2]) < _PARALLEL_COS
    s = np.where(parallel, np.nan, -origin[:, 2] / np.where(parallel, 1.0, direction[:, 2]))
    uv = origin[:, :2] + s[:, None] * direction[:, :2]
    within = np.isfinite(s) & (s >= 0.0) & (s <= rod.length_m)
    return PlaneCrossings(
        uv_m=uv,
        along_rod_m=s,
        within_rod=within,
        range_m=np.hypot(uv[:, 0], uv[:, 1]),
        bearing_rad=np.arctan2(uv[:, 1], uv[:, 0]),
    )


def horizontal_plane(z_m: float) -> FloatArray:
    """``T_base_plane`` of the horizontal plane at height ``z_m`` in the base frame."""
    return make_transform(np.eye(3), [0.0, 0.0, z_m])
