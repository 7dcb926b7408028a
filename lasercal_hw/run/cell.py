"""One job, every scanner of a cell: ``calibrate_cell(CellRunRequest) -> CellReport``.

A job with ``[scanners.NAME]`` tables calibrates each named scanner in turn, each a whole
run of ``engine.calibrate`` on the scanner's own one-scanner job (``JobConfig.for_scanner``:
its waypoints, rod and gates) in the folder ``<out>/<NAME>/`` (its own ``session.mcap``,
``result.json`` and exports). ``<out>/cell.json`` holds the job and the scanners' order from
the start, and at the end every scanner's result and every scanner-to-scanner transform
with its covariance (``calibration/pairs.py``). Resuming the cell folder keeps every
scanner that has a ``result.json``, continues the one whose recording stopped at the
waypoint where it stopped, and runs the rest (docs/cell.md).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from lasercal_hw.calibration.pairs import error_in_std, relative_pose
from lasercal_hw.config import JobConfig, job_from_mapping
from lasercal_hw.errors import ConfigError
from lasercal_hw.run.cancel import CancelToken
from lasercal_hw.run.engine import MotionPlan, RunEvent, RunReport, RunRequest, calibrate
from lasercal_hw.run.outputs import RESULT_FILE, SESSION_FILE, read_result_file, write_text

CELL_FILE = "cell.json"


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


def cell_folder(path: Path) -> Path:
    """The cell folder a ``--resume`` path names (the folder, or its ``cell.json``)."""
    folder = path.parent if path.name == CELL_FILE else path
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
    ``cell.json``: the recorded job and scanners decide)."""
    if request.resume is None:
        return request.job, list(request.scanners or request.job.scanner_names())
    folder = cell_folder(request.resume)
    document = _read_cell_file(folder)
    job = job_from_mapping(document["job"], str(folder / CELL_FILE))
    return job, list(document.get("scanners_run", job.scanner_names()))


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
    outcomes: dict[str, ScannerOutcome] = {}
    for name in names:
        folder = request.out_dir / name
        if not (folder / RESULT_FILE).is_file():
            session = folder / SESSION_FILE
            run = RunRequest(
                job=job.for_scanner(name),
                out_dir=folder,
                robot_host=None if request.dry_run else request.robot_host,
                dry_run=request.dry_run,
                scene=request.scene,
                resume=session if session.is_file() else None,
                title=f"{request.title}: scanner {name}",
                scanner_name=name,
            )
            tagged = events_of_scanner(on_event, name)
            report = calibrate(run, on_event=tagged, cancel=cancel, confirm=confirm)
            outcomes[name] = _scanner_outcome(name, folder / RESULT_FILE, report)
        else:
            outcomes[name] = _scanner_outcome(name, folder / RESULT_FILE, None)
    cell = CellReport(request.out_dir, outcomes, _pairs(outcomes))
    document = _read_cell_file(request.out_dir) | cell.document()
    write_text(request.out_dir / CELL_FILE, json.dumps(document, indent=2, allow_nan=False) + "\n")
    return cell


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
    on_event: Callable[[RunEvent], None] | None, name: str
) -> Callable[[RunEvent], None] | None:
    """``on_event`` with every event of scanner ``name``'s run naming it (``data["scanner"]``),
    so a page or a live view shows each scanner's scans and centres as its own."""
    if on_event is None:
        return None
    sink = on_event
    return lambda event: sink(replace(event, data=event.data | {"scanner": name}))


def _scanner_outcome(name: str, path: Path, report: RunReport | None) -> ScannerOutcome:
    """A scanner's outcome from its ``result.json`` (the one source, run now or before)."""
    result_file = read_result_file(path)
    truth = json.loads(path.read_text(encoding="utf-8")).get("ground_truth", {}).get("T_base_laser")
    return ScannerOutcome(
        name=name,
        result_path=path,
        passed=result_file.passed,
        T_base_laser=result_file.result.T_base_laser,
        covariance=result_file.result.covariance,
        ground_truth=truth,
        report=report,
    )


def _pairs(outcomes: dict[str, ScannerOutcome]) -> list[dict[str, Any]]:
    """Every scanner-to-scanner transform ``T_a_b`` (a before b in the job's order) with its
    covariance, and against the truth when both scanners have one (a dry run)."""
    names = list(outcomes)
    pairs = []
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            first, second = outcomes[a], outcomes[b]
            T_ab, covariance = relative_pose(
                np.asarray(first.T_base_laser), np.asarray(first.covariance),
                np.asarray(second.T_base_laser), np.asarray(second.covariance),
            )
            std = np.sqrt(np.diag(covariance))
            pair: dict[str, Any] = {
                "from": a,
                "to": b,
                "T_from_to": T_ab.tolist(),
                "covariance": covariance.tolist(),
                "covariance_note": "first order from the two poses' covariances, taken as independent",
                "std_translation_mm": (1000.0 * std[:3]).tolist(),
                "std_rotation_deg": np.degrees(std[3:]).tolist(),
                "passed": first.passed and second.passed,
            }
            if first.ground_truth is not None and second.ground_truth is not None:
                truth = np.linalg.inv(np.asarray(first.ground_truth)) @ np.asarray(second.ground_truth)
                pair["ground_truth_error"] = error_in_std(T_ab, covariance, truth)
            pairs.append(pair)
    return pairs
