"""The cell's other scanners at one scanner's waypoints (docs/cell.md, shared waypoints).

While a cell job visits scanner A's waypoints, each other scanner of the cell with a nominal
pose is a *watcher*: at a waypoint where that pose says the rod crosses the watcher's plane
inside its field of view, the watcher measures the rod at the same standstill, right after
A's dwell, and its centre goes on record in A's recording as a ``shared_observation`` event
(``scanner``, ``index``, ``tcp_pose``, ``centre_uv_m``, ``covariance_uv_m2``, ``quality``,
``scans``, ``window_start_s``, ``window_end_s``). Every scan it reads goes into A's recording
too, on its own topic (``/scan/NAME``), so a replay computes its centre again from them with
``watcher_centre`` (``run/replay.replay_shared_centres``). Where two scan planes see the rod at
one waypoint both centres are then on record, and the cell tests whether the two poses agree
(``calibration/agreement.py``). No background is taken for a watcher: its nominal pose picks
the rod among the scan's objects. After the job, with the watcher's own run solved, its centres
get the second pass its own centres got (``second_pass_centre``).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from lasercal_hw.errors import InterruptedRunError, LasercalError
from lasercal_hw.models import FloatArray, RodLine
from lasercal_hw.run.devices import Scanner
from lasercal_hw.run.dwell import collect_window
from lasercal_hw.run.records import WaypointMeasurement
from lasercal_hw.run.two_pass import predict_rod, refit_centres
from lasercal_hw.scan.average import AveragedScan, average_scans
from lasercal_hw.scan.extraction import RodCentre, RodNotFoundError, find_rod_centre

logger = logging.getLogger(__name__)

SHARED_OBSERVATION = "shared_observation"
#: The part of a watcher's field of view (and range) a predicted crossing must lie in: a
#: nominal pose is a few centimetres and degrees off.
_EDGE_MARGIN_RAD = np.radians(3.0)


@dataclass(frozen=True)
class Watcher:
    """Another scanner of the cell, connected, and its rough pose in the base frame."""

    name: str
    scanner: Scanner
    nominal: FloatArray


def expected_crossing(
    watcher: Watcher, tcp_pose: FloatArray, rod: RodLine
) -> tuple[FloatArray, FloatArray] | None:
    """Where the watcher's nominal pose puts the rod's crossing (u, v) in its plane and the rod's
    axis in its frame, or None when the rod misses its plane or its field of view."""
    predicted = predicted_crossing(watcher.nominal, tcp_pose, rod)
    if predicted is None:
        return None
    geometry = watcher.scanner.geometry()
    uv = predicted[0]
    angle_rad = float(np.arctan2(uv[1], uv[0]))
    angle_max_rad = geometry.angle_min_rad + (geometry.beam_count - 1) * geometry.angle_increment_rad
    inside = geometry.angle_min_rad + _EDGE_MARGIN_RAD <= angle_rad <= angle_max_rad - _EDGE_MARGIN_RAD
    if not inside or not geometry.min_range_m < float(np.linalg.norm(uv)) < geometry.max_range_m:
        return None
    return predicted


def predicted_crossing(
    nominal: FloatArray, tcp_pose: FloatArray, rod: RodLine
) -> tuple[FloatArray, FloatArray] | None:
    """Where the pose ``nominal`` puts the rod's crossing (u, v) and the rod's axis in its
    frame, or None when the rod misses its plane: what picks the rod in a watcher's scans."""
    predicted = predict_rod(nominal, tcp_pose, rod)
    if predicted.expected_uv_m is None:
        return None
    uv = np.asarray(predicted.expected_uv_m, dtype=float)
    return uv, np.asarray(predicted.axis_in_scanner, dtype=float)


def watcher_centre(
    averaged: AveragedScan, expected: tuple[FloatArray, FloatArray], rod: RodLine
) -> RodCentre:
    """The rod's centre in a watcher's averaged scan: no background, the rod picked and its
    cross-section cut where ``expected_crossing`` puts it (a RodNotFoundError when it is not there)."""
    expected_uv_m, axis = expected
    return find_rod_centre(
        averaged, radius_m=rod.radius_m, axis_in_scanner=axis, expected_uv_m=expected_uv_m, fluted=rod.fluted
    )


