"""The files a run leaves in its output folder (besides ``session.mcap``, which the
recorder writes while the run goes): ``observations.csv``, ``result.json``, the report PNG
and the ROS exports; and ``read_result_file``, the one reader of ``result.json``."""

from __future__ import annotations

import json
import logging
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from lasercal_hw.calibration.model import plane_crossing, rod_lines_in_base
from lasercal_hw.calibration.observations import write_observations_csv
from lasercal_hw.calibration.result import CalibrationResult
from lasercal_hw.config import JobConfig, job_from_mapping
from lasercal_hw.errors import ConfigError
from lasercal_hw.geometry import rotation_angle_rad
from lasercal_hw.models import FloatArray, RobotCalibration, RodLine
from lasercal_hw.outputs.exports import exports, scanner_frame, static_transform_publisher_args, urdf_joint
from lasercal_hw.outputs.report import ReportData, render_report
from lasercal_hw.run.records import RunOutcome
from lasercal_hw.run.two_pass import SecondPassRefit

logger = logging.getLogger(__name__)

SESSION_FILE = "session.mcap"
OBSERVATIONS_FILE = "observations.csv"
RESULT_FILE = "result.json"
REPORT_FILE = "report.png"
URDF_FILE = "base_to_laser.urdf.xml"
TF_ARGS_FILE = "static_transform_publisher.args"


def transform_error(T_estimate: FloatArray, T_truth: FloatArray) -> dict[str, float]:
    """Translation (mm) and rotation (deg) between an estimate and a known transform."""
    estimate, truth = np.asarray(T_estimate, dtype=float), np.asarray(T_truth, dtype=float)
    rotation = truth[:3, :3].T @ estimate[:3, :3]
    return {
        "translation_mm": 1000.0 * float(np.linalg.norm(estimate[:3, 3] - truth[:3, 3])),
        "rotation_deg": float(np.degrees(rotation_angle_rad(rotation))),
    }


def result_document(
    outcome: RunOutcome,
    job: JobConfig,
    *,
    ground_truth: FloatArray | None = None,
    robot_calibration: RobotCalibration | None = None,
    scanner: str | None = None,
) -> dict[str, Any]:
    """``result.json``: the solver's result plus the run's verdict, skips and timings, every
    waypoint's UR pose by index (``run.waypoints``: what the residuals' ``index`` counts), the
    robot's own kinematics calibration (``run.robot_calibration``; null: unknown), and the cell
    scanner it calibrated (``run.scanner_name``, whose frame the exports name)."""
    result = outcome.result
    document = result.to_json_dict()
    document["verdict"] = outcome.verdict.as_dict()
    document["run"] = {
        "waypoints_planned": len(outcome.measurements) + len(outcome.skipped),
        "waypoints": np.asarray(outcome.waypoints, dtype=float).tolist(),
        "observations": len(outcome.observations),
        "skipped": [{"index": s.index, "reason": s.reason} for s in outcome.skipped],
        "centre_warnings": [{"index": i, "warning": warning} for i, warning in outcome.centre_warnings],
        "refinement": outcome.refinement,
        "first_pass": first_pass_record(outcome.first_pass, job, outcome.refit),
        "resumed_after_waypoints": outcome.resumed_from,
        "timings": {
            "wall_s": outcome.timings.wall_s,
            "motion_s": outcome.timings.motion_s,
            "dwell_s": outcome.timings.dwell_s,
            "overhead_s": outcome.timings.overhead_s,
            "overhead_fraction": outcome.timings.overhead_fraction,
        },
        "robot": asdict(outcome.preflight.robot),
        "scanner": asdict(outcome.preflight.scanner),
        "robot_calibration": None if robot_calibration is None else robot_calibration.as_dict(),
        "job": job.model_dump(mode="json"),
    }
    if scanner is not None:
        document["run"]["scanner_name"] = scanner
    document["exports"] = exports(result.matrix(), child=scanner_frame(scanner))
    if ground_truth is not None:
        document["ground_truth"] = {
            "T_base_laser": np.asarray(ground_truth, dtype=float).tolist(),
            "error": transform_error(result.matrix(), ground_truth),
            "first_pass_error": transform_error(outcome.first_pass.matrix(), ground_truth),
        }
    return document


def first_pass_record(
    first_pass: CalibrationResult, job: JobConfig, refit: SecondPassRefit
) -> dict[str, Any]:
    """``result.json``'s ``run.first_pass``: the first pass's transform and residual, the rod
    line (TCP frame) with which the second pass fitted every centre again: the first pass's
    estimate of it (``solve_two_pass``), the job's own when the job does not estimate the axis;
    and for a fluted rod the flute phase pass's outcome (``flute_phase_record``)."""
    record = {
        "T_base_laser": first_pass.T_base_laser,
        "rms_residual_mm": first_pass.rms_residual_mm,
        "rod": _line_record(first_pass.estimated_rod(job.rod.rod_line())),
    }
    if job.rod.fluted:
        record["flute_phase"] = flute_phase_record(refit)
    return record


