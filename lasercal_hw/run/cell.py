"""One job, every scanner of a cell: ``calibrate_cell(CellRunRequest) -> CellReport``.

A job with ``[scanners.NAME]`` tables calibrates each named scanner in turn, each a whole
run of ``engine.calibrate`` on the scanner's own one-scanner job (``JobConfig.for_scanner``:
its waypoints, rod and gates) in the folder ``<out>/<NAME>/`` (its ``result.json`` and
exports), all recording into the job's one ``<out>/session.mcap`` (each scanner's part named
by it: docs/recorder.md). ``<out>/cell.json`` holds the job and the scanners' order from
the start, and at the end every scanner's result and every scanner-to-scanner transform
with its covariance (``calibration/pairs.py``). Resuming the cell folder keeps every
scanner that has a ``result.json``, continues the one whose run stopped at the waypoint
where it stopped, and runs the rest (docs/cell.md). A cell folder written before the one
recording (one ``<out>/<NAME>/session.mcap`` per scanner) resumes and reads in its layout.
"""

from __future__ import annotations

import contextlib
import json
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from lasercal_hw import __version__
from lasercal_hw.calibration.agreement import SharedCentre, agreement_test
from lasercal_hw.calibration.model import plane_crossing, range_error_m, rod_lines_in_base
from lasercal_hw.calibration.observations import read_observations_csv
from lasercal_hw.calibration.pairs import error_in_std, joint_relative_pose, relative_pose
from lasercal_hw.calibration.result import CalibrationResult, RangeOffset
from lasercal_hw.config import JobConfig, ScannerConfig, job_from_mapping, with_overrides
from lasercal_hw.errors import ConfigError, LasercalError
from lasercal_hw.models import FloatArray, RodLine
from lasercal_hw.run.cancel import CancelToken
from lasercal_hw.run.dry_run_cell import DryRunCell, start_fake_cell
from lasercal_hw.run.engine import JobRecording, MotionPlan, RunEvent, RunReport, RunRequest, calibrate
from lasercal_hw.run.events import EventSink
from lasercal_hw.run.outputs import OBSERVATIONS_FILE, RESULT_FILE, SESSION_FILE, read_result_file, write_text
from lasercal_hw.run.replay import ReplayedSharedCentres, replay_shared_centres
from lasercal_hw.run.resume import recorded_background
from lasercal_hw.run.timing import visit_time_s
from lasercal_hw.run.watchers import SolvedWatcher
from lasercal_hw.run.waypoints import job_waypoints
from lasercal_hw.session.format import META_JOB_SCANNERS, scan_topics
from lasercal_hw.session.reader import SessionRecording, read_session
from lasercal_hw.session.recorder import SessionRecorder

CELL_FILE = "cell.json"
#: ``cell.json``'s key naming the job's one recording (in the cell folder); a cell folder
#: without it was written with one recording per scanner (``<NAME>/session.mcap``).
CELL_RECORDING = "recording"
#: The event a cell job sends once a scanner has its ``result.json`` (run now, or kept from
#: before a resume): ``scanner``, ``folder``, ``passed``, ``kept``. A daemon files the scanner's
#: calibration on it, so a job killed later keeps it in the history.
SCANNER_RESULT = "scanner_result"
#: The event a cell job sends for each pair once every scanner is solved and ``cell.json`` is
#: written: ``from``, ``to`` and the pair's ``agreement`` as ``cell.json`` holds it, whose
#: ``centres`` are the centres the test compared (a watcher's after its second pass).
PAIR_AGREEMENT = "pair_agreement"


@dataclass(frozen=True)
class CellRunRequest:
    """What to run: the cell's job, its folder, which scanners (None: all, in the job's
    order), where the robot is, and a dry run's scene (with a ``[scanners.NAME]`` table for
    each scanner). ``resume``: a cell folder (or its ``cell.json``) to continue."""

    job: JobConfig
    out_dir: Path
    scanners: tuple[str, ...] | None = None
    robot_host: str | None = None
    dry_run: bool = False
    scene: Path | None = None
    resume: Path | None = None
    title: str = "lasercal run"


