"""Solve a recorded run again, offline: ``lasercal solve session.mcap``.

A replay never guesses. The recording holds the job, every scan and the ``observation``
events of the live run; every waypoint's averaged scan and the background are rebuilt
from the recorded scans by the rule the live run used (``lasercal_hw.run.resume``), every
centre is extracted again from them as the live run did, and the result is solved by the
same two-pass function (``solve_two_pass``), so the replay reproduces the live result.
Where a centre cannot be re-extracted (its scans are missing, no rod is found, or the rod
found is not where the live run saw it) the replay says so per waypoint and drops the
waypoint, unless ``use_recorded_centres`` keeps the centre the live run recorded.

A cell job's recording also holds its watchers' scans and centres (``run/watchers``):
``replay_shared_centres`` computes those centres again from their scans with the live
watcher's own function, and says which it could not and why (docs/cell.md); given the
watchers' solved runs, it then fits each again as their second pass.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from lasercal_hw.calibration.consensus import CONSENSUS_WAYPOINTS, provisional_pose
from lasercal_hw.config import JobConfig, NominalPose, with_overrides
from lasercal_hw.errors import CalibrationError, ConfigError
from lasercal_hw.models import FloatArray, LaserScan, RodLine
from lasercal_hw.run.records import WaypointMeasurement
from lasercal_hw.run.resume import (
    RECORDING_DOC,
    check_observation_events,
    recorded_background,
    recorded_centre,
    recorded_job,
    recorded_turn_note,
    window_average,
)
from lasercal_hw.run.two_pass import TwoPassSolution, predict_rod, solve_two_pass
from lasercal_hw.run.watchers import (
    SHARED_OBSERVATION,
    SolvedWatcher,
    as_first_pass,
    predicted_crossing,
    second_pass_centre,
    watcher_centre,
)
from lasercal_hw.scan.average import AveragedScan
from lasercal_hw.scan.extraction import RodCentre, RodNotFoundError, find_rod_centre
from lasercal_hw.session.reader import SessionRecording, read_session

logger = logging.getLogger(__name__)

#: A re-extracted centre further than this from the recorded one (and beyond
#: ``AGREEMENT_SIGMAS`` of its covariance) is not the rod the live run saw.
AGREEMENT_M = 0.005
AGREEMENT_SIGMAS = 5.0


@dataclass(frozen=True)
class RecordingSolution:
    """The two-pass solution of a recording, with what it was computed from."""

    job: JobConfig
    solution: TwoPassSolution
    skipped: dict[int, str]
    truncated: bool
    messages: list[str]
    #: The pose the live run commanded at each waypoint index, as recorded (the meta's and every
    #: later design's, ``recorded_job``); None where the recording does not hold a pose for every
    #: waypoint it measured or skipped (never made up).
    waypoints: FloatArray | None = None


def solve_recording(
    path: str | Path, *, use_recorded_centres: bool = False, job_overrides: dict[str, Any] | None = None,
    scanner: str | None = None,
) -> RecordingSolution:
    """Re-extract and re-solve a ``session.mcap`` written by ``lasercal run`` (of a cell job's
    one recording, the run of ``scanner``: ``SessionRecording.for_scanner``).

    ``job_overrides`` changes the recorded job (``{"rod.estimate_axis": True}``).
    Raises ``ConfigError`` (one line) for a recording that lacks what a replay needs and
    ``CalibrationError`` when no waypoint can be re-extracted."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"recording {str(path)!r} does not exist; pass the session.mcap of a run")
    recording = read_session(path).for_scanner(scanner)
    job, commanded = recorded_job(recording)
    if job_overrides:
        job = with_overrides(job, job_overrides, "command line")
    events = check_observation_events(recording)
    if not recording.scans:
        raise ConfigError(
            f"{path} holds no usable scans (a /scan message with its /lasercal/scan_info companion); the "
            f"centres cannot be re-extracted ({RECORDING_DOC})"
        )
    background = _background(recording)
    measurements, messages, unscanned = _reextract(events, recording, job, background, use_recorded_centres)
    for message in messages:
        logger.warning("%s", message)
    if not measurements:
        raise CalibrationError(_nothing_to_solve(recording, messages, scanned=len(messages) - unscanned))
    if recording.truncated:
        logger.warning("%s was not closed (%s); solving what it holds", path, recording.truncation_reason)
    observed = {int(event["index"]) for event in events}
    skipped = {
        int(event["index"]): str(event["reason"])
        for event in recording.events_of("waypoint_skipped")
        if int(event["index"]) not in observed
    }
    last = max(observed | set(skipped), default=-1)
    if last >= len(commanded):
        messages.append(
            f"the recording holds the commanded poses of waypoints 0-{len(commanded) - 1} only, not of "
            f"waypoint {last}: run.waypoints is left out"
        )
    solution = solve_two_pass(measurements, job, background)
    turn_note = recorded_turn_note(recording)
    if turn_note is not None:  # the spin is not fitted again: its note is the live run's, named so
        recorded = f"as the live run recorded it, not fitted again: {turn_note}"
        solution = replace(solution, refinement=f"{recorded}; {solution.refinement}")
    return RecordingSolution(
        job=job,
        solution=solution,
        skipped=dict(sorted(skipped.items())),
        truncated=recording.truncated,
        messages=messages,
        waypoints=commanded if last < len(commanded) else None,
    )


