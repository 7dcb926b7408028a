"""The rod's cross-section in the scan plane (a circle, or an ellipse for a tilted rod) and the
directions about a centre."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lasercal_hw.errors import ConfigError
from lasercal_hw.models import FloatArray

_Z_AXIS = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class _Section:
    """The rod's cross-section shape in the scan plane."""

    axis: FloatArray  # unit rod axis, scanner frame, pointing to +z
    radius_m: float
    unknown_tilt_cos: float = 1.0  # axis unknown: cos of the largest tilt to allow for

    @property
    def widest_semi_axis_m(self) -> float:
        """Largest half-width the cross-section may show (the semi-major axis, or with an
        unknown axis that of the largest tilt allowed for)."""
        return self.radius_m / min(self.cos_tilt, self.unknown_tilt_cos)

    @property
    def cos_tilt(self) -> float:
        return abs(float(self.axis[2]))

    @property
    def semi_major_m(self) -> float:
        return self.radius_m / self.cos_tilt

    def major_dir(self) -> FloatArray:
        """Unit in-plane direction of the ellipse's major axis (x if untilted)."""
        xy = self.axis[:2]
        norm = float(np.linalg.norm(xy))
        return xy / norm if norm > 1e-12 else np.array([1.0, 0.0])

    def to_circle(self, points: FloatArray) -> FloatArray:
        """Squeeze the plane along the major axis so the ellipse becomes a circle."""
        e = self.major_dir()
        return points - (1.0 - self.cos_tilt) * (points @ e)[:, None] * e

    def from_circle(self, points: FloatArray) -> FloatArray:
        """Inverse of ``to_circle``."""
        e = self.major_dir()
        return points + (1.0 / self.cos_tilt - 1.0) * (points @ e)[:, None] * e


def _unit_axis(axis: FloatArray | None) -> FloatArray:
    if axis is None:
        return _Z_AXIS
    a = np.asarray(axis, dtype=float)
    norm = float(np.linalg.norm(a))
    if a.shape != (3,) or not norm > 0.0:
        raise ConfigError(f"axis_in_scanner must be a non-zero 3-vector, got {axis!r}")
    a = a / norm
    return a if a[2] >= 0.0 else -a


def _across_bearing(centre_uv_m: FloatArray) -> FloatArray:
    """The unit vector across the bearing of ``centre_uv_m`` (counterclockwise)."""
    return np.array([-centre_uv_m[1], centre_uv_m[0]]) / float(np.linalg.norm(centre_uv_m))
