"""Scanner clock handling: unwrap the 24-bit millisecond counter and map it to host time.

The sensor stamps every scan with a free-running 24-bit ms counter that wraps after
4 h 39 min (scip2.md section 6). ``TimestampUnwrapper`` turns it into a 64-bit count
with a half-range rule (a backwards jump of more than half the range is a wrap; smaller
backwards steps are not). ``DeviceClock`` maps unwrapped device time to host time
(``time.time()`` seconds): the offset comes from a ``TM`` exchange (the sample with the
shortest round trip), the drift from the lower envelope of (host receive time - device
stamp) over a sliding window of stream scans.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from drivers.hokuyo.codec import TIMESTAMP_MODULUS

logger = logging.getLogger(__name__)

MAX_DRIFT = 1e-3
"""Drift estimates beyond 1000 ppm are treated as bad data (crystals drift ~50 ppm)."""


class TimestampUnwrapper:
    """Unwrap a wrapping counter with the half-range rule (64-bit Python ints)."""

    def __init__(self, modulus: int = TIMESTAMP_MODULUS) -> None:
        self.modulus = modulus
        self._last_raw: int | None = None
        self._offset = 0

    def reset(self) -> None:
        """Forget the history (the device counter was reset, e.g. after RS)."""
        self._last_raw = None
        self._offset = 0

    def unwrap(self, raw: int) -> int:
        """The unwrapped value of ``raw`` (0 <= raw < modulus)."""
        if self._last_raw is not None:
            delta = raw - self._last_raw
            if delta < -self.modulus // 2:
                self._offset += self.modulus
            elif delta > self.modulus // 2:
                self._offset -= self.modulus
        self._last_raw = raw
        return raw + self._offset


@dataclass(frozen=True)
class ClockSample:
    """One TM1 exchange: host send and receive times (s) and the device time (ms)."""

    host_send_s: float
    host_receive_s: float
    device_ms: int

    @property
    def round_trip_s(self) -> float:
        """Host-measured round trip."""
        return self.host_receive_s - self.host_send_s


@dataclass(frozen=True)
class ClockEstimate:
    """Current mapping: ``host_s = device_s + offset_s + drift * (device_s - reference_device_s)``."""

    offset_s: float
    drift: float
    reference_device_s: float
    source: str  # "tm", "stream" or "none"
    round_trip_s: float | None = None


class DeviceClock:
    """Maps unwrapped device milliseconds to host time, with offset and drift.

    ``synchronise`` anchors the offset with TM samples; ``observe`` feeds stream stamps
    (device time, host receive time) whose per-block minima estimate the drift and, when
    no TM anchor exists, the offset (minus ``stream_delay_s``, the time from a scan's
    step 0 to its arrival)."""

    def __init__(self, window_s: float = 120.0, block_s: float = 1.0, stream_delay_s: float = 0.0) -> None:
        self.window_s = window_s
        self.block_s = block_s
        self.stream_delay_s = stream_delay_s
        self._anchor: ClockEstimate | None = None
        self._blocks: deque[tuple[float, float]] = deque()  # (device_s, min host-device)
        self._block_start: float | None = None
        self._block_min: tuple[float, float] | None = None
        self._block_count = 0
        self._fit_cache: tuple[int, tuple[float, float, float] | None] | None = None

    def reset(self) -> None:
        """Forget anchor and stream history (device counter reset)."""
        self._anchor = None
        self._blocks.clear()
        self._block_start = None
        self._block_min = None
        self._fit_cache = None

    def synchronise(self, samples: Sequence[ClockSample]) -> ClockEstimate:
        """Anchor the offset on the TM sample with the shortest round trip."""
        if not samples:
            raise ValueError("need at least one clock sample")
        best = min(samples, key=lambda s: s.round_trip_s)
        device_s = best.device_ms / 1000.0
        midpoint = 0.5 * (best.host_send_s + best.host_receive_s)
        self._anchor = ClockEstimate(midpoint - device_s, 0.0, device_s, "tm", best.round_trip_s)
        logger.debug(
            "clock anchored: offset %.6f s, round trip %.3f ms", midpoint - device_s, 1000 * best.round_trip_s
        )
        return self.estimate()

    def observe(self, device_ms: int, host_receive_s: float) -> None:
        """Add one stream stamp pair (unwrapped device ms, host receive time)."""
        device_s = device_ms / 1000.0
        lag = host_receive_s - device_s
        if self._block_start is None or device_s < self._block_start:
            if self._block_start is not None:  # device time went backwards: history is void
                self._blocks.clear()
                self._fit_cache = None
            self._block_start, self._block_min = device_s, (device_s, lag)
            return
        if device_s - self._block_start >= self.block_s:
            if self._block_min is not None:
                self._blocks.append(self._block_min)
                self._block_count += 1
            self._block_start, self._block_min = device_s, (device_s, lag)
            while self._blocks and device_s - self._blocks[0][0] > self.window_s:
                self._blocks.popleft()
        elif self._block_min is None or lag < self._block_min[1]:
            self._block_min = (device_s, lag)

    def _envelope(self) -> tuple[float, float, float] | None:
        """(slope, intercept at reference, reference) of the closed blocks' minima, or None."""
        if self._fit_cache is not None and self._fit_cache[0] == self._block_count:
            return self._fit_cache[1]
        fit: tuple[float, float, float] | None = None
        if len(self._blocks) >= 3:
            device = np.array([p[0] for p in self._blocks])
            lag = np.array([p[1] for p in self._blocks])
            reference = float(device[-1])
            slope, intercept = np.polyfit(device - reference, lag, 1)
            if abs(slope) <= MAX_DRIFT:
                fit = (float(slope), float(intercept), reference)
        self._fit_cache = (self._block_count, fit)
        return fit

    def estimate(self) -> ClockEstimate:
        """The current offset/drift model."""
        envelope = self._envelope()
        drift = envelope[0] if envelope else 0.0
        if self._anchor is not None:
            anchor = self._anchor
            return ClockEstimate(anchor.offset_s, drift, anchor.reference_device_s, "tm", anchor.round_trip_s)
        if envelope is not None:
            slope, intercept, reference = envelope
            return ClockEstimate(intercept - self.stream_delay_s, slope, reference, "stream")
        if self._block_min is not None:
            device_s, lag = self._block_min
            return ClockEstimate(lag - self.stream_delay_s, 0.0, device_s, "stream")
        return ClockEstimate(0.0, 0.0, 0.0, "none")

    def to_host_s(self, device_ms: int) -> float:
        """Host time (s) of an unwrapped device time in ms."""
        estimate = self.estimate()
        device_s = device_ms / 1000.0
        return device_s + estimate.offset_s + estimate.drift * (device_s - estimate.reference_device_s)
