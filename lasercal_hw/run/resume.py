"""Recover what an interrupted run already measured from its ``session.mcap``.

Each ``observation`` event carries the TCP pose, the rod centre and the dwell window
(device-time stamps); the averaged scan is rebuilt from the recorded scans of that window
by the same rule the live run used, so the second extraction pass treats old and new
waypoints alike. ``waypoint_skipped`` events are kept as skipped; the background is
rebuilt from its window. A waypoint whose scans are missing is simply measured again.
"""

from __future__ import annotations

import logging
from enum import StrEnum
from typing import Any

import numpy as np

from lasercal_hw.config import JobConfig, job_from_mapping
from lasercal_hw.errors import ConfigError
from lasercal_hw.models import FloatArray, LaserScan
from lasercal_hw.run.records import ResumeState, SkippedWaypoint, WaypointMeasurement
from lasercal_hw.scan.average import AveragedScan, average_scans
from lasercal_hw.scan.extraction import RodCentre, RodQuality
from lasercal_hw.session.reader import SessionRecording

logger = logging.getLogger(__name__)

META_JOB = "job"
META_WAYPOINTS = "waypoints"
#: Recording meta: the procedure that wrote it (``Procedure``).
META_PROCEDURE = "procedure"
#: Event of an adaptive run's design (``lasercal_hw.run.adaptive``): its waypoints extend
#: the recorded ones from ``first_index`` on.
DESIGN_EVENT = "trajectory_design"


class Procedure(StrEnum):
    """What wrote a recording: only a calibration's is resumed; a verify is started anew."""

    CALIBRATION = "calibration"
    VERIFY = "verify"

    @property
    def resumable(self) -> bool:
        """Whether a run of this procedure continues from its recording."""
        return self is Procedure.CALIBRATION


def recorded_procedure(recording: SessionRecording) -> Procedure:
    """The procedure that wrote ``recording``; one made before the meta said (2026-11-29) is a
    calibration's (a verify's then was not told apart)."""
    value = recording.meta.get(META_PROCEDURE, Procedure.CALIBRATION.value)
    try:
        return Procedure(value)
    except ValueError:
        raise ConfigError(
            f"{recording.path} was written by a procedure this lasercal does not know ({value!r}): "
            "read it with the lasercal that wrote it"
        ) from None


def recorded_job(recording: SessionRecording) -> tuple[JobConfig, FloatArray]:
    """The job and the waypoints an earlier run recorded: its meta's, then those of any
    later design of an adaptive run."""
    meta = recording.meta
    if META_JOB not in meta or META_WAYPOINTS not in meta:
        raise ConfigError(
            f"{recording.path} has no recorded job or waypoints; it was not written by `lasercal run` "
            "and cannot be resumed"
        )
    job = job_from_mapping(meta[META_JOB], f"{recording.path} (recorded job)")
    waypoints = np.asarray(meta[META_WAYPOINTS], dtype=float).reshape(-1, 6)
    for event in recording.events_of(DESIGN_EVENT):  # an adaptive run's later designs
        designed = np.asarray(event["waypoints"], dtype=float).reshape(-1, 6)
        if int(event["first_index"]) == len(waypoints):
            waypoints = np.vstack([waypoints, designed])
    return job, waypoints


def recorded_turn_note(recording: SessionRecording) -> str | None:
    """What a spun run (``trajectory.flute_phase_deg``) said of its flute phase and the turn it
    gave its waypoints, as recorded with them; None for any other run."""
    for event in recording.events_of(DESIGN_EVENT):
        if "tool_turn_shift_deg" in event:
            return str(event["notes"][0])
    return None


#: Where the docs say what a recording must hold to be replayed (named in the errors).
RECORDING_DOC = 'docs/recorder.md, "What a recording must hold to be replayed"'

#: What an ``observation`` event must hold for the waypoint to be rebuilt from the recording.
OBSERVATION_FIELDS = (
    "index",
    "tcp_pose",
    "centre_uv_m",
    "covariance_uv_m2",
    "quality",
    "scans",
    "window_start_s",
    "window_end_s",
)


