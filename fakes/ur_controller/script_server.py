"""Script port (30003): collects URScript programs and hands complete ones to the
controller. Nothing is ever sent back on this port (ur_rtde never reads it)."""

from __future__ import annotations

import codecs
import logging
import re
import socket

from fakes.ur_controller.controller import FakeController

logger = logging.getLogger(__name__)

_PROGRAM = re.compile(r"^def\s+(\w+)\s*\(\s*\)\s*:\s*$(.*?)^end[ \t]*$", re.MULTILINE | re.DOTALL)
_MAX_BUFFER_CHARS = 4_000_000


class ProgramFramer:
    """Text in, complete ``def name(): ... end`` programs (name, whole text) out.

    A program ends at the first ``end`` in column 0 after its ``def`` line; inner blocks
    are indented, as in every program ur_rtde sends.
    """

    def __init__(self) -> None:
        self._text = ""

    def feed(self, text: str) -> list[tuple[str, str]]:
        """Add received text; return the programs it completes."""
        self._text += text
        programs: list[tuple[str, str]] = []
        while True:
            match = _PROGRAM.search(self._text)
            if match is None:
                break
            skipped = self._text[:match.start()].strip()
            if skipped:
                logger.info("script port: ignoring text outside a program: %.60r", skipped)
            programs.append((match.group(1), match.group(0)))
            self._text = self._text[match.end():]
        if len(self._text) > _MAX_BUFFER_CHARS:
            logger.warning("script port: dropping %d characters without a complete program", len(self._text))
            self._text = ""
        return programs


class ScriptServer:
    """Feeds programs from each script-port client to the controller."""

    def __init__(self, controller: FakeController) -> None:
        self.controller = controller

    def serve(self, sock: socket.socket) -> None:
        """Handle one connection (TcpListener handler)."""
        framer = ProgramFramer()
        decoder = codecs.getincrementaldecoder("utf-8")(errors="replace")
        while True:
            chunk = sock.recv(65536)
            if not chunk:
                return
            for name, text in framer.feed(decoder.decode(chunk)):
                logger.info("script port: program %r (%d characters)", name, len(text))
                self.controller.load_program(name, text)
