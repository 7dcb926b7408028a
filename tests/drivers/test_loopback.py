"""The loopback guard (``LASERCAL_LOOPBACK_ONLY``, on for the whole suite): every driver
refuses an address off 127.0.0.0/8 before a packet leaves. ``socket.create_connection`` is
replaced by one that fails the test, so a broken guard still sends nothing."""

from __future__ import annotations

import os
import socket
from collections.abc import Callable

import pytest

from drivers.hokuyo.transport import open_transport
from drivers.loopback import LOOPBACK_ONLY_ENV, check_host
from drivers.ur.client import probe_controller
from drivers.ur.dashboard import DashboardLink
from drivers.ur.primary import read_robot_calibration
from lasercal_hw.errors import ConfigError

OFF_LOOPBACK = "192.0.2.1"  # TEST-NET-1 (RFC 5737): never contacted, the guard refuses first

CONNECTIONS: dict[str, Callable[[], object]] = {
    "the scanner": lambda: open_transport(f"scip+tcp://{OFF_LOOPBACK}:10940", connect_timeout_s=0.1),
    "the UR controller": lambda: probe_controller(OFF_LOOPBACK, timeout_s=0.1),
    "the robot's dashboard": lambda: DashboardLink(OFF_LOOPBACK, timeout_s=0.1),
    "the robot's primary interface": lambda: read_robot_calibration(OFF_LOOPBACK, timeout_s=0.1),
}


@pytest.fixture(autouse=True)
def no_packet_leaves(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(address: tuple[str, int], *_args: object, **_kwargs: object) -> socket.socket:
        raise AssertionError(f"a connection to {address} was attempted")

    monkeypatch.setattr(socket, "create_connection", refuse)


def test_the_suite_runs_with_the_guard_on() -> None:
    assert os.environ.get(LOOPBACK_ONLY_ENV) == "the test suite"


@pytest.mark.parametrize("what", list(CONNECTIONS))
def test_every_driver_refuses_an_address_off_loopback(what: str) -> None:
    with pytest.raises(ConfigError) as refused:
        CONNECTIONS[what]()
    assert str(refused.value).startswith(f"{what} at {OFF_LOOPBACK} refused: ")
    assert "loopback addresses (127.0.0.X) only" in str(refused.value)


@pytest.mark.parametrize("host", ["localhost", "::1", "10.0.0.1", "robot.local", "0.0.0.0"])
def test_names_and_other_loopbacks_are_refused_too(host: str) -> None:
    with pytest.raises(ConfigError, match="refused"):
        check_host(host, "the robot")


def test_loopback_passes_and_without_the_guard_nothing_is_checked(monkeypatch: pytest.MonkeyPatch) -> None:
    check_host("127.0.0.1", "the robot")
    check_host("127.4.5.6", "the robot")
    monkeypatch.delenv(LOOPBACK_ONLY_ENV)
    check_host(OFF_LOOPBACK, "the robot")  # a real cell: the operator's address stands
