"""A fake cell as a child process, for ``lasercal run --dry-run``.

The child is ``lasercal fake cell --address 127.x.y.z [--scene FILE]``: one process serving
a fake UR controller (ports 29999, 30004, 30003) and a fake UTM-30LX-EW (port 10940) that
share one simulated world. It announces readiness with one line on standard output::

    fake cell ready: {"robot_host": "127.0.0.7", "scanner_url": "scip+tcp://127.0.0.7:10940",
                      "T_base_laser": [[...4x4 row-major...]]}

(a single line: the prefix, then a JSON object with at least those keys; the matrix is the
ground truth the run is compared with). The cell runs on a random loopback address whose
ports are free, so dry runs and tests can run side by side. ``close`` stops the child on
every exit path (terminate, then kill).
"""

from __future__ import annotations

import json
import logging
import random
import selectors
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from fakes.cell import READY_PREFIX
from lasercal_hw.errors import DeviceTimeoutError, TransportError
from lasercal_hw.models import FloatArray

logger = logging.getLogger(__name__)

CELL_PORTS = (29999, 30004, 30003, 10940)
_ADDRESS_TRIES = 20


def ports_free(address: str, ports: tuple[int, ...] = CELL_PORTS) -> bool:
    """True when every port can be bound on ``address`` right now."""
    for port in ports:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
            try:
                probe.bind((address, port))
            except OSError:
                return False
    return True


def free_loopback_address(rng: random.Random | None = None) -> str:
    """A random 127.x.y.z (never 127.0.0.1) whose fake-cell ports are free."""
    rng = rng or random.Random()
    for _ in range(_ADDRESS_TRIES):
        address = f"127.{rng.randint(1, 254)}.{rng.randint(0, 255)}.{rng.randint(2, 254)}"
        if ports_free(address):
            return address
    raise TransportError(f"no free loopback address for a fake cell after {_ADDRESS_TRIES} tries")


def parse_ready_line(line: str) -> dict[str, Any]:
    """The JSON object of a fake cell's ready line (see the module docstring)."""
    document = json.loads(line[len(READY_PREFIX):])
    missing = {"robot_host", "scanner_url", "T_base_laser"} - set(document)
    if missing:
        raise TransportError(f"fake cell ready line lacks {sorted(missing)}: {line.strip()}")
    return document


class FakeCellProcess:
    """``lasercal fake cell`` as a child process (context manager)."""

    def __init__(
        self,
        *,
        scene: Path | None = None,
        address: str | None = None,
        extra_args: tuple[str, ...] = (),
        startup_timeout_s: float = 60.0,
    ) -> None:
        self.address = address or free_loopback_address()
        self.args = [sys.executable, "-m", "lasercal_hw.cli.main", "fake", "cell", "--address", self.address]
        if scene is not None:
            self.args += ["--scene", str(scene)]
        self.args += list(extra_args)
        self.startup_timeout_s = startup_timeout_s
        self.process: subprocess.Popen[str] | None = None
        self.info: dict[str, Any] = {}
        self._stderr = tempfile.TemporaryFile(mode="w+")  # noqa: SIM115 - lives until close()

    @property
    def pid(self) -> int:
        """Process id of the running child."""
        assert self.process is not None, "start() first"
        return self.process.pid

    @property
    def robot_host(self) -> str:
        """Where the fake robot controller listens."""
        return str(self.info["robot_host"])

    @property
    def scanner_url(self) -> str:
        """Where the fake scanner listens."""
        return str(self.info["scanner_url"])

    @property
    def ground_truth(self) -> FloatArray:
        """The cell's true ``T_base_laser``."""
        return np.asarray(self.info["T_base_laser"], dtype=float).reshape(4, 4)

    def start(self) -> FakeCellProcess:
        """Launch the child and wait for its ready line."""
        logger.info("starting fake cell: %s", " ".join(self.args))
        self.process = subprocess.Popen(
            self.args, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=self._stderr, text=True
        )
        assert self.process.stdout is not None
        deadline = time.monotonic() + self.startup_timeout_s
        with selectors.DefaultSelector() as selector:
            selector.register(self.process.stdout, selectors.EVENT_READ)
            while (remaining_s := deadline - time.monotonic()) > 0:
                if not selector.select(timeout=remaining_s):
                    continue
                line = self.process.stdout.readline()
                if line.startswith(READY_PREFIX):
                    self.info = parse_ready_line(line)
                    return self
                if not line:
                    error = self._stderr_tail()
                    self.close()
                    raise TransportError(f"the fake cell on {self.address} exited before ready: {error}")
        self.close()
        raise DeviceTimeoutError(
            f"the fake cell on {self.address} printed no ready line within {self.startup_timeout_s:g} s"
        )

    def _stderr_tail(self) -> str:
        self._stderr.flush()
        self._stderr.seek(0)
        return self._stderr.read().strip()[-800:]

    def close(self) -> None:
        """Stop the child (terminate, then kill) and reap it; safe to call twice."""
        process, self.process = self.process, None
        if process is not None:
            if process.poll() is None:
                process.terminate()
                try:
                    process.wait(timeout=10.0)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait(timeout=10.0)
            if process.stdout is not None:
                process.stdout.close()
        if not self._stderr.closed:
            self._stderr.close()

    def __enter__(self) -> FakeCellProcess:
        try:
            return self.start()
        except BaseException:
            self.close()
            raise

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
