"""CLI errors of ``lasercal fake robot`` and ``lasercal robot info`` (no robot needed)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from fakes.ur_controller.net import require_loopback
from lasercal_hw.errors import ConfigError, ExitCode
from tests.drivers.ur.conftest import StartFake


def run_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "lasercal_hw.cli.main", *args], capture_output=True,
                          text=True, timeout=60, stdin=subprocess.DEVNULL)


def test_fake_robot_refuses_a_non_loopback_address() -> None:
    result = run_cli("fake", "robot", "--address", "192.168.1.10")
    assert result.returncode == ExitCode.BAD_INPUT
    assert "not a loopback address" in result.stderr


def test_fake_robot_refuses_an_unknown_version() -> None:
    result = run_cli("fake", "robot", "--address", "127.0.0.250", "--version", "5.2")
    assert result.returncode == ExitCode.BAD_INPUT
    assert "--version must be one of" in result.stderr


def test_robot_info_without_a_robot_is_a_device_error() -> None:
    result = run_cli("robot", "info", "--robot", "127.0.0.253", "--timeout-s", "1")
    assert result.returncode == ExitCode.DEVICE_ERROR
    assert "cannot reach a UR controller on 127.0.0.253" in result.stderr


@pytest.mark.parametrize("address", ["localhost", "::1", "10.0.0.1", "127.0.0"])
def test_require_loopback_rejects(address: str) -> None:
    with pytest.raises(ConfigError):
        require_loopback(address)


def test_fake_robot_exits_cleanly_on_sigterm(start_fake: StartFake) -> None:
    fake = start_fake()
    assert fake.process is not None
    fake.process.terminate()
    assert fake.process.wait(timeout=10) == 0
    assert "Traceback" not in fake.stderr_text()
