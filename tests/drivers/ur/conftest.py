"""Fake-robot fixtures: each fake is a child process on its own loopback address."""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

import pytest
import rtde_control
import rtde_receive

from fakes.ur_controller.process import FakeRobot
from lasercal_hw.errors import TransportError
from tests.drivers.ur.robot_process import FakeRobotProcess, in_process_robot

# Addresses 127.0.0.<first>..: spread by process id so parallel pytest runs rarely meet,
# and skip addresses whose ports are taken (the fake exits with "cannot listen").
_BASE = 20 + (os.getpid() % 40) * 5
_next = [0]

StartFake = Callable[..., FakeRobotProcess]


def _start(extra_args: Sequence[str]) -> FakeRobotProcess:
    last_error: Exception | None = None
    for _ in range(30):
        octet = 20 + (_BASE - 20 + _next[0]) % 230
        _next[0] += 1
        fake = FakeRobotProcess(f"127.0.0.{octet}", list(extra_args))
        try:
            return fake.start()
        except TransportError as exc:
            if "cannot listen" not in str(exc):
                raise
            last_error = exc
    raise RuntimeError(f"no free loopback address for a fake robot: {last_error}")


@pytest.fixture
def start_fake() -> Iterator[StartFake]:
    """``start_fake(*args)`` starts a fake robot (CLI options as args); all are killed at teardown."""
    started: list[FakeRobotProcess] = []

    def start(*extra_args: str) -> FakeRobotProcess:
        fake = _start(extra_args)
        started.append(fake)
        return fake

    yield start
    for fake in started:
        fake.close()


def eventually(condition: Callable[[], bool], timeout_s: float = 2.0) -> bool:
    """True once ``condition()`` holds (polled every 2 ms), False after ``timeout_s``.

    A receive interface is a connection of its own and may lag the control connection
    by a package or two, so "the move returned" and "the stream shows it" differ slightly.
    """
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.002)
    return True


@contextmanager
def receive_interface(address: str) -> Iterator[rtde_receive.RTDEReceiveInterface]:
    """An RTDEReceiveInterface that is always disconnected (before its fake is killed)."""
    receive = rtde_receive.RTDEReceiveInterface(address)
    try:
        yield receive
    finally:
        receive.disconnect()


@contextmanager
def control_interface(address: str, *,
                      stop_script: bool = True) -> Iterator[rtde_control.RTDEControlInterface]:
    """An RTDEControlInterface that is always disconnected, its script stopped first
    unless ``stop_script`` is off (then the script keeps running, as after a plain disconnect)."""
    control = rtde_control.RTDEControlInterface(address)
    try:
        yield control
    finally:
        if stop_script and control.isProgramRunning():
            control.stopScript()
        control.disconnect()



@pytest.fixture
def robot() -> Iterator[FakeRobot]:
    """A ``FakeRobot`` in this process (``in_process_robot``: raw-socket tests only)."""
    with in_process_robot() as fake:
        yield fake