@dataclass(frozen=True)
class SolvedWatcher:
    """What a watcher's second pass takes from its scanner's own run: the solved pose, the rod
    line its solve estimated, its background (None: it took none), and how far its first-pass
    centres lay from its solved ones (``run/cell.first_pass_scatter_uv_m2``; None: unknown)."""

    T_base_laser: FloatArray
    rod: RodLine
    background: AveragedScan | None
    first_pass_scatter_uv_m2: FloatArray | None


def second_pass_centre(
    averaged: AveragedScan, tcp_pose: FloatArray, first: RodCentre, solved: SolvedWatcher
) -> tuple[RodCentre, bool]:
    """A watcher's centre fitted again as its scanner's own run fits its own in the second pass
    (``run/two_pass.refit_centres``: the background, the rod picked and its ellipse cut where the
    solved pose puts it; no range offset taken out, the cell removes the whole curve), and True;
    where that finds no rod, the first-pass centre ``first`` with its scanner's first-pass
    scatter added to its covariance (what a first pass errs by that its covariance leaves out),
    and False."""
    measurement = WaypointMeasurement(0, tcp_pose, averaged, first)
    refitted, kept = refit_centres([measurement], solved.T_base_laser, solved.rod, solved.background)
    if not kept:
        return refitted[0].centre, True
    return as_first_pass(first, solved), False


def as_first_pass(centre: RodCentre, solved: SolvedWatcher) -> RodCentre:
    """A watcher's first-pass centre with its scanner's first-pass scatter in its covariance."""
    if solved.first_pass_scatter_uv_m2 is None:
        return centre
    covariance = np.asarray(centre.covariance_uv_m2, dtype=float) + solved.first_pass_scatter_uv_m2
    return replace(centre, covariance_uv_m2=covariance)


def watch_waypoint(
    watcher: Watcher,
    index: int,
    tcp_pose: FloatArray,
    rod: RodLine,
    *,
    dwell_s: float,
    scan_timeout_s: float,
    clock: Callable[[], float],
    record: Callable[..., None],
    on_scan: Callable[[Any], None],
) -> None:
    """Measure the rod with ``watcher`` at the waypoint the arm stands at, when its nominal pose
    says it sees the rod; every scan read goes to ``on_scan`` (the recording) and the centre is
    recorded (``record(SHARED_OBSERVATION, **fields)``) with the window whose scans it averaged.
    A watcher that fails or finds no rod is logged and left out: it never stops the run."""
    expected = expected_crossing(watcher, tcp_pose, rod)
    if expected is None:
        return
    scanner = watcher.scanner
    try:
        scanner.start_streaming()
        try:
            capture = collect_window(
                scanner, start_host_s=clock(), duration_s=dwell_s, scan_timeout_s=scan_timeout_s,
                on_scan=on_scan,
            )
        finally:
            scanner.stop_streaming()
        centre = watcher_centre(average_scans(capture.scans), expected, rod)
    except InterruptedRunError:
        raise
    except RodNotFoundError as exc:  # the waypoints are the run scanner's: the other's view is often blocked
        logger.info("scanner %s at waypoint %d: no shared centre (%s)", watcher.name, index, exc)
        return
    except LasercalError as exc:  # a failed stream
        logger.warning("scanner %s at waypoint %d: no shared centre (%s)", watcher.name, index, exc)
        return
    record(
        SHARED_OBSERVATION,
        scanner=watcher.name,
        index=index,
        tcp_pose=tcp_pose,
        centre_uv_m=[float(c) for c in centre.centre_uv_m],
        covariance_uv_m2=centre.covariance_uv_m2,
        quality=centre.quality,
        scans=len(capture.scans),
        expected_uv_m=[float(c) for c in expected[0]],
        window_start_s=capture.window_start_host_s,
        window_end_s=capture.window_end_host_s,
    )