def _background(recording: SessionRecording) -> AveragedScan | None:
    """The live run's background, or None when it took none; refuses one whose scans are gone."""
    background = recorded_background(recording)
    if isinstance(background, str):
        raise ConfigError(
            f"{recording.path}: the scans of the background are not all in the recording ({background}); "
            "without them the centres cannot be extracted as the live run did"
        )
    return background


def _nothing_to_solve(recording: SessionRecording, messages: list[str], scanned: int) -> str:
    """Why a recording gave no waypoint to solve and what to do instead, in one line;
    ``scanned`` waypoints had their scans (--use-recorded-centres would keep their centres)."""
    path = recording.path
    folder = path.parent if recording.view_of is None else path.parent / recording.view_of
    found = folder / "observations.csv"
    if found.is_file():
        instead = f"solve the centres the live run wrote instead: lasercal solve {found}"
    else:
        instead = "it cannot give a calibration; measure again with lasercal run"
    if scanned:
        instead += ", or keep the centres the live run recorded with --use-recorded-centres"
    return (
        f"{path}: none of its {len(messages)} waypoints could be re-extracted from the recorded scans "
        f"(first: {messages[0].removesuffix('; dropped')}); a replay does not guess them, so {instead}"
    )


def _reextract(
    events: list[dict[str, Any]],
    recording: SessionRecording,
    job: JobConfig,
    background: AveragedScan | None,
    use_recorded: bool,
) -> tuple[list[WaypointMeasurement], list[str], int]:
    """Every observation's centre extracted again from its scans, as the live run did; a
    message per waypoint where that fails (the waypoint dropped, or its recorded centre kept);
    how many of those failed because their scans are not all in the recording."""
    rod = job.rod.rod_line()
    expectation = _Expected(job.scanner.nominal, rod)
    latest = {int(event["index"]): event for event in events}
    measurements, messages, unscanned = [], [], 0
    for index in sorted(latest):
        event = latest[index]
        tcp_pose = np.asarray(event["tcp_pose"], dtype=float)
        recorded = recorded_centre(event)
        averaged = window_average(event, recording.scans)
        problem = None
        if isinstance(averaged, str):
            problem, unscanned = averaged, unscanned + 1
        else:
            expected = expectation.at(tcp_pose, measurements)
            try:
                centre = find_rod_centre(
                    averaged, radius_m=rod.radius_m, background=background, expected_uv_m=expected,
                    fluted=rod.fluted,
                )
            except RodNotFoundError as exc:
                problem = f"no rod found in its scans ({exc})"
            else:
                problem = _disagreement(centre.centre_uv_m, recorded.centre_uv_m, recorded.covariance_uv_m2)
                if problem is None:
                    measurements.append(WaypointMeasurement(index, tcp_pose, averaged, centre))
                    continue
        if use_recorded and not isinstance(averaged, str):
            messages.append(
                f"waypoint {index}: {problem}; the recorded centre is used (--use-recorded-centres)"
            )
            measurements.append(WaypointMeasurement(index, tcp_pose, averaged, recorded))
        else:
            messages.append(f"waypoint {index}: {problem}; dropped")
    return measurements, messages, unscanned


class _Expected:
    """Where the live run expected the rod: from the nominal mounting, else from the consensus
    of the first waypoints measured (``calibration.consensus``), as the sequencer does."""

    def __init__(self, nominal: NominalPose | None, rod: RodLine) -> None:
        self._pose = None if nominal is None else nominal.matrix()
        self._from_consensus = nominal is None
        self._rod = rod

    def at(self, tcp_pose: FloatArray, measured: list[WaypointMeasurement]) -> FloatArray | None:
        if self._from_consensus and self._pose is None and len(measured) >= CONSENSUS_WAYPOINTS:
            first = [m.observation() for m in measured[:CONSENSUS_WAYPOINTS]]
            self._pose = provisional_pose(first, self._rod)
            self._from_consensus = False  # one try, as the live run's first waypoints do not change
        return None if self._pose is None else predict_rod(self._pose, tcp_pose, self._rod).expected_uv_m


def _disagreement(found: np.ndarray, recorded: np.ndarray, covariance: np.ndarray) -> str | None:
    """Why a re-extracted centre is not the one the live run recorded (None when it is)."""
    delta = np.asarray(found, dtype=float) - np.asarray(recorded, dtype=float)
    distance = float(np.linalg.norm(delta))
    sigmas = float(np.sqrt(delta @ np.linalg.solve(covariance, delta))) if distance > 0 else 0.0
    if distance <= AGREEMENT_M or sigmas <= AGREEMENT_SIGMAS:
        return None
    return (
        f"the rod found in its scans at ({found[0]:.4f}, {found[1]:.4f}) m is {distance * 1e3:.1f} mm "
        f"({sigmas:.0f} sigma) from the recorded centre ({recorded[0]:.4f}, {recorded[1]:.4f}) m: the scans "
        "do not show what the live run saw"
    )


