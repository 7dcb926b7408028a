"""A fake cell as a child process: what a dry run (``lasercal run --dry-run``, the daemon's
``dry_run`` jobs, ``lasercal serve --dry-run``) asks for when it needs a cell.

The child is ``python -m fakes.cell --address 127.x.y.z [--scene FILE]``: one process serving
a fake UR controller (ports 29999, 30004, 30003, 30001, 30011) and a fake UTM-30LX-EW per
scene scanner (ports 10940, 10941, ...) that share one simulated world. It announces readiness
with one line on standard output::

    fake cell ready: {"robot_host": "127.0.0.7", "scanner_url": "scip+tcp://127.0.0.7:10940",
                      "T_base_laser": [[...4x4 row-major...]]}

(a single line: the prefix, then a JSON object with at least those keys; the matrix is the
ground truth the run is compared with). The cell runs on a random loopback address whose
ports are free, so dry runs and tests can run side by side.

The child never outlives this process and never takes a signal meant for it: it runs in
its own session (a terminal's Ctrl-C goes to the foreground process group, and the run
must still talk to the fake robot to stop the arm), and it watches its standard input, a
pipe this process holds (``--lifeline-stdin``): when this process dies, even by SIGKILL,
the pipe closes and the cell stops. ``stop`` ends the child on every exit path (closes
the lifeline, then terminate, then kill). A cell that dies on its own is reported at once
(``death``, a log error and the ``on_death`` callback) so a run can say why its devices
went silent.
"""

from __future__ import annotations

import json
import logging
import os
import random
import selectors
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from fakes.cell import READY_PREFIX
from lasercal_hw.errors import ConfigError, DeviceTimeoutError, InterruptedRunError, TransportError
from lasercal_hw.models import FloatArray

logger = logging.getLogger(__name__)

CELL_PORTS = (29999, 30004, 30003, 30001, 30011, 10940)
#: One BLAS thread in the cell unless the environment says otherwise, as ``lasercal`` sets for
#: itself and its children (``lasercal_hw.cli.threads``): a cell started from a script or the
#: daemon's library code runs as one the CLI started did.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")
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
    """The fake cell as a child process: ``start`` (returns once it is ready), ``ready``,
    its addresses and ground truth, ``alive``, ``stop``; also a context manager."""

    def __init__(
        self,
        *,
        scene: Path | None = None,
        address: str | None = None,
        startup_timeout_s: float = 60.0,
        on_death: Callable[[str], None] | None = None,
        serving: str = "during the run",
    ) -> None:
        self.address = address or free_loopback_address()
        self.args = [sys.executable, "-m", "fakes.cell", "--lifeline-stdin", "--address", self.address]
        if scene is not None:
            self.args += ["--scene", str(scene)]
        self.startup_timeout_s = startup_timeout_s
        self.process: subprocess.Popen[str] | None = None
        self.info: dict[str, Any] = {}
        self.death: str | None = None
        """Why the cell stopped by itself (None while it runs, or when ``stop`` ended it)."""
        self._on_death = on_death
        self._serving = serving  # what the cell was doing, for the message when it dies
        self._closing = threading.Event()
        self._stderr = tempfile.TemporaryFile(mode="w+")  # noqa: SIM115 - lives until stop()

    @property
    def pid(self) -> int:
        """Process id of the running child."""
        assert self.process is not None, "start() first"
        return self.process.pid

    @property
    def ready(self) -> bool:
        """True once the cell announced itself and while it runs."""
        return bool(self.info) and self.alive

    @property
    def alive(self) -> bool:
        """True while the child process runs."""
        return self.process is not None and self.process.poll() is None

    @property
    def robot_host(self) -> str:
        """Where the fake robot controller listens."""
        return str(self.info["robot_host"])

    @property
    def scanner_url(self) -> str:
        """Where the fake scanner (the first one) listens."""
        return str(self.info["scanner_url"])

    @property
    def ground_truth(self) -> FloatArray:
        """The cell's true ``T_base_laser`` (of the first scanner)."""
        return np.asarray(self.info["T_base_laser"], dtype=float).reshape(4, 4)

    def scanner(self, name: str | None) -> tuple[str, FloatArray]:
        """Where the scene's scanner ``name`` listens and its true ``T_base_laser`` (``None``:
        the first scanner); a ConfigError naming the scene's scanners when it has no such one."""
        if name is None:
            return self.scanner_url, self.ground_truth
        scanners = self.info.get("scanners", {})
        if name not in scanners:
            raise ConfigError(
                f"the dry run's scene has no scanner {name!r} (its scanners: {', '.join(scanners)}); "
                "give a scene with a [scanners.NAME] table for every scanner of the job"
            )
        entry = scanners[name]
        return str(entry["scanner_url"]), np.asarray(entry["T_base_laser"], dtype=float).reshape(4, 4)

    def start(self) -> FakeCellProcess:
        """Launch the child and wait for its ready line."""
        logger.info("starting fake cell: %s", " ".join(self.args))
        environment = {name: "1" for name in BLAS_THREAD_VARIABLES} | dict(os.environ)
        self.process = subprocess.Popen(
            self.args, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._stderr, text=True,
            start_new_session=True, env=environment,
        )
        try:
            return self._await_ready()
        except KeyboardInterrupt:
            self.stop()
            raise InterruptedRunError(
                "interrupted while the fake cell was starting; nothing was connected or moved"
            ) from None

    def _await_ready(self) -> FakeCellProcess:
        """Wait for the child's ready line (its document goes to ``info``)."""
        assert self.process is not None and self.process.stdout is not None
        deadline = time.monotonic() + self.startup_timeout_s
        with selectors.DefaultSelector() as selector:
            selector.register(self.process.stdout, selectors.EVENT_READ)
            while (remaining_s := deadline - time.monotonic()) > 0:
                if not selector.select(timeout=remaining_s):
                    continue
                line = self.process.stdout.readline()
                if line.startswith(READY_PREFIX):
                    self.info = parse_ready_line(line)
                    threading.Thread(
                        target=self._watch, args=(self.process,), name="fake-cell-watch", daemon=True
                    ).start()
                    return self
                if not line:
                    error = self._stderr_tail()
                    self.stop()
                    raise TransportError(f"the fake cell on {self.address} exited before ready: {error}")
        self.stop()
        raise DeviceTimeoutError(
            f"the fake cell on {self.address} printed no ready line within {self.startup_timeout_s:g} s"
        )

    def _watch(self, process: subprocess.Popen[str]) -> None:
        """Wait for the child; if it exits before ``stop`` asked it to, say so."""
        code = process.wait()
        if self._closing.is_set():
            return
        how = f"was killed by signal {-code}" if code < 0 else f"exited with code {code}"
        tail = self._stderr_tail().splitlines()[-1:] if not self._stderr.closed else []
        self.death = (f"the fake cell (pid {process.pid}) {how} {self._serving}"
                      + (f": {tail[0]}" if tail else ""))
        logger.error("%s", self.death)
        if self._on_death is not None:
            self._on_death(self.death)

    def _stderr_tail(self) -> str:
        self._stderr.flush()
        self._stderr.seek(0)
        return self._stderr.read().strip()[-800:]

    def stop(self) -> None:
        """Stop the child (close its lifeline and terminate it, then kill) and reap it; safe
        to call twice."""
        self._closing.set()
        process, self.process = self.process, None
        if process is not None:
            if process.stdin is not None:
                process.stdin.close()
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
            self.stop()
            raise

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()
