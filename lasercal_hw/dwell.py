"""Gathering the scans of one dwell: only scans taken after the arm settled count.

A scan's moment of acquisition comes from the scanner's own clock, not from when the
host happened to read it (a scan read after a move may have been taken during it). The
device clock is mapped onto the host clock by the smallest ``host - device`` difference
seen so far: transport latency is never negative, so that minimum is the tightest offset
estimate, and if the two clocks drift apart it errs towards calling a scan earlier than
it was, which only ever excludes a scan, never admits one taken while moving.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from lasercal_hw.devices import Scanner
from lasercal_hw.models import LaserScan


class DeviceClock:
    """Maps scanner device time (s) onto the host clock the sequencer uses."""

    def __init__(self) -> None:
        self._offset_s: float | None = None

    def observe(self, scan: LaserScan) -> None:
        """Tighten the offset estimate with one more scan."""
        offset_s = scan.host_time_s - scan.device_time_s
        if self._offset_s is None or offset_s < self._offset_s:
            self._offset_s = offset_s

    def host_time_of(self, scan: LaserScan) -> float:
        """When the scan was acquired, on the host clock (observe the scan first)."""
        if self._offset_s is None:
            self.observe(scan)
        assert self._offset_s is not None
        return scan.device_time_s + self._offset_s


@dataclass(frozen=True)
class DwellCapture:
    """The scans of one dwell and what was seen while gathering them."""

    scans: list[LaserScan]
    discarded_before_start: int
    window_start_host_s: float
    window_end_host_s: float


def collect_window(
    scanner: Scanner,
    clock: DeviceClock,
    *,
    start_host_s: float,
    duration_s: float,
    scan_timeout_s: float,
    on_scan: Callable[[LaserScan], None],
) -> DwellCapture:
    """Scans acquired in ``[start_host_s, start_host_s + duration_s)``.

    Every scan read is handed to ``on_scan`` (for the recording), including the stale ones
    from before the window and the first one after it, which ends the wait. Raises the
    scanner's ``DeviceTimeoutError``/``TransportError`` when the stream stalls.
    """
    end_host_s = start_host_s + duration_s
    kept: list[LaserScan] = []
    discarded = 0
    while True:
        scan = scanner.next_scan(scan_timeout_s)
        on_scan(scan)
        clock.observe(scan)
        acquired_s = clock.host_time_of(scan)
        if acquired_s >= end_host_s:
            break
        if acquired_s < start_host_s:
            discarded += 1
            continue
        kept.append(scan)
    return DwellCapture(kept, discarded, start_host_s, end_host_s)


def collect_count(
    scanner: Scanner,
    clock: DeviceClock,
    *,
    start_host_s: float,
    count: int,
    scan_timeout_s: float,
    on_scan: Callable[[LaserScan], None],
) -> DwellCapture:
    """The first ``count`` scans acquired at or after ``start_host_s``."""
    kept: list[LaserScan] = []
    discarded = 0
    last_s = start_host_s
    while len(kept) < count:
        scan = scanner.next_scan(scan_timeout_s)
        on_scan(scan)
        clock.observe(scan)
        acquired_s = clock.host_time_of(scan)
        if acquired_s < start_host_s:
            discarded += 1
            continue
        kept.append(scan)
        last_s = acquired_s
    return DwellCapture(kept, discarded, start_host_s, last_s)
