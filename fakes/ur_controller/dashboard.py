"""Dashboard server (port 29999): one ASCII command per line, one reply line each.

Replies end in a bare ``\\n`` (ur_rtde compares several of them exactly). The reply texts
follow Universal Robots' dashboard server (protocol reference, section 6).
"""

from __future__ import annotations

import logging
import socket

from fakes.ur_controller.controller import (
    ROBOT_MODE_IDLE,
    ROBOT_MODE_NAMES,
    ROBOT_MODE_POWER_OFF,
    ROBOT_MODE_RUNNING,
    SAFETY_MODE_NAMES,
    FakeController,
)
from fakes.ur_controller.net import read_lines

logger = logging.getLogger(__name__)

BANNER = "Connected: Universal Robots Dashboard Server"
_BUILD_DATE = "(Jan 27 2022)"


FAKE_REPLACE_JOINT = "fake replace joint"
"""The fake's own command (a real dashboard answers "could not understand"): ``fake replace
joint N`` changes the robot's kinematics calibration as a joint replacement does."""


class Dashboard:
    """Answers dashboard commands from the controller's state."""

    def __init__(self, controller: FakeController) -> None:
        self.controller = controller

    def _e_series_5_6(self) -> bool:
        major, minor = self.controller.config.version[:2]
        return (major == 5 and minor >= 6) or major > 5

    def _replace_joint(self, argument: str) -> str:
        try:
            calibration = self.controller.replace_joint(int(argument))
        except ValueError:
            return f"could not understand: 'fake replace joint {argument}' (joint 1 to 6)"
        checksums = " ".join(f"{c:08x}" for c in calibration.checksums)
        return f"Joint {argument} replaced: kinematics checksums {checksums}"

    def reply(self, command: str) -> tuple[str, bool]:
        """The reply line for one command, and whether to close the connection."""
        ctrl = self.controller
        text = command.strip()
        lower = text.lower()
        if lower.startswith(FAKE_REPLACE_JOINT):
            return self._replace_joint(lower[len(FAKE_REPLACE_JOINT):].strip()), False
        if lower == "robotmode":
            return f"Robotmode: {ROBOT_MODE_NAMES[ctrl.robot_mode]}", False
        if lower == "safetystatus":
            return f"Safetystatus: {SAFETY_MODE_NAMES[ctrl.safety_mode]}", False
        if lower == "safetymode":
            return f"Safetymode: {SAFETY_MODE_NAMES[ctrl.safety_mode]}", False
        if lower == "polyscopeversion":
            return f"URSoftware {ctrl.config.version_text} {_BUILD_DATE}", False
        if lower == "version" and self._e_series_5_6():
            return f"Version: {ctrl.config.version_text}", False
        if lower == "get serial number" and self._e_series_5_6():
            return ctrl.config.serial_number, False
        if lower == "get robot model" and self._e_series_5_6():
            return ctrl.config.model, False
        if lower == "is in remote control" and self._e_series_5_6():
            return "true" if ctrl.remote_control else "false", False
        if lower == "running":
            return f"Program running: {'true' if ctrl.program_running() else 'false'}", False
        if lower == "programstate":
            state = "PLAYING" if ctrl.program_running() else "STOPPED"
            return f"{state} {ctrl.program_name}", False
        if lower == "stop":
            if not ctrl.remote_control:
                return "Command is not allowed due to safety reasons", False
            ctrl.stop_program()
            return "Stopped", False
        if lower == "play":
            return "Failed to execute: play", False
        if lower == "pause":
            return "Failed to execute: pause", False
        if lower == "unlock protective stop":
            refusal = ctrl.unlock_protective_stop()
            return (refusal or "Protective stop releasing"), False
        if lower == "power on":
            ctrl.set_robot_mode(ROBOT_MODE_IDLE)
            return "Powering on", False
        if lower == "power off":
            ctrl.set_robot_mode(ROBOT_MODE_POWER_OFF)
            return "Powering off", False
        if lower == "brake release":
            ctrl.set_robot_mode(ROBOT_MODE_RUNNING)
            return "Brake releasing", False
        if lower == "isprogramsaved":
            return f"True {ctrl.program_name}", False
        if lower == "get loaded program":
            return "No program loaded", False
        if lower.startswith("load "):
            return f"File not found: {text[5:]}", False
        if lower == "close popup":
            return "closing popup", False
        if lower == "close safety popup":
            return "closing safety popup", False
        if lower.startswith("popup"):
            return "showing popup", False
        if lower.startswith("addtolog"):
            return "Added log message", False
        if lower == "restart safety":
            return "Restarting safety", False
        if lower == "shutdown":
            return "Shutting down", False
        if lower == "quit":
            return "Disconnected", True
        return f"could not understand: '{text}'", False

    def serve(self, sock: socket.socket) -> None:
        """Serve one client until it disconnects or sends ``quit``."""
        sock.sendall((BANNER + "\n").encode())
        next_line = read_lines(sock)
        while True:
            line = next_line()
            if line is None:
                return
            answer, close = self.reply(line)
            logger.debug("dashboard %r -> %r", line, answer)
            sock.sendall((answer + "\n").encode())
            if close:
                return
