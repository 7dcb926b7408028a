"""Serve a fake in the foreground until SIGINT or SIGTERM (``lasercal fake robot|cell``)."""

from __future__ import annotations

import signal
import threading
from typing import Protocol


class ForegroundFake(Protocol):
    """A fake that can start, announce itself on one line, and close."""

    def start(self) -> None:
        """Bind and start serving."""
        ...

    def ready_line(self) -> str:
        """The single line printed once it serves."""
        ...

    def close(self) -> None:
        """Stop serving; safe to call twice."""
        ...


def serve_until_signal(fake: ForegroundFake) -> None:
    """Start ``fake``, print its ready line, and serve until SIGINT or SIGTERM; always close."""
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        fake.start()
        print(fake.ready_line(), flush=True)
        while not stop.wait(0.5):
            pass
    finally:
        fake.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
