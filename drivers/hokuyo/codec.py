"""SCIP 2.0 wire codec: checksums, character encodings, data blocks, message framing.

Pure functions and small state machines, no I/O. Both the host driver
(``drivers.hokuyo.client``) and the fake scanner (``fakes.scip_server``) build on it, so
what one writes the other reads byte for byte. Reference:
``/work/shared/protocols/scip2.md`` (sections 2, 3, 4, 5, 10).
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from lasercal_hw.errors import ChecksumError, ProtocolError

logger = logging.getLogger(__name__)

LF = b"\n"
CHAR_OFFSET = 0x30
"""Every encoded character is ``value + 0x30`` (range ``'0'`` .. ``'o'``)."""
BITS_PER_CHAR = 6
DATA_LINE_CHARS = 64
"""Payload characters per scan data line (the checksum char comes on top)."""
TIMESTAMP_MODULUS = 1 << 24
"""The sensor clock is a 24-bit millisecond counter."""
MAX_TAG_CHARS = 16
MAX_ECHO_CHARS = 64
_TAG_PATTERN = re.compile(rb"[A-Za-z0-9 ._+@]*")
_STATUS_PATTERN = re.compile(rb"[0-9A-Z]{2}")

# --------------------------------------------------------------------------- status codes

STATUS_MEANINGS: dict[str, str] = {
    "00": "OK",
    "99": "scan data",
    "0A": "unable to create transmission data or reply internally",
    "0B": "buffer shortage, or command repeated that is already being processed",
    "0C": "command with insufficient parameters (command too short)",
    "0D": "undefined command (command too long)",
    "0E": "undefined command",
    "0F": "command with insufficient parameters / not supported",
    "0G": "string field longer than 16 characters",
    "0H": "string field contains invalid characters",
    "0I": "sensor in firmware-update mode",
    "0L": "sensor in abnormal state",
    "0M": "sensor unstable",
    "10": "command denied in the current state",
}
"""Common status codes (scip2.md 5.1); per-command meanings are in ``COMMAND_STATUS_MEANINGS``."""

_SCAN_STATUS = {
    "01": "start step non-numeric",
    "02": "end step non-numeric",
    "03": "cluster count non-numeric",
    "04": "end step out of range",
    "05": "end step smaller than start step",
}
_STREAM_STATUS = {
    **_SCAN_STATUS,
    "06": "scan interval non-numeric",
    "07": "number of scans non-numeric",
}
_SINGLE_STATUS = {**_SCAN_STATUS, "10": "laser is off (send BM first)"}
#: A model without intensities answers ME and GE as undefined commands.
_NO_INTENSITIES = {
    "0E": "undefined command: this scanner model sends no intensities; stream ranges alone "
    "(MD: the job's [scanner] intensities = false)"
}

COMMAND_STATUS_MEANINGS: dict[str, dict[str, str]] = {
    "BM": {"01": "unable to control due to laser malfunction", "02": "laser is already on"},
    "TM": {
        "01": "invalid control code",
        "02": "TM0 while already in time-adjust mode",
        "03": "TM2 while not in time-adjust mode",
        "04": "TM1 while not in time-adjust mode",
    },
    "SS": {
        "01": "non-numeric bit rate",
        "02": "invalid bit rate",
        "03": "already at that bit rate",
        "04": "not compatible with this sensor model",
    },
    "CR": {
        "01": "invalid motor speed",
        "02": "motor speed out of range",
        "03": "already at that motor speed",
        "04": "not compatible with this sensor model",
    },
    "HS": {
        "01": "parameter error",
        "02": "already in that sensitivity mode",
        "03": "not compatible with this sensor model",
    },
    "QT": {"0E": "sensor is in time-adjust mode (send TM2 first)"},
    "GD": _SINGLE_STATUS,
    "GS": _SINGLE_STATUS,
    "GE": {**_SINGLE_STATUS, **_NO_INTENSITIES},
    "MD": _STREAM_STATUS,
    "MS": _STREAM_STATUS,
    "ME": {**_STREAM_STATUS, **_NO_INTENSITIES},
}
"""Command-specific status meanings (scip2.md 4.4-4.12)."""


def status_meaning(command: str, status: str) -> str:
    """Human meaning of ``status`` as an answer to ``command`` (e.g. ``"GD"``, ``"10"``)."""
    specific = COMMAND_STATUS_MEANINGS.get(command[:2], {})
    if status in specific:
        return specific[status]
    if status in STATUS_MEANINGS:
        return STATUS_MEANINGS[status]
    if status.isdigit():
        number = int(status)
        if 21 <= number <= 49:
            return "processing stopped to verify an error"
        if 50 <= number <= 97:
            return "hardware trouble (laser, motor or sensor)"
        if number == 98:
            return "resumption after confirming normal laser operation"
    return "unknown status code"


# --------------------------------------------------------------------------- checksums


def checksum(data: bytes) -> bytes:
    """SCIP checksum char of ``data``: ``((sum of bytes) & 0x3F) + 0x30`` as one byte."""
    return bytes(((sum(data) & 0x3F) + CHAR_OFFSET,))


def verify_line(line: bytes, what: str = "line") -> bytes:
    """Check a line that ends in its checksum char; return the payload without it."""
    if len(line) < 2:
        raise ProtocolError(f"{what} {line!r} is too short to carry a checksum")
    payload, received = line[:-1], line[-1:]
    expected = checksum(payload)
    if received != expected:
        raise ChecksumError(f"{what} {line!r}: checksum {received!r}, expected {expected!r}")
    return payload


# --------------------------------------------------------------------------- N-char encoding


def encode_int(value: int, width: int) -> bytes:
    """Encode a non-negative integer as ``width`` SCIP characters (6 bits each, MSB first)."""
    if not 0 <= value < (1 << (BITS_PER_CHAR * width)):
        raise ValueError(f"{value} does not fit in {width} SCIP characters")
    return bytes(
        ((value >> (BITS_PER_CHAR * (width - 1 - i))) & 0x3F) + CHAR_OFFSET for i in range(width)
    )


def decode_int(chars: bytes) -> int:
    """Decode SCIP characters (any width) into an integer."""
    if not chars:
        raise ProtocolError("cannot decode an empty SCIP value")
    value = 0
    for position, code in enumerate(chars):
        if not CHAR_OFFSET <= code <= CHAR_OFFSET + 0x3F:
            raise ProtocolError(
                f"byte {bytes((code,))!r} at position {position} is not a SCIP encoded character"
            )
        value = (value << BITS_PER_CHAR) | (code - CHAR_OFFSET)
    return value


def encode_values(values: ArrayLike, width: int) -> bytes:
    """Encode an array of non-negative integers, ``width`` chars each, concatenated."""
    array = np.asarray(values, dtype=np.int64).ravel()
    if array.size and (array.min() < 0 or array.max() >= (1 << (BITS_PER_CHAR * width))):
        raise ValueError(f"values must lie in 0..{(1 << (BITS_PER_CHAR * width)) - 1} for width {width}")
    shifts = BITS_PER_CHAR * np.arange(width - 1, -1, -1, dtype=np.int64)
    digits = ((array[:, None] >> shifts) & 0x3F) + CHAR_OFFSET
    return digits.astype(np.uint8).tobytes()


def _place_values(width: int) -> NDArray[np.float32]:
    return (2.0 ** (BITS_PER_CHAR * np.arange(width - 1, -1, -1))).astype(np.float32)


_PLACE_VALUES = {width: _place_values(width) for width in (1, 2, 3, 4)}
"""Weights of each char; values of up to 4 chars (< 2**24) are exact in float32, so the
decode is one BLAS matrix-vector product."""


def decode_values(chars: bytes, width: int) -> NDArray[np.int64]:
    """Decode concatenated ``width``-char SCIP values into an int64 array (vectorised)."""
    if len(chars) % width:
        raise ProtocolError(f"{len(chars)} characters are not a whole number of {width}-char values")
    digits = np.frombuffer(chars, dtype=np.uint8) - np.uint8(CHAR_OFFSET)  # bytes < 0x30 wrap to > 0x3F
    if digits.size and digits.max() > 0x3F:
        position = int(np.argmax(digits > 0x3F))
        raise ProtocolError(
            f"byte {chars[position:position + 1]!r} at position {position} is not a SCIP encoded character"
        )
    groups = digits.reshape(-1, width)
    if width in _PLACE_VALUES:
        return (groups.astype(np.float32) @ _PLACE_VALUES[width]).astype(np.int64)
    values = np.zeros(groups.shape[0], dtype=np.int64)
    for column in range(width):
        values = (values << BITS_PER_CHAR) | groups[:, column]
    return values


# --------------------------------------------------------------------------- data lines


def encode_data_lines(payload: bytes) -> list[bytes]:
    """Cut a scan payload into 64-char lines, each followed by its checksum char (no LF)."""
    return [
        chunk + checksum(chunk)
        for chunk in (payload[i : i + DATA_LINE_CHARS] for i in range(0, len(payload), DATA_LINE_CHARS))
    ]


class DataLineChecksumError(ChecksumError):
    """One or more scan data lines failed their checksum; ``bad_lines`` are 0-based indices."""

    def __init__(self, bad_lines: Sequence[int], line_count: int) -> None:
        shown = ", ".join(str(i + 1) for i in bad_lines)
        super().__init__(f"checksum mismatch in data line(s) {shown} of {line_count}")
        self.bad_lines = list(bad_lines)


_LINE_SUM_WEIGHTS = np.append(np.ones(DATA_LINE_CHARS, dtype=np.float32), np.float32(0.0))
"""Sums the 64 payload chars of a full line and skips its checksum char (exact in float32)."""


def decode_data_lines(lines: Sequence[bytes]) -> bytes:
    """Verify each data line's checksum and return the concatenated payload.

    Full 64-char lines (all but the last, scip2.md 3.2) are checked together with one
    matrix-vector product. Raises ``DataLineChecksumError`` naming every bad line (and
    only those)."""
    if not lines:
        return b""
    full_line = DATA_LINE_CHARS + 1
    full = lines[:-1]
    last = lines[-1]
    codes = np.frombuffer(b"".join(full), dtype=np.uint8)
    if codes.size != full_line * len(full):  # irregular lines: check one by one
        bad = [i for i, line in enumerate(lines) if len(line) < 2 or checksum(line[:-1]) != line[-1:]]
        if bad:
            raise DataLineChecksumError(bad, len(lines))
        return b"".join(line[:-1] for line in lines)
    body = codes.reshape(-1, full_line)
    sums = (body.astype(np.float32) @ _LINE_SUM_WEIGHTS).astype(np.int64)
    bad = np.flatnonzero(((sums & 0x3F) + CHAR_OFFSET) != body[:, DATA_LINE_CHARS]).tolist()
    if len(last) < 2 or checksum(last[:-1]) != last[-1:]:
        bad.append(len(lines) - 1)
    if bad:
        raise DataLineChecksumError(bad, len(lines))
    return body[:, :DATA_LINE_CHARS].tobytes() + last[:-1]


def timestamp_line(time_ms: int) -> bytes:
    """The 4-char timestamp line (value modulo 2^24) with its checksum char."""
    chars = encode_int(time_ms % TIMESTAMP_MODULUS, 4)
    return chars + checksum(chars)


def decode_timestamp_line(line: bytes) -> int:
    """Verify and decode a timestamp line (4 chars + checksum) into milliseconds."""
    if len(line) != 5:
        raise ProtocolError(f"timestamp line {line!r} must be 4 characters plus a checksum")
    return decode_int(verify_line(line, "timestamp line"))


# --------------------------------------------------------------------------- parameter lines


def parameter_line(key: str, value: str) -> bytes:
    """``KEY:VALUE;S`` where the checksum covers ``KEY:VALUE`` (not the ``;``)."""
    text = f"{key}:{value}".encode("ascii")
    return text + b";" + checksum(text)


_CHECKSUM_CONVENTIONS = ("without ';'", "with ';'")


def _parameter_conventions(text: bytes, received: bytes) -> set[str]:
    """The checksum conventions under which ``text`` (``KEY:VALUE``) carries ``received``:
    the sum over the text (scip2.md 2.3, the captures), or over text and ``;`` (some
    firmware); a ``<-`` comment may be left out of either (P-4)."""
    bodies = [text]
    comment = text.find(b"<-")
    if comment > 0:
        bodies.append(text[:comment])
    return {
        convention
        for convention, suffix in zip(_CHECKSUM_CONVENTIONS, (b"", b";"), strict=True)
        if any(checksum(body + suffix) == received for body in bodies)
    }


def parse_parameter_lines(lines: Iterable[bytes], command: str = "parameter") -> dict[str, str]:
    """Parse the VV/PP/II lines of a ``command`` reply into ``{key: value}``.

    Key = text before the first ``:``; checksum = last char; the ``;`` before it is the
    separator; the value may itself contain ``:`` and ``;`` (scip2.md 2.3, P-4). These
    values decide every scan angle, so they are checked like scan data: a line that is
    not printable ASCII, has no key, no ``;`` + checksum, or a checksum that fails raises
    ``ChecksumError`` naming the line. One firmware computes every sum one way, so all
    lines of a reply must agree on the convention (with or without the ``;``): a damaged
    line that happens to match the other one is caught too."""
    result: dict[str, str] = {}
    common = set(_CHECKSUM_CONVENTIONS)
    for raw in lines:
        if not all(0x20 <= byte <= 0x7E for byte in raw):
            raise ChecksumError(f"{command} reply line {_shown(raw)} holds bytes that are not printable")
        colon = raw.find(b":")
        if colon <= 0:
            raise ChecksumError(f"{command} reply line {_shown(raw)} has no key (no ':')")
        if len(raw) < colon + 3 or raw[-2:-1] != b";":
            raise ChecksumError(f"{command} reply line {_shown(raw)} has no ';' + checksum")
        text, received = raw[:-2], raw[-1:]
        conventions = _parameter_conventions(text, received)
        if not conventions & common:
            raise ChecksumError(
                f"{command} reply line {_shown(raw)} fails its checksum "
                f"(received {_shown(received)}, expected {_shown(checksum(text))})"
            )
        common &= conventions
        key = text[:colon].decode("ascii")
        result[key] = text[colon + 1 :].decode("ascii")
    return result


def _shown(data: bytes) -> str:
    """``data`` quoted for a one-line message (non-ASCII bytes escaped)."""
    return repr(data.decode("ascii", errors="backslashreplace"))


def parse_time_field(value: str) -> int:
    """II ``TIME`` value in ms: 6 hex digits (URG/UTM) or 4-char SCIP encoding (UST)."""
    if len(value) == 6:
        try:
            return int(value, 16)
        except ValueError:
            pass
    if len(value) == 4:
        return decode_int(value.encode("ascii"))
    raise ProtocolError(f"II TIME value {value!r} is neither 6 hex digits nor 4 SCIP characters")


# --------------------------------------------------------------------------- requests


def format_request(command: str, parameters: str = "", tag: str | None = None) -> bytes:
    """One request line with LF: ``CMD`` + fixed-width parameters + optional ``;tag``."""
    line = (command + parameters).encode("ascii")
    if tag is not None:
        encoded = tag.encode("ascii")
        if len(encoded) > MAX_TAG_CHARS or not _TAG_PATTERN.fullmatch(encoded):
            raise ValueError(f"tag {tag!r}: at most 16 of A-Z a-z 0-9 space . _ + @")
        line += b";" + encoded
    return line + LF


class RequestParameterError(ProtocolError):
    """A request line is malformed; ``status`` is the SCIP code a sensor answers with."""

    def __init__(self, message: str, status: str) -> None:
        super().__init__(message)
        self.status = status


SINGLE_SCAN_COMMANDS = ("GD", "GS", "GE")
STREAM_COMMANDS = ("MD", "MS", "ME")


@dataclass(frozen=True)
class ScanRequest:
    """Parameters of a GD/GS/GE or MD/MS/ME request (scip2.md 4.11, 4.12).

    ``interval`` and ``count`` are None for single-scan commands; in a scan message echo
    ``count`` is the remaining-scan counter."""

    command: str
    first_step: int
    last_step: int
    cluster: int = 1
    interval: int | None = None
    count: int | None = None
    tag: str | None = None

    @property
    def is_stream(self) -> bool:
        """True for MD/MS/ME."""
        return self.command in STREAM_COMMANDS

    @property
    def chars_per_value(self) -> int:
        """2 for GS/MS, 3 otherwise."""
        return 2 if self.command[1] == "S" else 3

    @property
    def with_intensity(self) -> bool:
        """True for GE/ME (distance and intensity per step)."""
        return self.command[1] == "E"

    @property
    def value_count(self) -> int:
        """Number of output steps: ``ceil((last - first + 1) / cluster)``, cluster 0 = 1."""
        return values_per_scan(self.first_step, self.last_step, self.cluster)

    @property
    def payload_chars(self) -> int:
        """Characters of the concatenated data block of one scan."""
        return self.value_count * self.chars_per_value * (2 if self.with_intensity else 1)

    def prefix(self) -> bytes:
        """Command + start + end + cluster (+ interval): identifies the scan layout."""
        text = f"{self.command}{self.first_step:04d}{self.last_step:04d}{self.cluster:02d}"
        if self.is_stream:
            text += f"{self.interval or 0:d}"
        return text.encode("ascii")

    def line(self, count: int | None = None) -> bytes:
        """The request/echo line without terminator; ``count`` overrides the scan count."""
        text = self.prefix()
        if self.is_stream:
            text += f"{self.count if count is None else count:02d}".encode("ascii")
        if self.tag is not None:
            text += b";" + self.tag.encode("ascii")
        return text


def values_per_scan(first_step: int, last_step: int, cluster: int) -> int:
    """Number of values a scan over ``first_step..last_step`` with ``cluster`` carries."""
    return math.ceil((last_step - first_step + 1) / max(cluster, 1))


def format_scan_request(
    command: str,
    first_step: int,
    last_step: int,
    cluster: int = 1,
    *,
    interval: int = 0,
    count: int = 0,
    tag: str | None = None,
) -> bytes:
    """Request line with LF for GD/GS/GE (12 chars) or MD/MS/ME (15 chars)."""
    if command not in SINGLE_SCAN_COMMANDS + STREAM_COMMANDS:
        raise ValueError(f"{command!r} is not a scan command")
    if not (0 <= first_step <= 9999 and 0 <= last_step <= 9999 and 0 <= cluster <= 99):
        raise ValueError("steps must be 0..9999 and cluster 0..99")
    if command in STREAM_COMMANDS and not (0 <= interval <= 9 and 0 <= count <= 99):
        raise ValueError("interval must be 0..9 and count 0..99")
    parameters = f"{first_step:04d}{last_step:04d}{cluster:02d}"
    if command in STREAM_COMMANDS:
        parameters += f"{interval:d}{count:02d}"
    return format_request(command, parameters, tag)


def parse_scan_request(line: bytes) -> ScanRequest:
    """Parse a GD/GS/GE/MD/MS/ME request or echo line (without terminator).

    Raises ``RequestParameterError`` whose ``status`` is the code a sensor would answer
    (01/02/03/06/07 non-numeric field, 0C too short, 0D too long, 0G/0H bad string)."""
    body, sep, tag_bytes = line.partition(b";")
    command = body[:2].decode("ascii", errors="replace")
    if command not in SINGLE_SCAN_COMMANDS + STREAM_COMMANDS:
        raise RequestParameterError(f"{line!r} is not a scan command", "0E")
    width = 13 if command in STREAM_COMMANDS else 10
    fields = body[2:]
    if len(fields) < width:
        raise RequestParameterError(f"{line!r}: parameters too short", "0C")
    if len(fields) > width:
        raise RequestParameterError(f"{line!r}: parameters too long", "0D")
    tag: str | None = None
    if sep:
        if len(tag_bytes) > MAX_TAG_CHARS:
            raise RequestParameterError(f"{line!r}: string field longer than 16", "0G")
        if not _TAG_PATTERN.fullmatch(tag_bytes):
            raise RequestParameterError(f"{line!r}: string field has invalid characters", "0H")
        tag = tag_bytes.decode("ascii")
    spans = [("start step", 0, 4, "01"), ("end step", 4, 8, "02"), ("cluster count", 8, 10, "03")]
    if command in STREAM_COMMANDS:
        spans += [("scan interval", 10, 11, "06"), ("number of scans", 11, 13, "07")]
    numbers: list[int] = []
    for name, start, end, status in spans:
        text = fields[start:end]
        if not text.isdigit():
            raise RequestParameterError(f"{line!r}: {name} {text!r} is not numeric", status)
        numbers.append(int(text))
    if command in STREAM_COMMANDS:
        first, last, cluster, interval, count = numbers
        return ScanRequest(command, first, last, cluster, interval, count, tag)
    first, last, cluster = numbers
    return ScanRequest(command, first, last, cluster, tag=tag)


# --------------------------------------------------------------------------- responses


def format_response(echo: bytes, status: bytes, data_lines: Sequence[bytes] = ()) -> bytes:
    """A whole reply: echo LF, status + checksum LF, each data line LF, then LF."""
    parts = [echo, LF, status, checksum(status), LF]
    for line in data_lines:
        parts += [line, LF]
    parts.append(LF)
    return b"".join(parts)


@dataclass(frozen=True)
class Response:
    """One sensor message: echo line, 2-char status (checksum verified and stripped) and
    the data lines exactly as received (each still ending in its checksum char)."""

    echo: bytes
    status: bytes
    data_lines: tuple[bytes, ...] = field(default_factory=tuple)

    @property
    def command(self) -> str:
        """Command name from the echo: 2 chars, or 3 for ``%xx``/``$xx`` extensions."""
        size = 3 if self.echo[:1] in (b"%", b"$") else 2
        return self.echo[:size].decode("ascii", errors="replace")

    @property
    def status_text(self) -> str:
        """The status code as text, e.g. ``"00"``."""
        return self.status.decode("ascii")

    def to_bytes(self) -> bytes:
        """The message as it travels on the wire."""
        return format_response(self.echo, self.status, self.data_lines)


def _plausible_echo(line: bytes) -> bool:
    """A request line as a sensor echoes it: starts with a command letter (or ``%``/``$``),
    printable ASCII, at most 64 chars (a full data line is 65, so never mistaken)."""
    return (
        0 < len(line) <= MAX_ECHO_CHARS
        and (0x41 <= line[0] <= 0x5A or line[0] in b"%$")
        and all(0x20 <= b <= 0x7E for b in line)
    )


def _valid_status_line(line: bytes) -> bool:
    return len(line) == 3 and bool(_STATUS_PATTERN.fullmatch(line[:2])) and checksum(line[:2]) == line[2:]


class ResponseFramer:
    """Incremental sensor→host framer: bytes in, complete ``Response`` objects out.

    Buffers input and cuts at the first LF LF (scip2.md 2.4). A chunk whose first two
    lines are not a plausible echo + valid status line is resynchronised: lines are
    discarded until a valid echo + status pair; chunks without one are dropped whole.
    Discarded input is counted in ``discarded_bytes``; ``discarded_chunks`` counts the
    LF-LF-terminated chunks dropped whole (no message in them). The buffer is bounded by
    ``max_buffer_bytes`` so a stream without terminators cannot grow memory."""

    def __init__(self, max_buffer_bytes: int = 1 << 20) -> None:
        self.max_buffer_bytes = max_buffer_bytes
        self.discarded_bytes = 0
        self.discarded_chunks = 0
        self._buffer = bytearray()
        self._searched = 0

    def reset(self) -> None:
        """Forget buffered bytes (after a reconnect)."""
        self._buffer.clear()
        self._searched = 0

    @property
    def pending_bytes(self) -> int:
        """Bytes received but not yet part of a complete message."""
        return len(self._buffer)

    def feed(self, data: bytes) -> list[Response]:
        """Add received bytes; return every message completed by them, in order."""
        self._buffer += data
        responses: list[Response] = []
        while True:
            end = self._buffer.find(b"\n\n", self._searched)
            if end < 0:
                self._searched = max(len(self._buffer) - 1, 0)
                break
            chunk = bytes(self._buffer[:end])
            del self._buffer[: end + 2]
            self._searched = 0
            response = self._parse_chunk(chunk)
            if response is not None:
                responses.append(response)
        if len(self._buffer) > self.max_buffer_bytes:
            keep_from = self._buffer.rfind(b"\n") + 1
            self._discard(keep_from or len(self._buffer), "buffer limit exceeded without a terminator")
            del self._buffer[: keep_from or len(self._buffer)]
            self._searched = 0
        return responses

    def _parse_chunk(self, chunk: bytes) -> Response | None:
        lines = chunk.split(b"\n")
        pairs = [
            i
            for i in range(len(lines) - 1)
            if _plausible_echo(lines[i]) and _valid_status_line(lines[i + 1])
        ]
        if not pairs:
            self._discard(len(chunk) + 2, "no valid echo + status pair")
            return None
        # A later pair means the earlier message was cut short (its LF LF never came);
        # keep the last complete one. Position first+2 is a timestamp line followed by a
        # 3-char data line (GS/MS with one value), which is not a message start.
        later = [i for i in pairs if i > pairs[0] + 2]
        start = later[-1] if later else pairs[0]
        if start:
            self._discard(sum(len(line) + 1 for line in lines[:start]), "resynchronised", whole=False)
        return Response(lines[start], lines[start + 1][:2], tuple(lines[start + 2 :]))

    def _discard(self, byte_count: int, reason: str, *, whole: bool = True) -> None:
        self.discarded_bytes += byte_count
        if whole:
            self.discarded_chunks += 1
        logger.debug("discarded %d bytes: %s", byte_count, reason)


class CommandFramer:
    """Host→sensor framer for a server: bytes in, request lines out (no terminator).

    CR, LF and CRLF each end one line; empty lines are ignored (scip2.md 2.1). Bytes
    beyond ``max_line_bytes`` without a terminator are dropped (a real sensor never
    answers an unterminated line)."""

    def __init__(self, max_line_bytes: int = 4096) -> None:
        self.max_line_bytes = max_line_bytes
        self._buffer = bytearray()

    def feed(self, data: bytes) -> list[bytes]:
        """Add received bytes; return the complete request lines in order."""
        self._buffer += data
        lines: list[bytes] = []
        start = 0
        for index, byte in enumerate(self._buffer):
            if byte in (0x0A, 0x0D):
                if index > start:
                    lines.append(bytes(self._buffer[start:index]))
                start = index + 1
        del self._buffer[:start]
        if len(self._buffer) > self.max_line_bytes:
            logger.debug("dropping %d unterminated bytes", len(self._buffer))
            self._buffer.clear()
        return lines


# --------------------------------------------------------------------------- scan messages


@dataclass(frozen=True)
class DecodedScan:
    """A scan message's contents: sensor timestamp, distances and optional intensities."""

    timestamp_ms: int
    distances_mm: NDArray[np.int64]
    intensities: NDArray[np.int64] | None