@dataclass(frozen=True)
class ScannerOutcome:
    """One scanner's result in the cell: its ``result.json`` and, when it ran in this call,
    the run's report."""

    name: str
    result_path: Path
    passed: bool
    T_base_laser: list[list[float]]
    covariance: list[list[float]]
    ground_truth: list[list[float]] | None
    report: RunReport | None
    #: The rod line its solve estimated (its job's nominal one where it estimated none): what
    #: its second pass fits a watcher's centres with (``SolvedWatcher.rod``).
    rod: RodLine
    #: The range error curve it estimated (None: none), the part of it its solved centres
    #: already have taken out (the second pass's offset: ``range_offset_applied_m`` of
    #: ``result.json``'s solver options), and its solve's reduced chi-square.
    range_offset: RangeOffset | None = None
    range_offset_applied_m: float = 0.0
    reduced_chi_square: float = 1.0


@dataclass(frozen=True)
class CellReport:
    """A finished cell job: every scanner's outcome and the scanner-to-scanner transforms."""

    out_dir: Path
    scanners: dict[str, ScannerOutcome]
    pairs: list[dict[str, Any]]

    @property
    def passed(self) -> bool:
        """True when every scanner passed its gates."""
        return all(outcome.passed for outcome in self.scanners.values())

    def document(self) -> dict[str, Any]:
        """``cell.json``'s results (what ``lasercal run --json`` prints for a cell job)."""
        scanners: dict[str, Any] = {}
        for name, outcome in self.scanners.items():
            entry: dict[str, Any] = {
                "passed": outcome.passed,
                "result": str(outcome.result_path),
                "T_base_laser": outcome.T_base_laser,
                "covariance": outcome.covariance,
            }
            if outcome.ground_truth is not None:
                entry["ground_truth_error"] = error_in_std(
                    np.asarray(outcome.T_base_laser), np.asarray(outcome.covariance),
                    np.asarray(outcome.ground_truth),
                )
            scanners[name] = entry
        return {"passed": self.passed, "scanners": scanners, "pairs": self.pairs}


def names_a_cell(path: Path) -> bool:
    """Whether a ``--resume`` path names a cell job: its folder, its ``cell.json``, or its one
    recording (``<out>/session.mcap`` beside ``cell.json``)."""
    return path.is_dir() or path.name == CELL_FILE or (path.parent / CELL_FILE).is_file()


def cell_folder(path: Path) -> Path:
    """The cell folder a ``--resume`` path names (the folder, its ``cell.json`` or its one
    recording)."""
    folder = path.parent if path.name == CELL_FILE or path.is_file() else path
    if not (folder / CELL_FILE).is_file():
        raise ConfigError(f"{folder} holds no {CELL_FILE}: pass the folder of a cell job to resume")
    return folder


def _read_cell_file(folder: Path) -> dict[str, Any]:
    try:
        document = json.loads((folder / CELL_FILE).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"cannot read {folder / CELL_FILE}: {exc}") from None
    if not isinstance(document, dict) or not isinstance(document.get("job"), dict):
        raise ConfigError(f"{folder / CELL_FILE} is not a lasercal cell job (no job table)")
    return document


def cell_scanners(request: CellRunRequest) -> tuple[JobConfig, list[str]]:
    """The job and the scanners ``request`` runs: a new job's, or a resumed one's (its
    ``cell.json``: the recorded job and scanners decide, at the scanner URLs ``request.job``
    names now: ``_at_current_urls``)."""
    if request.resume is None:
        return request.job, list(request.scanners or request.job.scanner_names())
    folder = cell_folder(request.resume)
    document = _read_cell_file(folder)
    job = job_from_mapping(document["job"], str(folder / CELL_FILE))
    return _at_current_urls(job, request.job), list(document.get("scanners_run", job.scanner_names()))


def _at_current_urls(recorded: JobConfig, current: JobConfig) -> JobConfig:
    """The recorded job with each of its scanners at the URL ``current`` gives the scanner of the
    same name, as the robot is at the request's host: a daemon resumes at its devices as they are
    now (a restarted ``--dry-run`` daemon's fake cell listens elsewhere)."""
    urls = {
        f"scanners.{name}.url": current.scanners[name].url
        for name in recorded.scanners
        if name in current.scanners and current.scanners[name].url != recorded.scanners[name].url
    }
    return with_overrides(recorded, urls, source="the scanner URLs given now") if urls else recorded


