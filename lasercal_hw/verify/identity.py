"""The identity check: are the scanner, the robot and the rod the ones the calibration
was made with?  Recorded values come from the calibration's ``result.json`` (its ``run``
section: the preflight identities and the job); current ones from this verify's preflight
and job.  A value the calibration did not record is not compared (and said so)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from lasercal_hw.models import RobotCalibration, RobotIdentity, RodLine, ScannerIdentity

ROD_TOLERANCE_M = 0.0005
ROD_DIRECTION_TOLERANCE_DEG = 0.5


@dataclass(frozen=True)
class IdentityCheck:
    """One compared property."""

    name: str
    recorded: str | None
    current: str
    #: Says more than the two values: what changed, or why nothing was compared.
    note: str | None = None

    @property
    def matches(self) -> bool:
        """True when equal, or when the calibration did not record it."""
        return self.recorded is None or self.recorded == self.current

    def describe(self) -> str:
        """One line for a report."""
        if self.note is not None:
            return self.note if not self.matches else f"{self.name}: {self.current} ({self.note})"
        if self.recorded is None:
            return f"{self.name}: {self.current} (not recorded with the calibration)"
        if self.matches:
            return f"{self.name}: {self.current}"
        return f"{self.name} is {self.current}, the calibration was made with {self.recorded}"


def _text(record: dict[str, Any] | None, key: str) -> str | None:
    if not record or record.get(key) is None:
        return None
    return str(record[key])


def _rod_text(rod: RodLine) -> str:
    origin = ", ".join(f"{v * 1e3:.1f}" for v in np.asarray(rod.origin_m, dtype=float))
    direction = ", ".join(f"{v:.3f}" for v in rod.unit_direction())
    size = f"r {rod.radius_m * 1e3:.1f} mm, length {rod.length_m * 1e3:.0f} mm"
    return f"{size}, origin ({origin}) mm, axis ({direction})"


def _same_rod(a: RodLine, b: RodLine) -> bool:
    angle_deg = np.degrees(np.arccos(np.clip(a.unit_direction() @ b.unit_direction(), -1.0, 1.0)))
    return bool(
        abs(a.radius_m - b.radius_m) <= ROD_TOLERANCE_M
        and abs(a.length_m - b.length_m) <= ROD_TOLERANCE_M
        and np.linalg.norm(np.asarray(a.origin_m) - np.asarray(b.origin_m)) <= ROD_TOLERANCE_M
        and angle_deg <= ROD_DIRECTION_TOLERANCE_DEG
    )


ROBOT_CALIBRATION = "robot kinematics calibration"


def robot_calibration_check(
    recorded: dict[str, Any] | None, current: RobotCalibration | None
) -> IdentityCheck:
    """The robot's own kinematics calibration now against the one recorded with the
    calibration: a changed one names the change; an unknown one (either side) is not compared."""
    if current is None:
        return IdentityCheck(ROBOT_CALIBRATION, None, "unknown",
                             note="the robot's primary interface could not be read now; not compared")
    if recorded is None:
        return IdentityCheck(ROBOT_CALIBRATION, None, current.checksum)
    try:
        then = RobotCalibration.from_dict(recorded)
    except (KeyError, TypeError, ValueError):
        return IdentityCheck(ROBOT_CALIBRATION, None, current.checksum,
                             note="the calibration's record of it cannot be read; not compared")
    change = current.change_from(then)
    if change is None:
        return IdentityCheck(ROBOT_CALIBRATION, then.checksum, current.checksum)
    return IdentityCheck(
        ROBOT_CALIBRATION, then.checksum, f"{current.checksum} (changed)",
        note=f"the robot's kinematics calibration changed since the calibration: {change}",
    )


def check_identity(
    recorded_robot: dict[str, Any] | None,
    recorded_scanner: dict[str, Any] | None,
    recorded_rod: RodLine | None,
    robot: RobotIdentity,
    scanner: ScannerIdentity,
    rod: RodLine,
) -> list[IdentityCheck]:
    """Scanner serial and firmware, robot serial and model, and the rod, compared."""
    rod_now = _rod_text(rod)
    if recorded_rod is None:
        rod_then = None
    else:
        rod_then = rod_now if _same_rod(recorded_rod, rod) else _rod_text(recorded_rod)
    return [
        IdentityCheck("scanner serial", _text(recorded_scanner, "serial"), scanner.serial),
        IdentityCheck("scanner firmware", _text(recorded_scanner, "firmware"), scanner.firmware),
        IdentityCheck("robot serial", _text(recorded_robot, "serial_number"), robot.serial_number),
        IdentityCheck("robot model", _text(recorded_robot, "model"), robot.model),
        IdentityCheck("rod", rod_then, rod_now),
    ]
