"""One transform's UR pose vector in plain floats, for the fake controller's 500 Hz cycle.

``lasercal_hw.geometry.matrix_to_pose`` is vectorised numpy: about 0.1 ms for a single
4x4 matrix, most of it array set-up, which the fake paid twice every cycle of a move.
These functions take the same steps in the same order on Python floats (IEEE doubles,
as numpy's element-wise arithmetic): Shepperd's quaternion, normalised, then the
rotation vector. The pose the fake streams agrees with numpy's to within 2 units in the
last place (tests/drivers/ur/test_fake_cycle.py): not to the bit, because numpy's own
``arctan2`` and ``linalg.norm`` may round differently from ``math.atan2`` and a plain sum
of squares (numpy 2.4.6: 1 ulp at one of the test's 99 poses).
"""

from __future__ import annotations

import math

from lasercal_hw.models import FloatArray

_SMALL_ANGLE_RAD = 1e-8  # lasercal_hw.geometry's threshold for the small-angle series


def _unit_w_positive(quat_xyzw: list[float]) -> list[float]:
    """The quaternion divided by its norm, sign chosen so that w >= 0."""
    x, y, z, w = quat_xyzw
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    unit = [x / norm, y / norm, z / norm, w / norm]
    return [-value for value in unit] if unit[3] < 0.0 else unit


def _quaternion(m: list[list[float]]) -> list[float]:
    """``(x, y, z, w)`` of a rotation matrix (rows), w >= 0: Shepperd's method."""
    trace = m[0][0] + m[1][1] + m[2][2]
    pivots = [trace, m[0][0], m[1][1], m[2][2]]
    best = pivots.index(max(pivots))
    if best == 0:
        candidate = [m[2][1] - m[1][2], m[0][2] - m[2][0], m[1][0] - m[0][1], 1.0 + trace]
    elif best == 1:
        candidate = [1.0 + 2 * m[0][0] - trace, m[0][1] + m[1][0], m[0][2] + m[2][0], m[2][1] - m[1][2]]
    elif best == 2:
        candidate = [m[0][1] + m[1][0], 1.0 + 2 * m[1][1] - trace, m[1][2] + m[2][1], m[0][2] - m[2][0]]
    else:
        candidate = [m[0][2] + m[2][0], m[1][2] + m[2][1], 1.0 + 2 * m[2][2] - trace, m[1][0] - m[0][1]]
    return _unit_w_positive(candidate)


def rotvec_of(transform: FloatArray) -> tuple[float, float, float]:
    """Rotation vector (angle in [0, pi]) of a 4x4 transform's (or 3x3 matrix's) rotation."""
    x, y, z, w = _unit_w_positive(_quaternion(transform.tolist()))
    sin_half = math.sqrt(x * x + y * y + z * z)
    angle = 2.0 * math.atan2(sin_half, w)
    scale = 2.0 if sin_half < _SMALL_ANGLE_RAD else angle / sin_half
    return x * scale, y * scale, z * scale


def pose_of(transform: FloatArray) -> tuple[float, ...]:
    """UR pose vector ``(x, y, z, rx, ry, rz)`` of a 4x4 transform."""
    return (float(transform[0, 3]), float(transform[1, 3]), float(transform[2, 3]), *rotvec_of(transform))