def _start(request: CellRunRequest) -> tuple[CellRunRequest, JobConfig, list[str]]:
    """The request, job and scanners of a new cell job (``cell.json`` written) or of the
    resumed one (``cell.json`` read: the recorded job and scanners decide)."""
    job, names = cell_scanners(request)
    if request.resume is not None:
        folder = cell_folder(request.resume)
        recorded = dict(_read_cell_file(folder).get("request", {}))
        scene = request.scene or (Path(recorded["scene"]) if recorded.get("scene") else None)
        request = replace(request, out_dir=folder, dry_run=bool(recorded.get("dry_run")), scene=scene)
        return request, job, names
    folder = request.out_dir
    if (folder / CELL_FILE).exists():
        raise ConfigError(f"{folder / CELL_FILE} already exists: choose another output folder, or resume it")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"cannot create the output folder {folder}: {exc.strerror or exc}") from exc
    document = {
        "job": request.job.model_dump(mode="json"),
        "scanners_run": names,
        CELL_RECORDING: SESSION_FILE,
        "request": {
            "dry_run": request.dry_run, "scene": str(request.scene.resolve()) if request.scene else None,
        },
    }
    write_text(folder / CELL_FILE, json.dumps(document, indent=2) + "\n")
    return request, request.job, names


def calibrate_cell(
    request: CellRunRequest,
    *,
    on_event: Callable[[RunEvent], None] | None = None,
    cancel: CancelToken | None = None,
    confirm: Callable[[MotionPlan], None] | None = None,
) -> CellReport:
    """Calibrate the cell's scanners one after the other (see the module docstring); raises
    what stopped it, the scanners finished before keeping their results."""
    for name in request.scanners or ():
        request.job.for_scanner(name)  # a ConfigError naming the job's scanners when it has none such
    if request.dry_run and request.scene is None and request.resume is None:
        raise ConfigError(
            "a dry run of a cell job needs --scene: a scene file with a [scanners.NAME] table for each "
            "scanner (fakes/scenes/two_scanners.toml is one)"
        )
    request, job, names = _start(request)
    on_event = _resuming_the_cell(on_event, request.out_dir)
    sink = EventSink(on_event)
    cancel = cancel or CancelToken()
    outcomes: dict[str, ScannerOutcome] = {}
    pending = [name for name in names if not (request.out_dir / name / RESULT_FILE).is_file()]
    with contextlib.ExitStack() as stack:
        fake_cell = None
        if request.dry_run and pending:
            assert request.scene is not None, "a cell job's dry run has a scene (checked above, or recorded)"
            fake_cell = start_fake_cell(request.scene, stack, sink, cancel)  # one world for every scanner
        recording = None
        if pending and _one_recording(request.out_dir):
            recording = _open_job_recording(request.out_dir, names, job)
            stack.callback(recording.recorder.close)
        planned_s = {name: _planned_visit_s(job.for_scanner(name)) for name in pending}
        for position, name in enumerate(names):
            watch = tuple(
                (other, job.for_scanner(other).scanner) for other in names
                if other != name and job.for_scanner(other).scanner.nominal is not None
            )
            later_s = sum(planned_s.get(other, 0.0) for other in names[position + 1 :])
            outcomes[name] = _scanner(
                request, job, name, watch, fake_cell, recording, sink, on_event, cancel, confirm, later_s
            )
    cell = CellReport(request.out_dir, outcomes, _pairs(outcomes, request.out_dir, job))
    document = _read_cell_file(request.out_dir) | cell.document()
    write_text(request.out_dir / CELL_FILE, json.dumps(document, indent=2, allow_nan=False) + "\n")
    for pair in cell.pairs:
        agreement, a, b = pair["agreement"], pair["from"], pair["to"]
        sink.emit(PAIR_AGREEMENT, f"{a} and {b}: {agreement['verdict']} ({agreement['reason']})",
                  **{"from": a, "to": b} | agreement)
    return cell


def _one_recording(folder: Path) -> bool:
    """Whether the cell folder records into one ``session.mcap`` (False: a folder written before,
    one recording per scanner)."""
    return _read_cell_file(folder).get(CELL_RECORDING) is not None


