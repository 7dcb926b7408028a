"""SCIP fuzz harness: mutated conversations between the real driver and the fake device.

One conversation is what ``lasercal scanner capture --scans 1`` says on the wire: QT
(drain), VV, PP, II, BM, GD. The peer is the fake UTM-30LX-EW's state machine
(``fakes.scip_device``) behind an in-memory transport, so thousands run in seconds. A
seeded plan damages one to three of its replies (the first transmission only: a query
asked again gets a clean answer, as on a real link) with byte flips, substitutions,
insertions, deletions, truncation, duplicated, dropped or swapped lines and garbage.

Each conversation ends as one of:

* ``clean_error``: a LasercalError (one-line message) was raised;
* ``recovered``: the driver returned exactly what the undamaged conversation gives;
* ``wrong_detectable``: it returned other data although a damaged line failed its
  checksum (must never happen);
* ``wrong_undetectable``: it returned other data and every damaged line still passed its
  checksum (the 6-bit sum cannot see it, e.g. a byte changed by 64);
* ``crash``: any other exception;
* ``hang``: no end within ``HANG_S``.
"""

from __future__ import annotations

import random
import threading
import time
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.hokuyo.client import HokuyoScanner
from drivers.hokuyo.codec import CommandFramer, checksum, parse_parameter_lines, verify_line
from fakes.scan_scene import RoomScene
from fakes.scip_device import ScipDevice
from fakes.scip_faults import DEFAULT_GARBAGE
from lasercal_hw.errors import DeviceTimeoutError, LasercalError, ProtocolError, TransportError

URL = "scip+tcp://127.0.0.1:10940"
REPLIES = 6
"""Replies in an undamaged conversation (QT, VV, PP, II, BM, GD)."""
HANG_S = 5.0
TIMEOUT_S = 0.02
QUIET_S = 0.002
DEVICE_TIME_S = 10.0
OUTCOMES = ("clean_error", "recovered", "wrong_detectable", "wrong_undetectable", "crash", "hang")


class FuzzTransport:
    """An in-memory link to a ``ScipDevice``: requests in, (damaged) replies out."""

    def __init__(self, damage: dict[int, list[tuple[str, int]]], rng: random.Random) -> None:
        self.url = URL
        self.device = ScipDevice(RoomScene())
        self.damage = damage
        self.rng = rng
        self.damaged: list[tuple[bytes, bytes]] = []
        """(sent as the device made it, sent as damaged) for every damaged reply."""
        self._framer = CommandFramer()
        self._replies = 0
        self._buffer = bytearray()
        self._ready = threading.Condition()
        self._closed = False

    def write(self, data: bytes) -> None:
        if self._closed:
            raise TransportError(f"{self.url}: connection is closed")
        for line in self._framer.feed(data):
            reply = self.device.handle(line, DEVICE_TIME_S).data
            operations = self.damage.get(self._replies, [])
            self._replies += 1
            if operations:
                damaged = reply
                for name, seed in operations:
                    damaged = MUTATIONS[name](damaged, random.Random(seed))
                self.damaged.append((reply, damaged))
                reply = damaged
            with self._ready:
                self._buffer += reply
                self._ready.notify_all()

    def read_some(self, timeout_s: float) -> bytes:
        with self._ready:
            if not self._buffer and not self._closed:
                self._ready.wait(timeout_s)
            if self._closed:
                raise TransportError(f"{self.url}: connection is closed")
            if not self._buffer:
                raise DeviceTimeoutError(f"{self.url}: no data within {timeout_s:g} s")
            size = self.rng.randint(1, len(self._buffer))  # arbitrary chunking, as TCP may
            data = bytes(self._buffer[:size])
            del self._buffer[:size]
            return data

    def close(self) -> None:
        with self._ready:
            self._closed = True
            self._ready.notify_all()


# --------------------------------------------------------------------------- mutations


def _position(data: bytes, rng: random.Random) -> int:
    return rng.randrange(max(len(data), 1))


def _flip_bit(data: bytes, rng: random.Random) -> bytes:
    i = _position(data, rng)
    return data[:i] + bytes((data[i] ^ (1 << rng.randrange(8)),)) + data[i + 1 :] if data else data


def _substitute(data: bytes, rng: random.Random) -> bytes:
    i = _position(data, rng)
    return data[:i] + bytes((rng.randrange(0x30, 0x70),)) + data[i + 1 :] if data else data


def _random_byte(data: bytes, rng: random.Random) -> bytes:
    i = _position(data, rng)
    return data[:i] + bytes((rng.randrange(256),)) + data[i + 1 :] if data else data


def _delete_byte(data: bytes, rng: random.Random) -> bytes:
    i = _position(data, rng)
    return data[:i] + data[i + 1 :]


def _insert_byte(data: bytes, rng: random.Random) -> bytes:
    i = rng.randrange(len(data) + 1)
    return data[:i] + bytes((rng.randrange(256),)) + data[i:]


def _truncate(data: bytes, rng: random.Random) -> bytes:
    return data[: _position(data, rng)]


