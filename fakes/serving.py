"""Serve a fake in the foreground until SIGINT or SIGTERM, or until its parent dies
(``lasercal fake robot|cell``)."""

from __future__ import annotations

import signal
import sys
import threading
from typing import BinaryIO, Protocol


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


def serve_until_signal(fake: ForegroundFake, lifeline: BinaryIO | None = None) -> None:
    """Start ``fake``, print its ready line, and serve until SIGINT or SIGTERM, or until
    ``lifeline`` (a pipe from the parent) reaches end of file: the kernel closes a pipe
    when its writer dies, even by SIGKILL, so a parent's fake never outlives it. Always
    closes the fake."""
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    if lifeline is not None:
        threading.Thread(target=_watch, args=(lifeline, stop), name="lifeline", daemon=True).start()
    try:
        fake.start()
        print(fake.ready_line(), flush=True)
        while not stop.wait(0.5):
            pass
    finally:
        fake.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _watch(lifeline: BinaryIO, stop: threading.Event) -> None:
    """Read ``lifeline`` until end of file (or an error), then ask the fake to stop."""
    try:
        while lifeline.read(4096):
            pass
    except OSError:
        pass
    if not stop.is_set():
        print("lasercal fake: the parent is gone (lifeline closed); stopping", file=sys.stderr, flush=True)
    stop.set()