def _open_job_recording(folder: Path, names: list[str], job: JobConfig) -> JobRecording:
    """The job's one recording, new or, after a stop, continued (``SessionRecorder.resume``: the
    stopped file kept as ``session.interrupted-<k>.mcap``, every complete message copied); a new
    one starts with each scanner's nominal frame (``/tf_static``, for viewers)."""
    path = folder / SESSION_FILE
    meta = {META_JOB_SCANNERS: names, "software_version": __version__}
    if path.exists():
        recorder = SessionRecorder.resume(path, meta)
        return JobRecording(recorder, recorder.previous)
    recorder = SessionRecorder(path, meta)
    for name in names:
        nominal = job.for_scanner(name).scanner.nominal
        if nominal is not None:
            recorder.write_frame(time.time(), scan_topics(name)[2], nominal.matrix())
    return JobRecording(recorder)


def scanner_recordings(folder: Path, names: list[str]) -> dict[str, SessionRecording]:
    """Each scanner's run as the cell folder recorded it: its part of the job's one recording
    (``SessionRecording.for_scanner``) or, in a folder written before it, its own
    ``<NAME>/session.mcap``; a scanner with no recorded run is left out."""
    if (folder / SESSION_FILE).is_file():
        recording = read_session(folder / SESSION_FILE)
        return {name: recording.for_scanner(name) for name in names if name in recording.scanner_names}
    own = {name: folder / name / SESSION_FILE for name in names}
    return {name: read_session(path) for name, path in own.items() if path.is_file()}


def _scanner(
    request: CellRunRequest,
    job: JobConfig,
    name: str,
    watch: tuple[tuple[str, ScannerConfig], ...],
    fake_cell: DryRunCell | None,
    recording: JobRecording | None,
    sink: EventSink,
    on_event: Callable[[RunEvent], None] | None,
    cancel: CancelToken,
    confirm: Callable[[MotionPlan], None] | None,
    later_s: float,
) -> ScannerOutcome:
    """One scanner's outcome: its run (recorded in the job's ``recording``, or in a folder written
    before it in its own; continued where that holds its run; the scanners of ``watch`` measure
    the rod where they see it: ``run/watchers``; its time left counts ``later_s`` for the scanners
    after it), or its ``result.json`` kept from before a resume; told as a ``scanner_result`` event."""
    folder = request.out_dir / name
    kept = (folder / RESULT_FILE).is_file()
    report = None
    if not kept:
        session = folder / SESSION_FILE
        run = RunRequest(
            job=job.for_scanner(name),
            out_dir=folder,
            robot_host=None if request.dry_run else request.robot_host,
            # where the scanner is now: a resumed run's recording names where it was
            scanner_url=None if request.dry_run else job.for_scanner(name).scanner.url,
            dry_run=request.dry_run,
            scene=request.scene,
            resume=session if recording is None and session.is_file() else None,
            title=f"{request.title}: scanner {name}",
            scanner_name=name,
            fake_cell=fake_cell,
            watch=watch,
            recording=recording,
        )
        on_run_event = events_of_scanner(on_event, name, later_s)
        report = calibrate(run, on_event=on_run_event, cancel=cancel, confirm=confirm)
    outcome = _scanner_outcome(name, folder / RESULT_FILE, report, job.for_scanner(name).rod.rod_line())
    if recording is not None and report is not None:  # its calibrated frame, for viewers of the recording
        recording.recorder.write_frame(time.time(), scan_topics(name)[2], outcome.T_base_laser)
    sink.emit(
        SCANNER_RESULT,
        f"scanner {name}: {'passed' if outcome.passed else 'failed its quality gates'}"
        + (" (kept from before the resume)" if kept else ""),
        scanner=name, folder=str(folder), passed=outcome.passed, kept=kept,
    )
    return outcome


def _resuming_the_cell(
    on_event: Callable[[RunEvent], None] | None, folder: Path
) -> Callable[[RunEvent], None] | None:
    """``on_event`` with a scanner run's ``stopped`` event saying the cell folder is what
    resumes the job (``resume``), beside the scanner's recording (``session``)."""
    if on_event is None:
        return None
    sink = on_event

    def forward(event: RunEvent) -> None:
        if event.kind == "stopped" and "session" in event.data:
            event = replace(event, data=event.data | {"resume": str(folder)})
        sink(event)

    return forward


