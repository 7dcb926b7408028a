"""``lasercal robot ...``: look at a UR robot through ur_rtde (read-only commands)."""

from __future__ import annotations

import math
from dataclasses import asdict

import typer

from lasercal_hw.cli.common import console, print_json
from lasercal_hw.errors import LasercalError

robot_app = typer.Typer(no_args_is_help=True)  # its help is in cli/main.py, where it is listed


@robot_app.command("info")
def robot_info(
    robot: str = typer.Option(..., "--robot", help="Robot controller address, e.g. 192.168.1.10."),
    json_output: bool = typer.Option(False, "--json", help="Print one JSON document instead of text."),
    timeout_s: float = typer.Option(5.0, "--timeout-s", min=0.1, help="Connection timeout (s)."),
) -> None:
    """Show the robot's identity, modes, TCP pose, joint positions and kinematics calibration.

    Read-only: no control script is uploaded, a program running on the robot keeps running.
    """
    from drivers.ur.client import URRobot
    from drivers.ur.primary import read_robot_calibration

    with URRobot.connect(robot, timeout_s=timeout_s, control=False) as arm:
        identity = arm.identity()
        state = arm.state()
        tcp_pose = arm.tcp_pose().tolist()
        joints = arm.joint_positions_rad().tolist()
    try:
        calibration = read_robot_calibration(robot, timeout_s=timeout_s)
        status = calibration.calibration_status
        kinematics = f"{calibration.model}, checksum {calibration.checksum}, status {status}"
    except LasercalError as exc:
        calibration, kinematics = None, f"unknown ({exc})"
    if json_output:
        print_json({"robot": robot, "identity": asdict(identity), "state": asdict(state),
                    "tcp_pose": tcp_pose, "joint_positions_rad": joints,
                    "robot_calibration": None if calibration is None else calibration.as_dict()})
        return
    lines = [
        f"Robot {robot}: {identity.model}, serial {identity.serial_number}",
        f"Software: {identity.software_version} "
        f"(controller {'.'.join(map(str, identity.controller_version))})",
        f"Robot mode: {state.robot_mode}   safety: {state.safety_status}   program running: "
        f"{state.program_running}   remote control: {state.remote_control}",
        "TCP pose [m, rad]: " + ", ".join(f"{v:.6f}" for v in tcp_pose),
        "Joints [deg]: " + ", ".join(f"{math.degrees(v):.3f}" for v in joints),
        f"Kinematics calibration: {kinematics}",
    ]
    for line in lines:
        console.print(line, markup=False, soft_wrap=True)