#: A watcher's centre at one waypoint: ``(tcp_pose, centre_uv_m, covariance_uv_m2)``.
SharedEntry = tuple[FloatArray, FloatArray, FloatArray]


@dataclass
class ReplayedSharedCentres:
    """The centres a run's watchers measured, by watcher and waypoint, each computed again from
    its recorded scans (``recomputed``) or, in a recording written before the watchers' scans
    were, the recorded one; ``notes``: by watcher, every centre reused or left out, and why."""

    centres: dict[str, dict[int, SharedEntry]] = field(default_factory=dict)
    recomputed: dict[str, int] = field(default_factory=dict)
    notes: dict[str, list[str]] = field(default_factory=dict)
    #: By watcher, how many of its recomputed centres got their second pass.
    second_pass: dict[str, int] = field(default_factory=dict)


def replay_shared_centres(
    recording: SessionRecording, rod: RodLine, nominals: Mapping[str, NominalPose | None],
    solved: Mapping[str, SolvedWatcher] | None = None,
) -> ReplayedSharedCentres:
    """Every ``shared_observation`` of ``recording`` (the last at a waypoint wins) computed again
    as the live watcher did (``run/watchers.watcher_centre``): the scans of its window averaged,
    the rod picked where the watcher's nominal pose (``nominals``, the cell job's) puts it. A
    centre whose scans are incomplete, where no rod is found, or where the rod found is not the
    recorded one is left out; a recording whose events carry no scan window (written before
    watchers' scans were recorded) has its recorded centres reused. Each is named in ``notes``.
    A watcher in ``solved`` (its own run solved) has each centre it found again fitted as its
    second pass (``run/watchers.second_pass_centre``); a centre without one (reused, or its
    second pass found no rod) carries the watcher's first-pass scatter in its covariance."""
    latest = {(str(e["scanner"]), int(e["index"])): e for e in recording.events_of(SHARED_OBSERVATION)}
    replayed = ReplayedSharedCentres()
    reused: dict[str, list[int]] = {}
    solved = solved or {}
    for (name, index), event in sorted(latest.items()):
        tcp_pose = np.asarray(event["tcp_pose"], dtype=float)
        recorded = recorded_centre(event)
        if "window_start_s" not in event or "window_end_s" not in event:
            reused.setdefault(name, []).append(index)
            if name in solved:
                recorded = as_first_pass(recorded, solved[name])
            replayed.centres.setdefault(name, {})[index] = (
                tcp_pose, recorded.centre_uv_m, recorded.covariance_uv_m2
            )
            continue
        scans = recording.scans_by_scanner.get(name, [])
        found = _shared_centre_again(event, scans, nominals.get(name), rod)
        if isinstance(found, str):
            replayed.notes.setdefault(name, []).append(
                f"{recording.path}: {name}'s centre at waypoint {index}: {found}; left out"
            )
            continue
        centre, averaged = found
        replayed.recomputed[name] = replayed.recomputed.get(name, 0) + 1
        if name in solved:
            centre, second = second_pass_centre(averaged, tcp_pose, centre, solved[name])
            replayed.second_pass[name] = replayed.second_pass.get(name, 0) + int(second)
        replayed.centres.setdefault(name, {})[index] = (tcp_pose, centre.centre_uv_m, centre.covariance_uv_m2)
    for name, indices in reused.items():
        replayed.notes.setdefault(name, []).append(
            f"{recording.path}: {name}'s centres at waypoints {', '.join(map(str, indices))} are reused as "
            "recorded: the recording holds no scans of them (written before a watcher's scans were "
            "recorded), so they cannot be computed again"
        )
    return replayed


def _shared_centre_again(
    event: dict[str, Any], scans: list[LaserScan], nominal: NominalPose | None, rod: RodLine
) -> tuple[RodCentre, AveragedScan] | str:
    """A watcher's centre computed again from its recorded scans, with their average, or why it
    cannot be."""
    if nominal is None:
        return "the job gives its scanner no nominal pose to pick the rod with"
    averaged = window_average(event, scans)
    if isinstance(averaged, str):
        return averaged
    expected = predicted_crossing(nominal.matrix(), np.asarray(event["tcp_pose"], dtype=float), rod)
    if expected is None:
        return "its nominal pose puts the rod off its plane"
    try:
        centre = watcher_centre(averaged, expected, rod)
    except RodNotFoundError as exc:
        return f"no rod found in its scans ({exc})"
    recorded = recorded_centre(event)
    problem = _disagreement(centre.centre_uv_m, recorded.centre_uv_m, recorded.covariance_uv_m2)
    return (centre, averaged) if problem is None else problem