def events_of_scanner(
    on_event: Callable[[RunEvent], None] | None, name: str, later_s: float = 0.0
) -> Callable[[RunEvent], None] | None:
    """``on_event`` with every event of scanner ``name``'s run naming it (``data["scanner"]``),
    so a page or a live view shows each scanner's scans and centres as its own; a progress
    event's time left is the job's, ``later_s`` of the scanners after this one added."""
    if on_event is None:
        return None
    sink = on_event

    def named(event: RunEvent) -> None:
        data = event.data | {"scanner": name}
        if event.kind == "progress" and data.get("time_left_s") is not None:
            data["time_left_s"] += later_s
        sink(replace(event, data=data))

    return named


def _planned_visit_s(job: JobConfig) -> float:
    """A scanner's visit of its job's waypoints as planned before the arm moves (``run.timing``);
    0 where the UR5 model cannot plan it or the job cannot list them yet. An adaptive job's
    second part and a spun drill's waypoints follow from what the run measures first: not counted."""
    try:
        planned_s = visit_time_s(job, job_waypoints(job))
    except LasercalError:
        return 0.0
    return 0.0 if planned_s is None else planned_s


def _scanner_outcome(name: str, path: Path, report: RunReport | None, nominal_rod: RodLine) -> ScannerOutcome:
    """A scanner's outcome from its ``result.json`` (the one source, run now or before); its rod
    the one the result estimated, ``nominal_rod`` (its job's) where it estimated none."""
    result_file = read_result_file(path)
    return ScannerOutcome(
        name=name,
        result_path=path,
        passed=result_file.passed,
        T_base_laser=result_file.result.T_base_laser,
        covariance=result_file.result.covariance,
        ground_truth=result_file.ground_truth,
        report=report,
        rod=result_file.result.estimated_rod(nominal_rod),
        range_offset=result_file.result.range_offset,
        range_offset_applied_m=applied_range_offset_m(result_file.result),
        reduced_chi_square=result_file.result.reduced_chi_square,
    )


def applied_range_offset_m(result: CalibrationResult) -> float:
    """The range offset a result's second pass took out of its centres before its solve."""
    return float(result.provenance.solver_options.get("range_offset_applied_m", 0.0))


def _pairs(outcomes: dict[str, ScannerOutcome], folder: Path, job: JobConfig) -> list[dict[str, Any]]:
    """Every scanner-to-scanner transform ``T_a_b`` (a before b in the job's order) with its
    covariance, the two poses' agreement where both scanners saw the rod at one waypoint
    (``calibration/agreement``), and against the truth when both have one (a dry run)."""
    recordings = scanner_recordings(folder, list(outcomes))
    runs = {name: _own_run(folder / name, recordings.get(name)) for name in outcomes}
    solved = {name: _solved_watcher(outcomes[name], recordings[name], run)
              for name, run in runs.items() if run is not None}
    recorded = {name: _recorded_centres(recordings.get(name), runs[name], name, job, solved)
                for name in outcomes}
    centres = {name: entry.centres for name, entry in recorded.items()}
    names = list(outcomes)
    pairs = []
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            pair = pair_document(a, b, outcomes, centres, job)
            watched = (recorded[a].replayed, b), (recorded[b].replayed, a)  # b at a's waypoints, a at b's
            pair["agreement"]["watcher_centres"] = {
                "recomputed": sum(run.recomputed.get(other, 0) for run, other in watched),
                "second_pass": sum(run.second_pass.get(other, 0) for run, other in watched),
                "notes": [note for run, other in watched for note in run.notes.get(other, [])],
            }
            pairs.append(pair)
    return pairs


def _transform_document(T_ab: FloatArray, covariance: FloatArray, note: str) -> dict[str, Any]:
    std = np.sqrt(np.diag(covariance))
    return {
        "T_from_to": T_ab.tolist(),
        "covariance": covariance.tolist(),
        "covariance_note": note,
        "std_translation_mm": (1000.0 * std[:3]).tolist(),
        "std_rotation_deg": np.degrees(std[3:]).tolist(),
    }


