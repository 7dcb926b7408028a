"""``lasercal fake robot`` as a child process, for the UR client's tests: a fake must never
run as threads inside the process of an ur_rtde client (its constructors hold the GIL while
they wait for the controller). Starting it through the CLI tests that command too."""

from __future__ import annotations

import selectors
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from types import TracebackType

from fakes.ur_controller.controller import ControllerConfig
from fakes.ur_controller.net import require_loopback
from fakes.ur_controller.process import READY_PREFIX, FakeRobot
from lasercal_hw.errors import DeviceTimeoutError, TransportError


class FakeRobotProcess:
    """``lasercal fake robot`` as a child process; ``start`` returns once it printed its
    ready line, ``close`` terminates it (and kills it if it does not exit)."""

    def __init__(self, address: str, extra_args: Sequence[str] = (), startup_timeout_s: float = 20.0) -> None:
        self.address = require_loopback(address)
        self.args = [sys.executable, "-m", "lasercal_hw.cli.main", "fake", "robot",
                     "--address", address, *extra_args]
        self.startup_timeout_s = startup_timeout_s
        self.process: subprocess.Popen[str] | None = None
        self._stderr = tempfile.TemporaryFile(mode="w+")  # noqa: SIM115  (closed in close())
        self._stderr_text = ""
        self.ready_line = ""

    @property
    def pid(self) -> int:
        """Process id of the fake."""
        assert self.process is not None, "start() first"
        return self.process.pid

    def start(self) -> FakeRobotProcess:
        """Launch and wait for the ready line; TransportError if the fake exits first,
        DeviceTimeoutError if it stays silent."""
        self.process = subprocess.Popen(self.args, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                        stderr=self._stderr, text=True)
        assert self.process.stdout is not None
        deadline = time.monotonic() + self.startup_timeout_s
        with selectors.DefaultSelector() as selector:
            selector.register(self.process.stdout, selectors.EVENT_READ)
            while time.monotonic() < deadline:
                if not selector.select(timeout=deadline - time.monotonic()):
                    continue
                line = self.process.stdout.readline()
                if line.startswith(READY_PREFIX):
                    self.ready_line = line.strip()
                    return self
                if not line:
                    self.close()
                    error = self.stderr_text()
                    raise TransportError(f"fake robot on {self.address} exited before it was ready: "
                                         f"{error.strip()[-500:]}")
        self.close()
        raise DeviceTimeoutError(f"fake robot on {self.address} printed no ready line "
                                 f"within {self.startup_timeout_s:g} s")

    def stderr_text(self) -> str:
        """Everything the fake wrote to standard error so far."""
        if self._stderr.closed:
            return self._stderr_text
        self._stderr.flush()
        self._stderr.seek(0)
        text = self._stderr.read()
        self._stderr.seek(0, 2)
        return text

    def close(self) -> None:
        """Terminate the fake and reap it; safe to call twice (its stderr stays readable)."""
        if self.process is None:
            return
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout=5.0)
        if self.process.stdout is not None:
            self.process.stdout.close()
        self.process = None
        self._stderr_text = self.stderr_text()
        self._stderr.close()

    def __enter__(self) -> FakeRobotProcess:
        return self.start()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


@contextmanager
def in_process_robot(config: ControllerConfig | None = None) -> Iterator[FakeRobot]:
    """A ``FakeRobot`` (``config``) in this process on a free 127.0.0.200+ address, for
    raw-socket clients only (ur_rtde must never talk to an in-process fake)."""
    for octet in range(200, 250):
        fake = FakeRobot(f"127.0.0.{octet}", config)
        try:
            fake.start()
        except TransportError:
            continue
        try:
            yield fake
        finally:
            fake.close()
        return
    raise RuntimeError("no free loopback address")