def encode_scan_lines(
    timestamp_ms: int,
    distances_mm: ArrayLike,
    intensities: ArrayLike | None = None,
    chars_per_value: int = 3,
) -> list[bytes]:
    """Timestamp line + data lines of one scan message (distance, or distance+intensity)."""
    distances = np.asarray(distances_mm, dtype=np.int64)
    if intensities is not None:
        values = np.column_stack([distances, np.asarray(intensities, dtype=np.int64)]).ravel()
    else:
        values = distances
    return [timestamp_line(timestamp_ms), *encode_data_lines(encode_values(values, chars_per_value))]


def decode_scan_lines(data_lines: Sequence[bytes], request: ScanRequest) -> DecodedScan:
    """Decode the data lines of a GD/GE/MD/ME scan message for ``request``.

    Verifies the timestamp and every data line checksum and that the number of values
    matches the request (P-14)."""
    if not data_lines:
        raise ProtocolError(f"scan message for {request.command} has no timestamp line")
    timestamp_ms = decode_timestamp_line(data_lines[0])
    payload = decode_data_lines(data_lines[1:])
    if len(payload) != request.payload_chars:
        raise ProtocolError(
            f"scan for {request.line().decode()} carries {len(payload)} characters, "
            f"expected {request.payload_chars} ({request.value_count} steps)"
        )
    values = decode_values(payload, request.chars_per_value)
    if request.with_intensity:
        pairs = values.reshape(-1, 2)
        return DecodedScan(timestamp_ms, pairs[:, 0].copy(), pairs[:, 1].copy())
    return DecodedScan(timestamp_ms, values, None)
