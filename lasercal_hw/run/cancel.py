"""A cancel token: another thread (a service request, a signal handler) asks a running
calibration to stop; the run stops the arm exactly as Ctrl-C does and keeps its recording."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

from lasercal_hw.errors import InterruptedRunError

logger = logging.getLogger(__name__)


class CancelToken:
    """Thread-safe, one-way: once cancelled it stays cancelled."""

    def __init__(self) -> None:
        self._event = threading.Event()
        self._lock = threading.Lock()
        self._reason: str | None = None
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
        """Ask the run to stop; listeners (e.g. stopping the arm mid-move) run in this thread."""
        with self._lock:
            if self._event.is_set():
                return
            self._reason = reason
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
        """Raise InterruptedRunError when cancelled (the run's checkpoints call this)."""
        if self._event.is_set():
            raise InterruptedRunError(self._reason or "cancelled")
