"""The robot's kinematics calibration in a run and a verify: unreadable is a warning and
"unknown" (never a failure), a changed one names the change, an unknown one is not compared."""

from __future__ import annotations

import dataclasses

from drivers.access import DeviceAccess
from fakes.ur_controller.kinematics_calibration import KinematicsCalibration
from lasercal_hw.run.engine import _read_robot_calibration
from lasercal_hw.run.events import EventSink, RunEvent
from lasercal_hw.verify.identity import robot_calibration_check
from lasercal_hw.verify.verdict import decide
from tests.verify_helpers import fake_robot_calibration


def test_a_robot_whose_primary_interface_does_not_answer_is_a_warning_and_unknown() -> None:
    events: list[RunEvent] = []
    found = _read_robot_calibration(DeviceAccess(), "127.0.0.254", EventSink(events.append))  # nothing there
    assert found is None
    (warning,) = [e for e in events if e.kind == "warning"]
    assert warning.message.startswith("the robot's kinematics calibration is unknown and recorded as unknown")
    assert "cannot reach the robot's primary interface at 127.0.0.254:30011" in warning.message


def test_the_robot_calibration_check() -> None:
    then = fake_robot_calibration()
    replaced = fake_robot_calibration(KinematicsCalibration().with_joint_replaced(5))
    same = robot_calibration_check(then.as_dict(), then)
    assert same.matches and same.describe() == f"robot kinematics calibration: {then.checksum}"

    changed = robot_calibration_check(then.as_dict(), replaced)
    assert not changed.matches
    reason = f"the robot's kinematics calibration changed since the calibration: checksum {then.checksum} -> "
    assert changed.describe() == reason + replaced.checksum
    assert decide([changed], None, 1.0, 0.1).status == "recalibrate"

    moved_row = dataclasses.replace(then, dh_a_m=(0.0, -0.4251, *then.dh_a_m[2:]))
    assert "same checksum" in robot_calibration_check(then.as_dict(), moved_row).describe()

    unknown_now = robot_calibration_check(then.as_dict(), None)
    assert unknown_now.matches and "could not be read now; not compared" in unknown_now.describe()
    not_recorded = robot_calibration_check(None, then)
    assert not_recorded.matches and "not recorded with the calibration" in not_recorded.describe()
    garbled = robot_calibration_check({"checksum": "x"}, then)
    assert garbled.matches and "cannot be read; not compared" in garbled.describe()