def pair_document(
    a: str, b: str, outcomes: dict[str, ScannerOutcome], centres: dict[str, RecordedCentres], job: JobConfig
) -> dict[str, Any]:
    """``cell.json``'s pair ``a``, ``b``: ``T_a_b`` with its covariance from the two poses, the
    agreement at the shared waypoints and, when they agree there, ``joint``: ``T_a_b`` with the
    shared centres used jointly (``calibration/pairs.joint_relative_pose``; not yet the pair's
    transform, docs/cell.md "Not done yet"; its std were not honest on the physical scanner model
    before the not-the-rod rule, docs/lab/cell-log.md); each
    against the truth when both scanners have one (a dry run)."""
    first, second = outcomes[a], outcomes[b]
    poses = (np.asarray(first.T_base_laser), np.asarray(first.covariance),
             np.asarray(second.T_base_laser), np.asarray(second.covariance))
    shared, agreement = pair_agreement(a, b, outcomes, centres, job)
    pair: dict[str, Any] = {"from": a, "to": b} | _transform_document(
        *relative_pose(*poses), "first order from the two poses' covariances, taken as independent"
    )
    pair |= {"passed": first.passed and second.passed, "agreement": agreement}
    if agreement["verdict"] == "agree":
        pair["joint"] = _transform_document(
            *joint_relative_pose(*poses, shared),
            f"the two poses' covariances and the {len(shared)} shared waypoints' centres used jointly",
        )
    if first.ground_truth is not None and second.ground_truth is not None:
        truth = np.linalg.inv(np.asarray(first.ground_truth)) @ np.asarray(second.ground_truth)
        for document in (pair, pair.get("joint")):
            if document is not None:
                document["ground_truth_error"] = error_in_std(
                    np.asarray(document["T_from_to"]), np.asarray(document["covariance"]), truth
                )
    return pair


#: A scanner's centres by waypoint index: its own (``None``) and its watchers' (by name),
#: each ``(tcp_pose, centre_uv_m, covariance_uv_m2)``.
RecordedCentres = dict[str | None, dict[int, tuple[Any, Any, Any]]]
#: How far beyond the distances a scanner's range error curve spans a watcher's centre is
#: still corrected by it; farther ones are left out of the agreement test.
CURVE_REACH_M = 0.1


@dataclass(frozen=True)
class _RecordedRun:
    """What the cell's pairs need of one scanner's run, read from its folder once."""

    #: Its own centres as its solve used them (key None) and its watchers' (by name).
    centres: RecordedCentres
    #: How its watchers' centres were computed again (``run/replay.replay_shared_centres``).
    replayed: ReplayedSharedCentres


@dataclass(frozen=True)
class _OwnRun:
    """A scanner's own centres: as its solve used them (``observations.csv``: second pass, its
    applied range offset taken out) and as its run found them (``observation`` events: the
    first pass, as a watcher finds its centres)."""

    solved: dict[int, tuple[Any, Any, Any]]
    first_pass: dict[int, FloatArray]


def _own_run(folder: Path, recording: SessionRecording | None) -> _OwnRun | None:
    """The scanner's own centres from its ``folder`` and run's ``recording`` (None without either)."""
    if recording is None or not (folder / OBSERVATIONS_FILE).is_file():
        return None
    solved = {o.index: (o.tcp_pose, o.centre_uv_m, o.covariance_uv_m2)
              for o in read_observations_csv(folder / OBSERVATIONS_FILE)}
    first_pass = {int(event["index"]): np.asarray(event["centre_uv_m"], dtype=float)
                  for event in recording.events_of("observation")}
    return _OwnRun(solved, first_pass)


def _solved_watcher(outcome: ScannerOutcome, recording: SessionRecording, run: _OwnRun) -> SolvedWatcher:
    """What a scanner's centres as a watcher take from its own solved run for their second pass:
    its pose, the rod line its solve estimated, its background (none where the recording lacks
    its scans) and its first-pass scatter (``first_pass_scatter_uv_m2``)."""
    background = recorded_background(recording)
    scatter = first_pass_scatter_uv_m2(
        run.first_pass, {index: centre for index, (_, centre, _) in run.solved.items()}, outcome
    )
    return SolvedWatcher(np.asarray(outcome.T_base_laser, dtype=float), outcome.rod,
                         None if isinstance(background, str) else background, scatter)


