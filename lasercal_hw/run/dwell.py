"""Gathering the scans of one dwell: only scans acquired after the arm settled count.

When a scan was acquired comes from its device-time stamp (``LaserScan.device_time_s``:
the scanner's own clock mapped onto the host's ``time.time()`` by the driver), never from
when the host happened to read it: a scan read just after a move may have been taken
during it. Missing sequence numbers inside a window mean the stream had a gap (a
reconnect or lost blocks), which the caller treats as a reason to repeat the dwell.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from itertools import pairwise

from lasercal_hw.models import LaserScan
from lasercal_hw.run.devices import Scanner


@dataclass(frozen=True)
class DwellCapture:
    """The scans of one window and what was seen while gathering them."""

    scans: list[LaserScan]
    discarded_before_start: int
    window_start_host_s: float
    window_end_host_s: float
    missed_scans: int = 0


def _missed(sequences: list[int]) -> int:
    """Sequence numbers skipped in an ascending run (scans the stream never delivered)."""
    return sum(max(b - a - 1, 0) for a, b in pairwise(sequences))


def collect_window(
    scanner: Scanner,
    *,
    start_host_s: float,
    duration_s: float,
    scan_timeout_s: float,
    on_scan: Callable[[LaserScan], None],
) -> DwellCapture:
    """Scans acquired in ``[start_host_s, start_host_s + duration_s)``.

    Every scan read is handed to ``on_scan`` (for the recording), including the stale ones
    from before the window and the first one after it, which ends the wait. Scans missing
    from the first kept one to that last one are counted as missed. The scanner's
    ``DeviceTimeoutError``/``TransportError`` propagate when the stream stalls.
    """
    end_host_s = start_host_s + duration_s
    kept: list[LaserScan] = []
    discarded = 0
    while True:
        scan = scanner.next_scan(scan_timeout_s)
        on_scan(scan)
        if scan.device_time_s >= end_host_s:
            missed = _missed([s.sequence for s in kept] + [scan.sequence]) if kept else 0
            return DwellCapture(kept, discarded, start_host_s, end_host_s, missed)
        if scan.device_time_s < start_host_s:
            discarded += 1
            continue
        kept.append(scan)


def collect_count(
    scanner: Scanner,
    *,
    start_host_s: float,
    count: int,
    scan_timeout_s: float,
    on_scan: Callable[[LaserScan], None],
) -> DwellCapture:
    """The first ``count`` scans acquired at or after ``start_host_s``."""
    kept: list[LaserScan] = []
    discarded = 0
    while len(kept) < count:
        scan = scanner.next_scan(scan_timeout_s)
        on_scan(scan)
        if scan.device_time_s < start_host_s:
            discarded += 1
            continue
        kept.append(scan)
    missed = _missed([s.sequence for s in kept])
    return DwellCapture(kept, discarded, start_host_s, kept[-1].device_time_s, missed)