def _lines(operation: str):  # type: ignore[no-untyped-def]
    def mutate(data: bytes, rng: random.Random) -> bytes:
        lines = data.split(b"\n")
        if len(lines) < 3:
            return data
        i = rng.randrange(len(lines) - 1)
        if operation == "duplicate":
            lines.insert(i, lines[i])
        elif operation == "drop":
            del lines[i]
        else:
            j = min(i + 1, len(lines) - 2)
            lines[i], lines[j] = lines[j], lines[i]
        return b"\n".join(lines)

    return mutate


def _garbage(data: bytes, rng: random.Random) -> bytes:
    i = rng.randrange(len(data) + 1)
    return data[:i] + DEFAULT_GARBAGE + data[i:]


MUTATIONS = {
    "flip_bit": _flip_bit,
    "substitute": _substitute,
    "random_byte": _random_byte,
    "delete_byte": _delete_byte,
    "insert_byte": _insert_byte,
    "truncate": _truncate,
    "duplicate_line": _lines("duplicate"),
    "drop_line": _lines("drop"),
    "swap_lines": _lines("swap"),
    "garbage": _garbage,
}


# --------------------------------------------------------------------------- checksums


def _line_fails(line: bytes, index: int, command: bytes) -> bool:
    """True when a reply line (after the echo) fails the check its kind carries."""
    if not line:
        return False
    if index == 1:
        return len(line) != 3 or checksum(line[:2]) != line[2:]
    try:
        if command in (b"VV", b"PP", b"II"):
            parse_parameter_lines([line], command.decode())
        else:
            verify_line(line)
    except ProtocolError:
        return True
    return False


def checksum_detects(original: bytes, damaged: bytes) -> bool:
    """True when some line of ``damaged`` fails its checksum (the damage was detectable)."""
    command = original[:2]
    return any(_line_fails(line, i, command) for i, line in enumerate(damaged.split(b"\n")) if i >= 1)


# --------------------------------------------------------------------------- runs


@dataclass(frozen=True)
class Outcome:
    """What one conversation gave."""

    kind: str
    detail: str


def converse(transport: FuzzTransport) -> dict[str, Any]:
    """The conversation: open, II, one scan; what the driver returned."""
    with HokuyoScanner.open(URL, transport=transport, timeout_s=TIMEOUT_S, quiet_s=QUIET_S, sync_clock=False,
                            reconnect=False) as scanner:
        status = scanner.status()
        scan = scanner.single_scan()
        return {
            "identity": scanner.identity(),
            "parameters": scanner.parameters(),
            "status": (status.model, status.diagnostic, status.laser_on),
            "ranges": scan.raw_ranges_mm.tolist(),
        }


REFERENCE = converse(FuzzTransport({}, random.Random(0)))


def run_one(seed: int) -> Outcome:
    """One seeded damaged conversation, classified (see the module docstring)."""
    rng = random.Random(seed)
    damage: dict[int, list[tuple[str, int]]] = {}
    for _ in range(rng.randint(1, 3)):
        operation = (rng.choice(list(MUTATIONS)), rng.getrandbits(32))
        damage.setdefault(rng.randrange(REPLIES), []).append(operation)
    transport = FuzzTransport(damage, rng)
    box: list[Outcome] = []

    def work() -> None:
        try:
            returned = converse(transport)
        except LasercalError as exc:
            box.append(Outcome("clean_error", str(exc)))
            return
        except Exception as exc:  # the harness counts what the driver must never raise
            box.append(Outcome("crash", f"{type(exc).__name__}: {exc}"))
            return
        if _same(returned, REFERENCE):
            box.append(Outcome("recovered", ""))
        elif all(checksum_detects(original, damaged) for original, damaged in transport.damaged):
            box.append(Outcome("wrong_detectable", f"seed {seed}: {damage}"))
        else:
            box.append(Outcome("wrong_undetectable", f"seed {seed}: {damage}"))

    thread = threading.Thread(target=work, name=f"fuzz-{seed}", daemon=True)
    thread.start()
    thread.join(HANG_S)
    if thread.is_alive():
        transport.close()
        return Outcome("hang", f"seed {seed}: {damage}")
    return box[0]


def _same(returned: dict[str, Any], reference: dict[str, Any]) -> bool:
    return all(
        np.array_equal(returned[key], reference[key]) if key == "ranges" else returned[key] == reference[key]
        for key in reference
    )


def run_many(count: int, first_seed: int = 0) -> tuple[Counter[str], dict[str, list[str]], float]:
    """``count`` conversations from ``first_seed``: outcome counts, details of the bad
    ones (wrong data, crashes, hangs) and the seconds taken."""
    started = time.perf_counter()
    counts: Counter[str] = Counter({kind: 0 for kind in OUTCOMES})
    details: dict[str, list[str]] = {}
    for seed in range(first_seed, first_seed + count):
        outcome = run_one(seed)
        counts[outcome.kind] += 1
        if outcome.kind not in ("clean_error", "recovered"):
            details.setdefault(outcome.kind, []).append(outcome.detail)
    return counts, details, time.perf_counter() - started