def flute_phase_record(refit: SecondPassRefit) -> dict[str, Any]:
    """``run.first_pass.flute_phase``: whether the flute phase pass was kept and, where it was,
    the phase (deg from the tool's x axis, over the half turn) and its std, the transform and
    plain rod line of its plain fits (``plain_fit``) and those its section offsets were taken
    with (``offsets``): what the verify's re-fit needs to move the plain fits as the pass did."""
    shift = refit.flutes
    if shift is None:
        return {"kept": False}
    return {
        "kept": True,
        "phase_deg": float(np.degrees(shift.phase_rad)) % 180.0,
        "phase_std_deg": float(np.degrees(shift.phase_std_rad)),
        "plain_fit": _fit_record(refit.T_base_laser, refit.rod),
        "offsets": _fit_record(shift.T_base_laser, shift.rod),
    }


def _fit_record(T_base_laser: FloatArray, rod: RodLine) -> dict[str, Any]:
    """A transform and rod line a fit was made with, as ``result.json`` records them."""
    return {"T_base_laser": np.asarray(T_base_laser, dtype=float).tolist(), "rod": _line_record(rod)}


def _line_record(rod: RodLine) -> dict[str, list[float]]:
    """A rod line as ``result.json`` records it (TCP frame)."""
    return {
        "origin_m": np.asarray(rod.origin_m, dtype=float).tolist(),
        "direction": np.asarray(rod.direction, dtype=float).tolist(),
    }


@dataclass(frozen=True)
class ResultFile:
    """A ``result.json`` read back: the calibration, the run's verdict and what the run
    recorded beside it (None where the file has none, as in one ``lasercal solve`` wrote)."""

    path: Path
    result: CalibrationResult
    verdict: dict[str, Any] | None
    robot: dict[str, Any] | None
    scanner: dict[str, Any] | None
    job: JobConfig | None
    motion_and_dwell_s: float | None
    #: The cell scanner it calibrated (None: a one-scanner job's).
    scanner_name: str | None = None
    #: The robot's own kinematics calibration as recorded (``RobotCalibration.as_dict``), or None.
    robot_calibration: dict[str, Any] | None = None
    #: A dry run's true ``T_base_laser`` (4x4 rows) as recorded, or None.
    ground_truth: list[list[float]] | None = None
    #: The first pass's ``T_base_laser`` (4x4 rows), with which the second pass fitted every
    #: centre again, or None where the file has none.
    first_pass_transform: list[list[float]] | None = None
    #: The rod line (TCP frame: ``origin_m``, ``direction``) with which the second pass fitted
    #: every centre again (the first pass's estimate of it, or the job's), or None where the
    #: file has none.
    first_pass_rod: dict[str, list[float]] | None = None
    #: The flute phase pass's outcome as recorded (``run.first_pass.flute_phase``), or None where
    #: the file has none (a rod without flutes, or a file written before 2026-11-27).
    flute_phase: dict[str, Any] | None = None
    #: The UR pose of every waypoint the run planned (N, 6), by the residuals' index
    #: (``run.waypoints``), or None where the file has none (written before 2026-11-28, or by
    #: ``lasercal solve`` of a CSV; of a ``session.mcap`` it writes them where the recording holds them all).
    run_waypoints: FloatArray | None = None

    @property
    def passed(self) -> bool:
        """True when the run's quality gates passed (False without a verdict)."""
        return bool((self.verdict or {}).get("passed", False))


def _run_waypoints(run: dict[str, Any], path: Path) -> FloatArray | None:
    """``run.waypoints`` as UR poses (N, 6), None where the file has none; malformed: ConfigError."""
    value = run.get("waypoints")
    if value is None:
        return None
    try:
        poses = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        poses = np.zeros(0)
    if poses.ndim != 2 or poses.shape[1] != 6 or not np.isfinite(poses).all():
        raise ConfigError(
            f"{path}: run.waypoints is not a list of UR poses (6 finite numbers each); pass the "
            "result.json that `lasercal run` wrote"
        )
    return poses


def _table(document: dict[str, Any], key: str) -> dict[str, Any] | None:
    value = document.get(key)
    return value if isinstance(value, dict) else None


def _not_a_result(path: Path, why: str) -> ConfigError:
    """The error for a file that is not a ``result.json`` (another file of a run, or a broken one)."""
    return ConfigError(
        f"{path} is not a result.json ({why}): give the result.json that `lasercal run` or "
        "`lasercal solve` wrote"
    )


