"""The fake UTM-30LX-EW's SCIP 2.0 state machine, without sockets or threads.

``ScipDevice.handle(line, now_s)`` turns one request line into the reply bytes;
``ScipDevice.complete_scan(scan_start_s)`` returns the stream message (if any) for the
scan that started at ``scan_start_s``. Time is passed in (seconds on any monotonic
clock), so every reply is reproducible in a test. Behaviour follows scip2.md section 8;
the choices for [UNCONFIRMED] points are listed in docs/scip-fake.md.

Framing, checksums and encodings all come from ``drivers.hokuyo.codec``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivers.hokuyo import codec
from fakes.scan_scene import RangeSource
from fakes.scip_identity import UTM_30LX_EW, LinkKind, ScipIdentity, SensorState

logger = logging.getLogger(__name__)

SCAN_PERIOD_S = 0.025
"""UTM-30LX-EW: 2400 rpm, one revolution every 25 ms."""
REBOOT_WINDOW_S = 1.0
"""A second ``RB`` within this time of the first reboots the sensor."""
SERIAL_BIT_RATES = (19200, 38400, 57600, 115200, 250000, 500000, 750000)
INITIAL_SERIAL_BIT_RATE = 115200
TWO_CHAR_MAX_MM = 4095
_EPSILON_S = 1e-6

_PARAMETER_WIDTHS: dict[str, int] = {
    "VV": 0, "PP": 0, "II": 0, "BM": 0, "QT": 0, "RS": 0, "RT": 0, "RB": 0,
    "TM": 1, "SS": 6, "CR": 2, "HS": 1,
}
"""Fixed parameter width of every non-scan command the fake implements."""
_ALLOWED_IN_TIME_ADJUST = ("VV", "II", "TM", "RS", "RT", "QT")
"""Everything else is answered ``10`` (denied) between TM0 and TM2 (QT answers ``0E``)."""


@dataclass(frozen=True)
class DeviceReply:
    """Bytes to send for one request; ``hang_up`` asks the server to drop the link after
    sending them (second ``RB``: the sensor reboots)."""

    data: bytes
    hang_up: bool = False


@dataclass
class _Stream:
    request: codec.ScanRequest
    first_scan_start_s: float
    scans_seen: int = 0
    scans_sent: int = 0


class ScipDevice:
    """One simulated UTM-30LX-EW: laser, motor clock, 24-bit timer and SCIP replies.

    ``origin_s`` is the power-up instant on the caller's clock: scan ``k`` starts at
    ``origin_s + k * scan_period_s`` and the timer reads ``start_time_ms`` then.
    """

    def __init__(
        self,
        source: RangeSource,
        *,
        identity: ScipIdentity = UTM_30LX_EW,
        link: LinkKind = LinkKind.ETHERNET,
        start_time_ms: int = 0,
        origin_s: float = 0.0,
        scan_period_s: float = SCAN_PERIOD_S,
    ) -> None:
        if scan_period_s <= 0:
            raise ValueError("scan_period_s must be positive")
        self.source = source
        self.identity = identity
        self.link = link
        self.scan_period_s = scan_period_s
        self.origin_s = origin_s
        self._timer_origin_s = origin_s
        self._timer_start_ms = start_time_ms % codec.TIMESTAMP_MODULUS
        self.state = SensorState.IDLE
        self._stream: _Stream | None = None
        self._high_sensitivity = False
        self._bit_rate = INITIAL_SERIAL_BIT_RATE
        self._reboot_armed_s: float | None = None

    # ----------------------------------------------------------------- clock

    def time_ms(self, now_s: float) -> int:
        """The sensor's 24-bit millisecond timer at ``now_s``."""
        elapsed_ms = math.floor((now_s - self._timer_origin_s) * 1000.0 + _EPSILON_S)
        return (self._timer_start_ms + elapsed_ms) % codec.TIMESTAMP_MODULUS

    def _reset_timer(self, now_s: float) -> None:
        self._timer_origin_s = now_s
        self._timer_start_ms = 0

    def scan_start_s(self, index: int) -> float:
        """Start time of scan ``index`` (0 = the first revolution after power-up)."""
        return self.origin_s + index * self.scan_period_s

    def _next_scan_start_s(self, now_s: float) -> float:
        return self.scan_start_s(math.ceil((now_s - self.origin_s) / self.scan_period_s - _EPSILON_S))

    def _latest_complete_scan_start_s(self, now_s: float) -> float:
        return self.scan_start_s(math.floor((now_s - self.origin_s) / self.scan_period_s + _EPSILON_S) - 1)

    @property
    def laser_on(self) -> bool:
        """True while measuring or streaming."""
        return self.state in (SensorState.MEASURING, SensorState.STREAMING)

    @property
    def streaming(self) -> bool:
        """True while an MD/MS/ME stream is running."""
        return self.state is SensorState.STREAMING

    # ----------------------------------------------------------------- link events

    def disconnect(self) -> None:
        """The TCP client went away: stop streaming, laser off (urg_sim behaviour)."""
        if self.state is not SensorState.IDLE:
            logger.info("client disconnected: stream stopped, laser off")
        self._go_idle()

    def _go_idle(self) -> None:
        self.state = SensorState.IDLE
        self._stream = None

    # ----------------------------------------------------------------- requests

    def handle(self, line: bytes, now_s: float) -> DeviceReply:
        """Reply to one request line (without its terminator) processed at ``now_s``."""
        command = line[:2].decode("ascii", errors="replace")
        if command != "RB":
            self._reboot_armed_s = None
        if command in codec.SINGLE_SCAN_COMMANDS + codec.STREAM_COMMANDS:
            return DeviceReply(self._scan_command(line, now_s))
        width = _PARAMETER_WIDTHS.get(command)
        if width is None:
            return DeviceReply(_status(line, "0E"))
        body, separator, tag = line.partition(b";")
        parameters = body[2:]
        if len(parameters) < width:
            return DeviceReply(_status(line, "0C"))
        if len(parameters) > width:
            return DeviceReply(_status(line, "0D"))
        tag_status = _tag_status(tag) if separator else None
        if tag_status:
            return DeviceReply(_status(line, tag_status))
        if self.state is SensorState.TIME_ADJUST and command not in _ALLOWED_IN_TIME_ADJUST:
            return DeviceReply(_status(line, "10"))
        handler = getattr(self, f"_cmd_{command.lower()}")
        return handler(line, parameters, now_s)

    def _cmd_vv(self, line: bytes, parameters: bytes, now_s: float) -> DeviceReply:
        return DeviceReply(_with_fields(line, self.identity.version_fields()))

    def _cmd_pp(self, line: bytes, parameters: bytes, now_s: float) -> DeviceReply:
        return DeviceReply(_with_fields(line, self.identity.parameter_fields()))

    def _cmd_ii(self, line: bytes, parameters: bytes, now_s: float) -> DeviceReply:
        identity = self.identity
        time_ms = self.time_ms(now_s)
        if identity.ii_time_format == "hex":
            time_text = f"{time_ms:06X}"
        else:
            time_text = codec.encode_int(time_ms, 4).decode("ascii")
        fields = [
            ("MODL", identity.ii_model),
            ("LASR", "ON" if self.laser_on else "OFF"),
            ("SCSP", identity.ii_motor_speed),
            ("MESM", identity.mode_text(self.state)),
            ("SBPS", identity.link_text(self.link)),
            ("TIME", time_text),
            ("STAT", identity.ii_status),
        ]
        return DeviceReply(_with_fields(line, fields))

    def _cmd_bm(self, line: bytes, parameters: bytes, now_s: float) -> DeviceReply:
        if self.laser_on:
            return DeviceReply(_status(line, "02"))
        self.state = SensorState.MEASURING
        return DeviceReply(_status(line, "00"))

    def _cmd_qt(self, line: bytes, parameters: bytes, now_s: float) -> DeviceReply:
        if self.state is SensorState.TIME_ADJUST:
            return DeviceReply(_status(line, "0E"))
        self._go_idle()
        return DeviceReply(_status(line, "00"))

    def _cmd_rs(self, line: bytes, parameters: bytes, now_s: float) -> DeviceReply:
        """Reset: laser off, stream stopped, timer to 0, defaults restored; stays in
        time-adjust mode if it was in it (only TM2 leaves it)."""
        if self.state is not SensorState.TIME_ADJUST:
            self._go_idle()
        self._reset_timer(now_s)
        self._high_sensitivity = False
        self._bit_rate = INITIAL_SERIAL_BIT_RATE
        return DeviceReply(_status(line, "00"))

    def _cmd_rt(self, line: bytes, parameters: bytes, now_s: float) -> DeviceReply:
        """Partial reset: like RS but keeps the bit rate."""
        if self.state is not SensorState.TIME_ADJUST:
            self._go_idle()
        self._reset_timer(now_s)
        self._high_sensitivity = False
        return DeviceReply(_status(line, "00"))

    def _cmd_rb(self, line: bytes, parameters: bytes, now_s: float) -> DeviceReply:
        """Reboot: the first RB answers 01; a second within 1 s answers 00, then the
        sensor reboots (state and timer reset; the server drops the link)."""
        armed = self._reboot_armed_s
        if armed is None or now_s - armed > REBOOT_WINDOW_S:
            self._reboot_armed_s = now_s
            return DeviceReply(_status(line, "01"))
        self._reboot_armed_s = None
        self._go_idle()
        self._reset_timer(now_s)
        self._high_sensitivity = False
        self._bit_rate = INITIAL_SERIAL_BIT_RATE
        return DeviceReply(_status(line, "00"), hang_up=self.link is LinkKind.ETHERNET)

    def _cmd_tm(self, line: bytes, parameters: bytes, now_s: float) -> DeviceReply:
        code = parameters.decode("ascii", errors="replace")
        in_adjust = self.state is SensorState.TIME_ADJUST
        if code == "0":
            if in_adjust:
                return DeviceReply(_status(line, "02"))
            if self.streaming:
                return DeviceReply(_status(line, "10"))
            self._go_idle()
            self.state = SensorState.TIME_ADJUST
            return DeviceReply(_status(line, "00"))
        if code == "1":
            if not in_adjust:
                return DeviceReply(_status(line, "04"))
            stamp = codec.timestamp_line(self.time_ms(now_s))
            return DeviceReply(codec.format_response(line, b"00", [stamp]))
        if code == "2":
            if not in_adjust:
                return DeviceReply(_status(line, "03"))
            self._go_idle()
            return DeviceReply(_status(line, "00"))
        return DeviceReply(_status(line, "01"))

    def _cmd_ss(self, line: bytes, parameters: bytes, now_s: float) -> DeviceReply:
        """Bit rate: meaningless on Ethernet (``0F``, as urg_library expects); on the
        serial link validated and stored (a pseudo-terminal ignores it)."""
        if self.link is LinkKind.ETHERNET:
            return DeviceReply(_status(line, "0F"))
        if not parameters.isdigit():
            return DeviceReply(_status(line, "01"))
        rate = int(parameters)
        if rate not in SERIAL_BIT_RATES:
            return DeviceReply(_status(line, "02"))
        if rate == self._bit_rate:
            return DeviceReply(_status(line, "03"))
        self._bit_rate = rate
        return DeviceReply(_status(line, "00"))

    def _cmd_cr(self, line: bytes, parameters: bytes, now_s: float) -> DeviceReply:
        """Motor speed: the UTM-30LX family does not support it (captured ``04``)."""
        if not parameters.isdigit():
            return DeviceReply(_status(line, "01"))
        return DeviceReply(_status(line, "04"))

    def _cmd_hs(self, line: bytes, parameters: bytes, now_s: float) -> DeviceReply:
        if parameters not in (b"0", b"1"):
            return DeviceReply(_status(line, "01"))
        wanted = parameters == b"1"
        if wanted == self._high_sensitivity:
            return DeviceReply(_status(line, "02"))
        self._high_sensitivity = wanted
        return DeviceReply(_status(line, "00"))

    # ----------------------------------------------------------------- scans

    def _scan_command(self, line: bytes, now_s: float) -> bytes:
        try:
            request = codec.parse_scan_request(line)
        except codec.RequestParameterError as exc:
            return _status(line, exc.status)
        if request.last_step > self.identity.last_step:
            return _status(line, "04")
        if request.last_step < request.first_step:
            return _status(line, "05")
        if self.state is SensorState.TIME_ADJUST:
            return _status(line, "10")
        if not request.is_stream:
            if not self.laser_on:
                return _status(line, "10")
            scan_start_s = self._latest_complete_scan_start_s(now_s)
            return codec.format_response(line, b"00", self._scan_lines(request, scan_start_s))
        self.state = SensorState.STREAMING
        self._stream = _Stream(request, self._next_scan_start_s(now_s))
        return _status(line, "00")

    def complete_scan(self, scan_start_s: float) -> bytes | None:
        """The stream message for the revolution that started at ``scan_start_s``, or
        None when nothing is due (not streaming, scan started before the request, or
        skipped by the scan interval). Ends a finite stream after its last scan."""
        stream = self._stream
        if stream is None or scan_start_s < stream.first_scan_start_s - _EPSILON_S:
            return None
        request = stream.request
        stream.scans_seen += 1
        if (stream.scans_seen - 1) % ((request.interval or 0) + 1):
            return None
        stream.scans_sent += 1
        remaining = (request.count or 0) - stream.scans_sent if request.count else 0
        message = codec.format_response(
            request.line(remaining), b"99", self._scan_lines(request, scan_start_s)
        )
        if request.count and stream.scans_sent >= request.count:
            self._go_idle()
        return message

    def _scan_lines(self, request: codec.ScanRequest, scan_start_s: float) -> list[bytes]:
        distances, intensities = self._measure(request, scan_start_s)
        if request.chars_per_value == 2:
            distances = np.minimum(distances, TWO_CHAR_MAX_MM)
        return codec.encode_scan_lines(
            self.time_ms(scan_start_s),
            distances,
            intensities if request.with_intensity else None,
            request.chars_per_value,
        )

    def _measure(
        self, request: codec.ScanRequest, scan_start_s: float
    ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        first, last = request.first_step, request.last_step
        all_ranges, all_intensities = self.source.ranges_mm(scan_start_s)
        ranges = np.asarray(all_ranges, dtype=np.int64)
        intensities = np.asarray(all_intensities, dtype=np.int64)
        expected = (self.identity.last_step + 1,)
        if ranges.shape != expected or intensities.shape != expected:
            raise ValueError(
                f"range source returned shapes {ranges.shape}/{intensities.shape}, expected {expected} "
                f"(steps 0..{self.identity.last_step})"
            )
        ranges, intensities = ranges[first : last + 1], intensities[first : last + 1]
        ranges = np.clip(ranges, 0, (1 << 18) - 1)
        intensities = np.clip(intensities, 0, (1 << 18) - 1)
        return _cluster(ranges, intensities, max(request.cluster, 1), self.identity.min_range_mm)


def _cluster(
    ranges: NDArray[np.int64], intensities: NDArray[np.int64], cluster: int, min_range_mm: int
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Group ``cluster`` steps: the minimum valid distance of each group (its intensity
    with it); a group without a valid distance reports its first error code."""
    if cluster == 1:
        return ranges, intensities
    groups = -(-ranges.size // cluster)
    padded = groups * cluster
    r = np.zeros(padded, dtype=np.int64)
    r[: ranges.size] = ranges
    i = np.zeros(padded, dtype=np.int64)
    i[: intensities.size] = intensities
    real = np.arange(padded) < ranges.size
    r, i, real = r.reshape(groups, cluster), i.reshape(groups, cluster), real.reshape(groups, cluster)
    valid = real & (r >= min_range_mm)
    pick = np.argmin(np.where(valid, r, np.iinfo(np.int64).max), axis=1)
    pick = np.where(valid.any(axis=1), pick, 0)
    rows = np.arange(groups)
    return r[rows, pick], i[rows, pick]


def _status(echo: bytes, status: str) -> bytes:
    return codec.format_response(echo, status.encode("ascii"))


def _with_fields(echo: bytes, fields: list[tuple[str, str]]) -> bytes:
    return codec.format_response(echo, b"00", [codec.parameter_line(k, v) for k, v in fields])


def _tag_status(tag: bytes) -> str | None:
    """``0G`` if the string field is longer than 16 characters, ``0H`` if it holds a
    character outside ``A-Z a-z 0-9 space . _ + @``."""
    if len(tag) > codec.MAX_TAG_CHARS:
        return "0G"
    if any(not (chr(b).isascii() and (chr(b).isalnum() or chr(b) in " ._+@")) for b in tag):
        return "0H"
    return None
