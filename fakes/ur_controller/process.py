"""Run a fake UR controller in this process (``FakeRobot``), for the processes that host
the fake itself (``lasercal fake robot``, the fake cell, which also runs the fake scanner
next to it).

ur_rtde's constructors hold the GIL while they wait for the controller, so a fake must
never run as threads inside the process of an ur_rtde client: such a client starts it as a
child process (the fake cell, or ``lasercal fake robot``; tests/drivers/ur/robot_process.py).
"""

from __future__ import annotations

import os
import threading
from types import TracebackType

from fakes.ur_controller.controller import ControllerConfig, FakeController
from fakes.ur_controller.dashboard import Dashboard
from fakes.ur_controller.net import TcpListener, require_loopback
from fakes.ur_controller.primary_server import PRIMARY_PORT, PRIMARY_READ_ONLY_PORT, PrimaryServer
from fakes.ur_controller.rtde_server import RtdeServer
from fakes.ur_controller.script_server import ScriptServer
from lasercal_hw.errors import TransportError

DASHBOARD_PORT = 29999
RTDE_PORT = 30004
SCRIPT_PORT = 30003
READY_PREFIX = "fake robot ready"


class FakeRobot:
    """Controller + dashboard + RTDE + script + primary servers on one loopback address."""

    def __init__(self, address: str, config: ControllerConfig | None = None) -> None:
        self.address = require_loopback(address)
        self.controller = FakeController(config)
        self.rtde = RtdeServer(self.controller)
        self._listeners: list[TcpListener] = []
        self._thread = threading.Thread(target=self.controller.run, name="fake-ur-cycle", daemon=True)

    def start(self) -> None:
        """Bind the ports and start the controller cycle; TransportError if a port
        is taken (the listeners already bound are closed again)."""
        servers = [(DASHBOARD_PORT, Dashboard(self.controller).serve, "dashboard"),
                   (RTDE_PORT, self.rtde.serve, "rtde"),
                   (SCRIPT_PORT, ScriptServer(self.controller).serve, "script"),
                   (PRIMARY_PORT, PrimaryServer(self.controller).serve, "primary"),
                   (PRIMARY_READ_ONLY_PORT, PrimaryServer(self.controller).serve, "primary-read-only")]
        try:
            for port, handler, name in servers:
                self._listeners.append(TcpListener(self.address, port, handler, name))
        except TransportError:
            self.close()
            raise
        self.controller.add_drop_listener(self.drop_connections)
        self._thread.start()
        for listener in self._listeners:
            listener.start()

    def drop_connections(self) -> None:
        """Close every client connection; the ports keep listening."""
        for listener in self._listeners:
            listener.close_clients()

    def ready_line(self) -> str:
        """The line announcing readiness on standard output."""
        return (f"{READY_PREFIX}: address={self.address} version={self.controller.config.version_text} "
                f"dashboard={DASHBOARD_PORT} rtde={RTDE_PORT} script={SCRIPT_PORT} "
                f"primary={PRIMARY_PORT},{PRIMARY_READ_ONLY_PORT} pid={os.getpid()}")

    def close(self) -> None:
        """Stop the servers and the cycle; safe to call twice."""
        for listener in self._listeners:
            listener.close()
        self._listeners.clear()
        self.controller.stop()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)

    def __enter__(self) -> FakeRobot:
        self.start()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
