"""Fault injection for the fake scanner: what goes wrong on the wire, and when.

``ScipFaults`` is plain settings (all off by default); ``FaultInjector`` applies them
to the outgoing message stream of one connection. Faults change bytes on the wire only;
the state machine (``fakes.scip_device``) never knows.
"""

from __future__ import annotations

from dataclasses import dataclass

from drivers.hokuyo.codec import CHAR_OFFSET

DEFAULT_GARBAGE = b"\x00\xfe#%garbage%\x7f\n"
"""Line noise: bytes no SCIP message contains, ended by one LF so that the next message
still starts on a line of its own (a robust reader resynchronises on it)."""


@dataclass(frozen=True)
class ScipFaults:
    """Which faults to inject (0 = off).

    * ``corrupt_every_scans``: in every N-th scan message of a connection, the checksum
      char of the first data line is replaced by a wrong one.
    * ``garbage_every_messages``: before every N-th message (scan or reply) the bytes
      ``garbage`` are sent.
    * ``drop_after_scans``: after the N-th scan message of a connection the link is
      dropped (TCP: closed; pseudo-terminal: hung up and not reopened).
    * ``reply_delay_ms``: every reply to a command is held back this long (scan messages
      keep their rhythm; order is kept).
    * ``stale_field``: ``"KEY=VALUE"``; the VV/PP/II line of KEY carries VALUE but keeps
      the checksum of the true value (one changed digit on a link without its own check),
      in the first ``stale_replies`` such replies of a connection (0 = all of them).
    """

    corrupt_every_scans: int = 0
    garbage_every_messages: int = 0
    drop_after_scans: int = 0
    reply_delay_ms: float = 0.0
    garbage: bytes = DEFAULT_GARBAGE
    stale_field: str = ""
    stale_replies: int = 0

    def __post_init__(self) -> None:
        for name in ("corrupt_every_scans", "garbage_every_messages", "drop_after_scans", "stale_replies"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0 (0 = off)")
        if self.reply_delay_ms < 0:
            raise ValueError("reply_delay_ms must be >= 0")
        if not self.garbage or b"\n\n" in self.garbage:
            raise ValueError("garbage must be non-empty and must not contain LF LF")
        key, sep, value = self.stale_field.partition("=")
        if self.stale_field and not (sep and key and value.isprintable() and "\n" not in value):
            raise ValueError(f"stale_field must be KEY=VALUE, got {self.stale_field!r}")

    @property
    def reply_delay_s(self) -> float:
        """``reply_delay_ms`` in seconds."""
        return self.reply_delay_ms / 1000.0


def corrupt_first_data_line(message: bytes) -> bytes:
    """Return a scan message whose first data line (after echo, status, timestamp) has
    a wrong checksum char; other lines are untouched."""
    lines = message.split(b"\n")
    if len(lines) < 4 or len(lines[3]) < 2:
        raise ValueError("not a scan message with data lines")
    line = lines[3]
    wrong = ((line[-1] - CHAR_OFFSET + 1) & 0x3F) + CHAR_OFFSET
    lines[3] = line[:-1] + bytes((wrong,))
    return b"\n".join(lines)


def with_stale_field(message: bytes, key: str, value: str) -> bytes | None:
    """``message`` with the value of its ``key:`` line replaced by ``value`` and the old
    checksum char kept; None when the message has no such line."""
    lines = message.split(b"\n")
    prefix = key.encode("ascii") + b":"
    for index, line in enumerate(lines[2:], start=2):
        if line.startswith(prefix) and line[-2:-1] == b";":
            lines[index] = prefix + value.encode("ascii") + line[-2:]
            return b"\n".join(lines)
    return None


class FaultInjector:
    """Applies ``ScipFaults`` to one connection's outgoing messages (counts restart on
    every new connection)."""

    def __init__(self, faults: ScipFaults) -> None:
        self.faults = faults
        self.messages_sent = 0
        self.scans_sent = 0
        self.stale_sent = 0

    def outgoing(self, message: bytes, *, is_scan: bool) -> bytes:
        """The bytes to put on the wire for ``message``."""
        faults = self.faults
        self.messages_sent += 1
        if is_scan:
            self.scans_sent += 1
            if faults.corrupt_every_scans and self.scans_sent % faults.corrupt_every_scans == 0:
                message = corrupt_first_data_line(message)
        elif faults.stale_field and (not faults.stale_replies or self.stale_sent < faults.stale_replies):
            key, _, value = faults.stale_field.partition("=")
            stale = with_stale_field(message, key, value)
            if stale is not None:
                message = stale
                self.stale_sent += 1
        if faults.garbage_every_messages and self.messages_sent % faults.garbage_every_messages == 0:
            message = faults.garbage + message
        return message

    @property
    def should_drop(self) -> bool:
        """True once ``drop_after_scans`` scan messages have been sent."""
        limit = self.faults.drop_after_scans
        return bool(limit) and self.scans_sent >= limit