def read_result_file(path: Path) -> ResultFile:
    """Read a ``result.json`` (as ``result_document`` writes it); a missing or malformed
    file raises ``ConfigError`` naming it."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{path} is a folder: give {path / RESULT_FILE}, the calibration's result file")
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(
            f"calibration file {path} does not exist; pass the result.json of a calibration"
        ) from None
    except UnicodeDecodeError:
        raise _not_a_result(path, "not text: a binary file such as session.mcap") from None
    except json.JSONDecodeError as exc:
        raise _not_a_result(path, f"not JSON from line {exc.lineno}") from None
    except OSError as exc:
        raise ConfigError(f"cannot read calibration file {path}: {exc.strerror or exc}") from None
    if not isinstance(document, dict):
        raise _not_a_result(path, "a JSON document, but not an object")
    try:
        result = CalibrationResult.model_validate(document)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise ConfigError(
            f"{path} is not a lasercal calibration result ({where}: {first['msg']}); pass the result.json "
            "that `lasercal run` or `lasercal solve` wrote"
        ) from None
    run = _table(document, "run") or {}
    job_table = _table(run, "job")
    job = job_from_mapping(job_table, f"{path} (run.job)") if job_table is not None else None
    timings = _table(run, "timings") or {}
    busy_s = (timings.get("motion_s") or 0.0) + (timings.get("dwell_s") or 0.0)
    return ResultFile(
        path=Path(path),
        result=result,
        verdict=_table(document, "verdict"),
        robot=_table(run, "robot"),
        scanner=_table(run, "scanner"),
        job=job,
        motion_and_dwell_s=float(busy_s) if busy_s > 0 else None,
        scanner_name=run.get("scanner_name"),
        robot_calibration=_table(run, "robot_calibration"),
        ground_truth=(_table(document, "ground_truth") or {}).get("T_base_laser"),
        first_pass_transform=(_table(run, "first_pass") or {}).get("T_base_laser"),
        first_pass_rod=_table(_table(run, "first_pass") or {}, "rod"),
        flute_phase=_table(_table(run, "first_pass") or {}, "flute_phase"),
        run_waypoints=_run_waypoints(run, path),
    )


def report_data(
    outcome: RunOutcome, job: JobConfig, title: str, ground_truth: FloatArray | None = None
) -> ReportData:
    """What the report PNG shows for this run (a dry run's error against its truth too)."""
    result = outcome.result
    T = result.matrix()
    poses = np.array([o.tcp_pose for o in outcome.observations])
    origins, directions = rod_lines_in_base(poses, job.rod.rod_line())
    predicted, _, _ = plane_crossing(T[:3, :3], T[:3, 3], origins, directions)
    used = {r.index: r.used for r in result.residuals}
    notes = [outcome.refinement, *outcome.result.estimate_lines(), *outcome.verdict.failures()]
    notes += [f"waypoint {s.index} skipped: {s.reason}" for s in outcome.skipped]
    background = outcome.background
    return ReportData(
        title=title,
        T_base_laser=result.T_base_laser,
        std_translation_mm=result.std_translation_mm,
        std_rotation_deg=result.std_rotation_deg,
        indices=[o.index for o in outcome.observations],
        measured_uv_m=np.array([o.centre_uv_m for o in outcome.observations]),
        predicted_uv_m=predicted,
        used=[used.get(o.index, False) for o in outcome.observations],
        tcp_poses=poses,
        background_angles_rad=background.angles_rad if background is not None else [],
        background_ranges_m=background.ranges_m if background is not None else [],
        notes=notes,
        truth_error_mm_deg=None if ground_truth is None else tuple(transform_error(T, ground_truth).values()),
    )


def write_text(path: Path, text: str) -> None:
    """Write an output file; a failure is a ConfigError naming the file."""
    try:
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"cannot write {path}: {exc.strerror or exc}") from exc


def write_outputs(
    out_dir: Path,
    outcome: RunOutcome,
    job: JobConfig,
    *,
    ground_truth: FloatArray | None = None,
    title: str = "lasercal calibration",
    scanner: str | None = None,
    robot_calibration: RobotCalibration | None = None,
) -> dict[str, Path]:
    """Write every result file into ``out_dir``; returns them by name.

    A result that failed a quality gate gets no URDF and no ``static_transform_publisher``
    arguments: a launch file picks those up as they are, and nothing in them could say
    FAILED. ``result.json`` (with its verdict and exports) and the report still say
    everything, and a stale pair from an earlier pass in the same folder is removed."""
    files = {
        "observations": out_dir / OBSERVATIONS_FILE,
        "result": out_dir / RESULT_FILE,
    }
    write_observations_csv(files["observations"], outcome.observations, outcome.solve_settings)
    document = result_document(
        outcome, job, ground_truth=ground_truth, robot_calibration=robot_calibration, scanner=scanner
    )
    write_text(files["result"], json.dumps(document, indent=2, allow_nan=False) + "\n")
    T = outcome.result.matrix()
    ros_files = {"urdf": out_dir / URDF_FILE, "static_transform_publisher": out_dir / TF_ARGS_FILE}
    if outcome.verdict.passed:
        child = scanner_frame(scanner)
        write_text(ros_files["urdf"], urdf_joint(T, child=child))
        tf_args = " ".join(static_transform_publisher_args(T, child_frame_id=child))
        write_text(ros_files["static_transform_publisher"], tf_args + "\n")
        files |= ros_files
    else:
        for path in ros_files.values():
            path.unlink(missing_ok=True)
        logger.warning("quality gate failed: %s and %s are not written (result.json has the transform "
                       "and its verdict)", URDF_FILE, TF_ARGS_FILE)
    if job.output.report:
        files["report"] = render_report(
            report_data(outcome, job, title, ground_truth), out_dir / REPORT_FILE
        )
    return files