def _recorded_centres(
    recording: SessionRecording | None, run: _OwnRun | None, name: str, job: JobConfig,
    solved: dict[str, SolvedWatcher],
) -> _RecordedRun:
    """Scanner ``name``'s centres: its own as its solve used them and those its run's watchers
    measured, each computed again from the watcher's recorded scans and fitted again as the
    watcher's second pass (``run/replay.replay_shared_centres``, with what it could not; a
    watcher whose rod differs from this run's keeps its solve's pose and background but takes
    this run's rod); empty without its run's ``recording``."""
    if recording is None or run is None:
        return _RecordedRun({}, ReplayedSharedCentres())
    own_rod = job.for_scanner(name).rod
    rod = own_rod.rod_line()
    nominals = {other: job.for_scanner(other).scanner.nominal for other in job.scanner_names()}
    views = {other: view if job.for_scanner(other).rod == own_rod else replace(view, rod=rod)
             for other, view in solved.items() if other != name}
    replayed = replay_shared_centres(recording, rod, nominals, views)
    return _RecordedRun({None: run.solved} | dict(replayed.centres), replayed)


def pair_agreement(
    a: str, b: str, outcomes: dict[str, ScannerOutcome], centres: dict[str, RecordedCentres], job: JobConfig
) -> tuple[list[SharedCentre], dict[str, Any]]:
    """The waypoints of either run where the other scanner saw the rod too (a watcher's centre
    corrected by its scanner's range error curve; left out beyond the distances that curve
    spans, and where by the solved poses a plane does not cut the rod between its ends), and
    the agreement test of ``a`` and ``b`` over them (``calibration/agreement``), with the
    ``centres`` it compared at each (by scanner: centre and covariance as tested)."""
    forward, left_out_ab = _shared(a, b, outcomes, centres, job)
    backward, left_out_ba = _shared(b, a, outcomes, centres, job)
    first, second = outcomes[a], outcomes[b]
    shared = forward + _swapped(backward)
    result = agreement_test(
        np.asarray(first.T_base_laser), np.asarray(first.covariance),
        np.asarray(second.T_base_laser), np.asarray(second.covariance),
        shared,
    )
    result["centres"] = [
        {"waypoint": s.waypoint,
         "centres_uv_m": {a: s.centre_a_uv_m.tolist(), b: s.centre_b_uv_m.tolist()},
         "covariances_uv_m2": {a: s.covariance_a_uv_m2.tolist(), b: s.covariance_b_uv_m2.tolist()}}
        for s in shared
    ]
    left_out = left_out_ab + left_out_ba
    if left_out:
        result["left_out"] = [waypoint for waypoint, _ in left_out]
        causes = Counter(cause for _, cause in left_out)
        result["reason"] += f"; {len(left_out)} more left out: " + ", ".join(
            f"{count} {cause}" for cause, count in causes.items()
        )
    return shared, result


#: Why a waypoint both scanners saw is left out of the agreement test.
_BEYOND_CURVE = "where a scanner saw the rod beyond the distances its range error was calibrated at"
_NOT_THE_ROD = ("where by the solved poses the rod ends short of a plane or a centre lies off the rod "
                "by more than its radius")


def _shared(
    owner: str, other: str, outcomes: dict[str, ScannerOutcome], centres: dict[str, RecordedCentres],
    job: JobConfig,
) -> tuple[list[SharedCentre], list[tuple[str, str]]]:
    """The waypoints of ``owner``'s run where ``other`` saw the rod too (owner's centre first),
    and those left out with why (a centre beyond its scanner's range error curve's reach; a
    centre that by its scanner's solved pose is not the rod's: ``_on_the_rod``).
    Each centre is moved back by what is left in it of its scanner's range error curve (the
    owner's solved centre had the applied offset taken out, the watcher's none: the solver's
    own model of its centres), and its covariance is scaled by its scanner's reduced
    chi-square where that exceeds 1: the model error its solve showed."""
    own, seen = centres[owner].get(None, {}), centres[owner].get(other, {})
    rod = job.for_scanner(owner).rod.rod_line()
    scale = {name: max(1.0, outcomes[name].reduced_chi_square) for name in (owner, other)}
    shared, left_out = [], []
    for index in sorted(set(own) & set(seen)):
        tcp_pose, centre, covariance = own[index]
        _, other_centre, other_covariance = seen[index]
        first = _without_range_error(np.asarray(centre, dtype=float), outcomes[owner])
        second = _without_range_error(np.asarray(other_centre, dtype=float), outcomes[other], removed=False)
        origins, directions = rod_lines_in_base(np.asarray(tcp_pose, dtype=float)[None, :], rod)
        if first is None or second is None:
            left_out.append((f"{owner} {index}", _BEYOND_CURVE))
            continue
        found = ((outcomes[owner], first), (outcomes[other], second))
        if not all(_on_the_rod(np.asarray(o.T_base_laser, dtype=float), origins, directions, uv, rod)
                   for o, uv in found):
            left_out.append((f"{owner} {index}", _NOT_THE_ROD))
            continue
        shared.append(SharedCentre(
            f"{owner} {index}", first, np.asarray(covariance, dtype=float) * scale[owner],
            second, np.asarray(other_covariance, dtype=float) * scale[other], directions[0],
        ))
    return shared, left_out


