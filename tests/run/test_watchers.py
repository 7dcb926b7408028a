"""What a cell's other scanner (``run.watchers``) says when it gets no centre at a waypoint: its
view blocked is routine and logged quietly; a failed stream is a warning."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from lasercal_hw.geometry import make_transform
from lasercal_hw.models import RodLine
from lasercal_hw.run.watchers import Watcher, expected_crossing, watch_waypoint
from tests.doubles import PAPER_T_BASE_LASER, SimClock, SimRobot, SimScanner, semicircle_waypoints

ROD = RodLine()


def _watch(scanner: SimScanner, clock: SimClock, pose: np.ndarray) -> list[dict[str, object]]:
    recorded: list[dict[str, object]] = []
    watcher = Watcher("front", scanner, PAPER_T_BASE_LASER)
    assert expected_crossing(watcher, pose, ROD) is not None  # its nominal pose says it sees the rod
    watch_waypoint(watcher, 3, pose, ROD, dwell_s=0.25, scan_timeout_s=0.1, clock=clock,
                   record=lambda kind, **fields: recorded.append(fields), on_scan=lambda scan: None)
    return recorded


def _cell(**scanner_options: object) -> tuple[SimClock, SimScanner, np.ndarray]:
    clock = SimClock()
    pose = semicircle_waypoints(6)[2]
    robot = SimRobot(clock, pose=pose.copy())
    return clock, SimScanner(clock, robot, ROD, **scanner_options), pose  # type: ignore[arg-type]


def test_a_watcher_whose_view_is_blocked_logs_it_below_warning(caplog: pytest.LogCaptureFixture) -> None:
    # The scanner is really 0.3 m from where its nominal pose says: the rod is not where expected.
    moved = make_transform(PAPER_T_BASE_LASER[:3, :3], PAPER_T_BASE_LASER[:3, 3] + [0.3, 0.0, 0.0])
    clock, scanner, pose = _cell(T_base_laser=moved)
    with caplog.at_level(logging.INFO, logger="lasercal_hw.run.watchers"):
        assert _watch(scanner, clock, pose) == []
    (record,) = [r for r in caplog.records if "no shared centre" in r.getMessage()]
    assert record.levelno == logging.INFO and "scanner front at waypoint 3" in record.getMessage()


def test_a_watcher_whose_stream_fails_warns(caplog: pytest.LogCaptureFixture) -> None:
    clock, scanner, pose = _cell(fail_reads_at=set(range(1, 100)))
    with caplog.at_level(logging.INFO, logger="lasercal_hw.run.watchers"):
        assert _watch(scanner, clock, pose) == []
    (record,) = [r for r in caplog.records if "no shared centre" in r.getMessage()]
    assert record.levelno == logging.WARNING


def test_a_watcher_that_sees_the_rod_records_its_centre() -> None:
    clock, scanner, pose = _cell()
    (fields,) = _watch(scanner, clock, pose)
    assert fields["scanner"] == "front" and fields["index"] == 3