def check_observation_events(recording: SessionRecording) -> list[dict[str, Any]]:
    """The recording's ``observation`` events, or a one-line ``ConfigError`` naming what is missing."""
    events = recording.events_of("observation")
    if not events:
        raise ConfigError(
            f"{recording.path} holds no 'observation' events (/lasercal/event): it does not say which scans "
            f"each waypoint averaged; record with `lasercal run` ({RECORDING_DOC})"
        )
    for event in events:
        missing = [name for name in OBSERVATION_FIELDS if name not in event]
        if missing:
            which = f"waypoint {event['index']}" if "index" in event else "an observation event"
            raise ConfigError(
                f"{recording.path}: {which} lacks {', '.join(missing)} in its 'observation' event; the "
                f"recording is incomplete or from an older version ({RECORDING_DOC})"
            )
    return events


def _window_scans(scans: list[LaserScan], start_s: float, end_s: float) -> list[LaserScan]:
    return [scan for scan in scans if start_s <= scan.device_time_s < end_s]


def window_average(event: dict[str, Any], scans: list[LaserScan]) -> AveragedScan | str:
    """The averaged scan of an observation's dwell window, or why it cannot be rebuilt."""
    window = _window_scans(scans, float(event["window_start_s"]), float(event["window_end_s"]))
    expected = int(event["scans"])
    if len(window) != expected or not window:
        return f"{len(window)} scans recorded in its dwell window, the live run averaged {expected}"
    return average_scans(window)


def recorded_centre(event: dict[str, Any]) -> RodCentre:
    """The centre the live run extracted, as its ``observation`` event recorded it."""
    return RodCentre(
        centre_uv_m=np.asarray(event["centre_uv_m"], dtype=float),
        covariance_uv_m2=np.asarray(event["covariance_uv_m2"], dtype=float),
        quality=RodQuality(**event["quality"]),
    )


def _measurement(event: dict[str, Any], scans: list[LaserScan]) -> WaypointMeasurement | None:
    index = int(event["index"])
    averaged = window_average(event, scans)
    if isinstance(averaged, str):
        logger.warning("waypoint %d: %s; measuring again", index, averaged)
        return None
    return WaypointMeasurement(
        index, np.asarray(event["tcp_pose"], dtype=float), averaged, recorded_centre(event)
    )


def recorded_background(recording: SessionRecording) -> AveragedScan | str | None:
    """The background rebuilt from its recorded scans, why it cannot be (a string), or None
    when the run recorded none."""
    events = recording.events_of("background")
    if not events:
        return None
    event = events[-1]
    window = [
        scan
        for scan in recording.scans
        if float(event["window_start_s"]) <= scan.device_time_s <= float(event["window_end_s"])
    ][: int(event["scans"])]
    if len(window) != int(event["scans"]) or not window:
        return f"{len(window)} scans recorded, {event['scans']} were used"
    return average_scans(window)


def _background(recording: SessionRecording) -> AveragedScan | None:
    background = recorded_background(recording)
    if isinstance(background, str):
        logger.warning("background: %s; measuring again", background)
        return None
    return background


def resume_state(recording: SessionRecording) -> ResumeState:
    """The measured and skipped waypoints of an interrupted run, its background and, a spun
    run's, what it said of its turn (``recorded_turn_note``)."""
    observed: dict[int, WaypointMeasurement] = {}
    for event in check_observation_events(recording) if recording.events_of("observation") else []:
        measurement = _measurement(event, recording.scans)
        if measurement is not None:
            observed[measurement.index] = measurement
    skipped = {
        int(event["index"]): SkippedWaypoint(int(event["index"]), str(event["reason"]))
        for event in recording.events_of("waypoint_skipped")
        if int(event["index"]) not in observed
    }
    logger.info("resuming %s: %d waypoints measured, %d skipped", recording.path, len(observed), len(skipped))
    return ResumeState(
        measurements=[observed[i] for i in sorted(observed)],
        skipped=[skipped[i] for i in sorted(skipped)],
        background=_background(recording),
        turn_note=recorded_turn_note(recording),
    )