def _on_the_rod(
    T_base_laser: FloatArray, origins: FloatArray, directions: FloatArray, centre_uv_m: FloatArray,
    rod: RodLine,
) -> bool:
    """Whether ``centre_uv_m`` can be the rod's centre by the solved pose ``T_base_laser``: its
    scan plane cuts the rod (one line of ``origins``, ``directions``) wholly between its ends
    (the ellipse it cuts reaches ``radius * tan(tilt)`` along the rod either side of the axis's
    crossing), and the centre lies within the rod's radius of that crossing. A watcher's nominal
    pose may say the rod crosses where it ends short of the plane, and its rod search then finds
    something else (another object, or the rod's end)."""
    rotation, translation_m = T_base_laser[:3, :3], T_base_laser[:3, 3]
    crossing_uv_m, slope, along_m = plane_crossing(rotation, translation_m, origins, directions)
    reach_m = rod.radius_m * float(np.linalg.norm(slope[0]))
    within = reach_m <= float(along_m[0]) <= rod.length_m - reach_m
    return within and float(np.linalg.norm(crossing_uv_m[0] - centre_uv_m)) <= rod.radius_m


def first_pass_scatter_uv_m2(
    first_pass: dict[int, FloatArray], solved: dict[int, FloatArray], outcome: ScannerOutcome
) -> FloatArray | None:
    """The mean outer product of (solved - first-pass) centre differences by the scanner's own
    waypoints, each centre moved back by what is left in it of the scanner's range error (as the
    agreement moves them: ``_without_range_error``); None with fewer than 3 waypoints."""
    differences = []
    for index in sorted(set(first_pass) & set(solved)):
        first = _without_range_error(np.asarray(first_pass[index], dtype=float), outcome, removed=False)
        second = _without_range_error(np.asarray(solved[index], dtype=float), outcome)
        if first is not None and second is not None:
            differences.append(second - first)
    if len(differences) < 3:
        return None
    d = np.asarray(differences)
    return d.T @ d / len(d)


def _without_range_error(
    centre_uv_m: FloatArray, outcome: ScannerOutcome, *, removed: bool = True
) -> FloatArray | None:
    """A centre moved back along its bearing by its scanner's range error there, less the
    offset already taken out of it when ``removed`` (a solved centre: its second pass's
    applied offset; a watcher's or a first-pass centre has none taken out), or None beyond
    ``CURVE_REACH_M`` of the distances the curve spans."""
    range_offset = outcome.range_offset
    if range_offset is None or not range_offset.curve:
        return centre_uv_m
    distance_m = float(np.linalg.norm(centre_uv_m))
    spanned = [point.distance_m for point in range_offset.curve]
    if not min(spanned) - CURVE_REACH_M <= distance_m <= max(spanned) + CURVE_REACH_M:
        return None
    error_m, _ = range_error_m(np.asarray(range_offset.coefficients_m()), np.asarray([distance_m]))
    left_m = float(error_m[0]) - (outcome.range_offset_applied_m if removed else 0.0)
    return centre_uv_m * (1.0 - left_m / distance_m)


def _swapped(shared: list[SharedCentre]) -> list[SharedCentre]:
    """The same waypoints with the two scanners' centres the other way round."""
    return [replace(s, centre_a_uv_m=s.centre_b_uv_m, covariance_a_uv_m2=s.covariance_b_uv_m2,
                    centre_b_uv_m=s.centre_a_uv_m, covariance_b_uv_m2=s.covariance_a_uv_m2) for s in shared]
