"""One error hierarchy for the whole product.

The CLI maps each family to one exit code (see ``ExitCode``) and prints the message on
one line; ``--debug`` shows the traceback.  Every message should say what was wrong and
what to do about it.
"""

from __future__ import annotations

from enum import IntEnum


class ExitCode(IntEnum):
    """Process exit codes of the ``lasercal`` command (documented in the README)."""

    OK = 0
    QUALITY_GATE_FAILED = 1
    BAD_INPUT = 2
    DEVICE_ERROR = 3
    CALIBRATION_FAILED = 4
    BUSY = 5
    """The daemon already runs a job that moves the arm: the command was right, try it later."""
    INTERRUPTED = 130


class LasercalError(Exception):
    """Root of every error this project raises on purpose."""

    exit_code: ExitCode = ExitCode.BAD_INPUT


class ConfigError(LasercalError):
    """A configuration file, option or input file is invalid."""

    exit_code = ExitCode.BAD_INPUT


class DeviceError(LasercalError):
    """A device (robot or scanner) or its connection failed."""

    exit_code = ExitCode.DEVICE_ERROR


class TransportError(DeviceError):
    """The byte transport failed: connection refused, closed or reset."""


class DeviceTimeoutError(TransportError):
    """A device did not answer in time; no partial data is ever returned."""


class ProtocolError(DeviceError):
    """A device sent bytes that do not follow its protocol."""


class ChecksumError(ProtocolError):
    """A checksum on a received line did not match."""


class ScannerStatusError(DeviceError):
    """The scanner answered a command with an error status code."""

    def __init__(self, command: str, status: str, meaning: str) -> None:
        super().__init__(f"scanner refused {command!r}: status {status} ({meaning})")
        self.command = command
        self.status = status
        self.meaning = meaning


class RobotError(DeviceError):
    """The robot refused a command, stopped, or is not in a state to move."""


class ProtectiveStopError(RobotError):
    """The robot entered a protective or emergency stop; it never resumes by itself."""


class CalibrationError(LasercalError):
    """The data cannot give a trustworthy calibration."""

    exit_code = ExitCode.CALIBRATION_FAILED


class DegenerateDataError(CalibrationError):
    """Some direction of the transform is not observable from the given waypoints."""


class InterruptedRunError(LasercalError):
    """The run was interrupted by the operator (Ctrl-C) or by SIGTERM."""

    exit_code = ExitCode.INTERRUPTED
