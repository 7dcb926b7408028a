"""The fake controller's own kinematics calibration: what its primary interface reports as
the kinematics info (a checksum per joint, the calibrated DH rows). It is identity data: the
fake moves on the nominal UR5 model whatever the calibration says (docs/ur.md)."""

from __future__ import annotations

import zlib
from dataclasses import dataclass, replace

from lasercal_hw.ur_kinematics import UR5

#: The checksums a fake reports unless its scene says otherwise (one per joint).
DEFAULT_CHECKSUMS = (0x5EC0A1D1, 0x5EC0A1D2, 0x5EC0A1D3, 0x5EC0A1D4, 0x5EC0A1D5, 0x5EC0A1D6)
#: How far a replaced joint's theta offset moves (rad): a new unit's zero is a little off.
REPLACED_JOINT_THETA_RAD = 2e-4
_ZERO6 = (0.0,) * 6


@dataclass(frozen=True)
class KinematicsCalibration:
    """Checksums and the corrections to the nominal UR5 DH table (m, rad)."""

    checksums: tuple[int, ...] = DEFAULT_CHECKSUMS
    delta_theta_rad: tuple[float, ...] = _ZERO6
    delta_a_m: tuple[float, ...] = _ZERO6
    delta_d_m: tuple[float, ...] = _ZERO6
    delta_alpha_rad: tuple[float, ...] = _ZERO6

    def rows(self) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
        """The calibrated DH rows theta, a, d, alpha: nominal UR5 plus the corrections."""
        def plus(nominal: tuple[float, ...], delta: tuple[float, ...]) -> tuple[float, ...]:
            return tuple(float(n + d) for n, d in zip(nominal, delta, strict=True))

        return (plus(_ZERO6, self.delta_theta_rad), plus(UR5.dh.a_m, self.delta_a_m),
                plus(UR5.dh.d_m, self.delta_d_m), plus(UR5.dh.alpha_rad, self.delta_alpha_rad))

    def with_joint_replaced(self, joint: int) -> KinematicsCalibration:
        """The calibration after joint ``joint`` (1-6) was replaced and calibrated again: a new
        checksum for it and a slightly different zero."""
        if not 1 <= joint <= 6:
            raise ValueError(f"joint {joint} does not exist; joints are 1 to 6")
        index = joint - 1
        checksums = list(self.checksums)
        checksums[index] = zlib.crc32(checksums[index].to_bytes(4, "big"))
        theta = list(self.delta_theta_rad)
        theta[index] += REPLACED_JOINT_THETA_RAD
        return replace(self, checksums=tuple(checksums), delta_theta_rad=tuple(theta))
