"""A job's cancel signal: set from the HTTP side, read or listened to by the run."""

from __future__ import annotations

import threading
from collections.abc import Callable


class CancelSignal:
    """Thread-safe; ``listen`` lets a runner forward the signal to the engine's own token."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._reason: str | None = None
        self._listeners: list[Callable[[str], None]] = []

    def cancel(self, reason: str) -> None:
        """Ask the run to stop (the first reason wins)."""
        with self._lock:
            if self._reason is not None:
                return
            self._reason = reason
            listeners = list(self._listeners)
        for listener in listeners:
            listener(reason)

    def listen(self, listener: Callable[[str], None]) -> None:
        """Call ``listener(reason)`` on cancel (at once when already cancelled)."""
        with self._lock:
            self._listeners.append(listener)
            reason = self._reason
        if reason is not None:
            listener(reason)

    @property
    def cancelled(self) -> bool:
        """True once cancelled."""
        return self._reason is not None

    @property
    def reason(self) -> str | None:
        """Why, once cancelled."""
        return self._reason
