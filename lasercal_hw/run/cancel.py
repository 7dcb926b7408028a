"""A cancel token: another thread (a service request, a device watchdog) asks a running
calibration to stop; the run stops the arm exactly as Ctrl-C does and keeps its recording."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

from lasercal_hw.errors import InterruptedRunError, LasercalError

logger = logging.getLogger(__name__)


class CancelToken:
    """Thread-safe, one-way: once cancelled it stays cancelled."""

    def __init__(self) -> None:
        self._event = threading.Event()
        self._lock = threading.Lock()
        self._reason: str | None = None
        self._error: LasercalError | None = None
        self._listeners: list[Callable[[], None]] = []

    @property
    def cancelled(self) -> bool:
        """True once ``cancel`` was called."""
        return self._event.is_set()

    @property
    def reason(self) -> str | None:
        """What ``cancel`` was given, or None."""
        return self._reason

    def cancel(self, reason: str = "cancelled") -> None:
        """Ask the run to stop; listeners (e.g. stopping the arm mid-move) run in this thread.
        The run ends with InterruptedRunError (exit code 130)."""
        self.fail(InterruptedRunError(reason))

    def fail(self, error: LasercalError) -> None:
        """Stop the run as ``cancel`` does, but end it with ``error`` (e.g. the DeviceError of a
        device that died under it)."""
        with self._lock:
            if self._event.is_set():
                return
            self._reason = str(error)
            self._error = error
            self._event.set()
            listeners = list(self._listeners)
        for listener in listeners:
            try:
                listener()
            except Exception:  # a listener must not keep the others from running
                logger.exception("cancel listener failed")

    def on_cancel(self, listener: Callable[[], None]) -> Callable[[], None]:
        """Call ``listener`` on cancel (at once if already cancelled); returns its remover."""
        with self._lock:
            already = self._event.is_set()
            if not already:
                self._listeners.append(listener)
        if already:
            listener()

        def remove() -> None:
            with self._lock:
                if listener in self._listeners:
                    self._listeners.remove(listener)

        return remove

    def raise_if_cancelled(self) -> None:
        """Raise the cancel's error (InterruptedRunError unless ``fail`` gave another) when
        cancelled; the run's checkpoints call this."""
        if self._error is not None:
            raise self._error
