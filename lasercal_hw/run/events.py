"""What a run reports while it goes: ``RunEvent``s, numbered, JSON-ready, for any consumer
(a terminal view, a JSON printer, an HTTP event stream, a test).

Kinds and their ``data``:

- ``stage``: ``stage`` (fake_cell, connect, outputs; verify's select) and what goes with it;
- ``progress``: every sequencer step: ``stage``, ``waypoint``, ``waypoint_count``,
  ``completed``, ``scans_averaged``, ``time_left_s``;
- ``centre``: ``waypoint``, ``centre_uv_m``, ``covariance_uv_m2``, ``warnings`` (why the centre
  may be off by more than its covariance; empty: no doubt), ``scans``;
- ``skip``: ``waypoint``, ``reason``;
- ``scan``: the averaged scan of a waypoint for a live picture: ``waypoint``,
  ``angle_min_rad``, ``angle_increment_rad``, ``ranges_m`` (null where no return),
  ``rod_beams``, ``circle`` (``centre_uv_m``, ``radius_m``) or null;
- ``warning``, ``stopped`` (the run ended on an error: where its recording is), ``result``;
- a cell job's ``scanner_result`` (``run/cell``): ``scanner``, ``folder``, ``passed``, ``kept``;
  and, once every scanner is solved, one ``pair_agreement`` per pair: ``from``, ``to`` and the
  pair's agreement as ``cell.json`` holds it (its ``centres``: those the test compared, a
  watcher's after its second pass; a ``centre`` event is always a first pass).

Every ``stage`` is a ``Stage``, which says which ``Phase`` of the run it belongs to (what a
job reports as its state).
"""

from __future__ import annotations

import itertools
import logging
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from enum import StrEnum
from typing import Any

import numpy as np

from lasercal_hw.run.records import Progress
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction import RodCentre

logger = logging.getLogger(__name__)

EventCallback = Callable[["RunEvent"], None]


class Phase(StrEnum):
    """The part of a run a stage belongs to (a daemon job's state while it runs)."""

    PREFLIGHT = "preflight"
    RUNNING = "running"
    SOLVING = "solving"


class Stage(StrEnum):
    """Every stage a run (or a verify) goes through, with its ``phase``."""

    phase: Phase

    def __new__(cls, value: str, phase: Phase) -> Stage:
        stage = str.__new__(cls, value)
        stage._value_ = value
        stage.phase = phase
        return stage

    SELECT = "select", Phase.PREFLIGHT  # verify chooses its waypoints
    FAKE_CELL = "fake_cell", Phase.PREFLIGHT
    CONNECT = "connect", Phase.PREFLIGHT
    PREFLIGHT = "preflight", Phase.PREFLIGHT
    BACKGROUND = "background", Phase.RUNNING
    MOVE = "move", Phase.RUNNING
    DWELL = "dwell", Phase.RUNNING
    CENTRE = "centre", Phase.RUNNING
    SKIP = "skip", Phase.RUNNING
    RETRY = "retry", Phase.RUNNING
    SOLVE = "solve", Phase.SOLVING
    REFINE = "refine", Phase.SOLVING
    DONE = "done", Phase.SOLVING
    OUTPUTS = "outputs", Phase.SOLVING


@dataclass(frozen=True)
class RunEvent:
    """One thing that happened in a run; ``seq`` counts from 1 within the run. ``stage`` is
    set for ``stage`` and ``progress`` events (its value is also ``data["stage"]``)."""

    seq: int
    kind: str
    message: str
    data: dict[str, Any] = field(default_factory=dict)
    time_utc: str = ""
    stage: Stage | None = None

    def fields(self) -> dict[str, Any]:
        """``data`` with the ``message``: the event as an event stream sends it."""
        return self.data | {"message": self.message}

    def as_dict(self) -> dict[str, Any]:
        """The event as a JSON object."""
        return {"seq": self.seq, "kind": self.kind, "message": self.message, "data": self.data,
                "time_utc": self.time_utc}


def _plain(value: Any) -> Any:
    """Numpy values, enums and non-finite floats made JSON-ready (NaN and inf become null)."""
    if isinstance(value, StrEnum):
        return value.value
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return _plain(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


def scan_picture(averaged: AveragedScan, centre: RodCentre | None, radius_m: float) -> dict[str, Any]:
    """The averaged scan, the rod's beams and the fitted circle, as ``scan`` event data."""
    angles = np.asarray(averaged.angles_rad, dtype=float)
    increment = float(angles[1] - angles[0]) if angles.size > 1 else 0.0
    circle = None
    if centre is not None:
        fitted = centre.quality.estimated_radius_m
        circle = {"centre_uv_m": centre.centre_uv_m, "radius_m": fitted if fitted is not None else radius_m}
    return {
        "angle_min_rad": float(angles[0]) if angles.size else 0.0,
        "angle_increment_rad": increment,
        "ranges_m": np.round(np.asarray(averaged.ranges_m, dtype=float), 4),
        "rod_beams": centre.beam_indices if centre is not None else [],
        "circle": circle,
        "rod_radius_m": radius_m,
    }


class EventSink:
    """Numbers events and hands them to one callback; a failing consumer is logged, never
    allowed to stop the arm's run."""

    def __init__(self, callback: EventCallback | None) -> None:
        self._callback = callback
        self._seq = itertools.count(1)
        self._lock = threading.Lock()

    def emit(self, kind: str, message: str, **data: Any) -> None:
        """Send one event (a ``stage`` in ``data`` must be a ``Stage`` or its value)."""
        if self._callback is None:
            return
        stage = Stage(data["stage"]) if "stage" in data else None
        with self._lock:
            event = RunEvent(
                next(self._seq), kind, message, _plain(data), datetime.now(UTC).isoformat(), stage
            )
        try:
            self._callback(event)
        except Exception:
            logger.exception("an event consumer failed on %s", kind)

    def progress_listener(self, rod_radius_m: float) -> Callable[[Progress], None]:
        """The sequencer's progress callback: each step becomes a ``progress`` event, and a
        centre or skip also its own event (with the scan picture where there is one)."""

        def listen(step: Progress) -> None:
            self.emit(
                "progress",
                step.message,
                stage=step.stage,
                waypoint=step.waypoint,
                waypoint_count=step.waypoint_count,
                completed=step.completed,
                scans_averaged=step.scans_averaged,
                time_left_s=step.time_left_s,
            )
            if step.averaged is not None:
                picture = scan_picture(step.averaged, step.centre, rod_radius_m)
                message = f"averaged scan of waypoint {step.waypoint}"
                self.emit("scan", message, waypoint=step.waypoint, **picture)
            if step.stage == "centre" and step.centre is not None:
                self.emit(
                    "centre",
                    step.message,
                    waypoint=step.waypoint,
                    centre_uv_m=step.centre.centre_uv_m,
                    covariance_uv_m2=step.centre.covariance_uv_m2,
                    warnings=list(step.centre.warnings),
                    scans=step.scans_averaged,
                    **({} if step.expected_uv_m is None else {"expected_uv_m": step.expected_uv_m}),
                )
            elif step.stage == "skip":
                self.emit("skip", step.message, waypoint=step.waypoint, reason=step.reason)

        return listen
