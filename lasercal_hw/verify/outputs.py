"""What a verify leaves beside its ``session.mcap``: ``verify.json`` and the one-page
``verify.png`` (the run's report layout: measured against predicted centres, the
residuals, the waypoints, and the verdict with the estimated move in its notes)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import chi2

from lasercal_hw.config import JobConfig
from lasercal_hw.models import FloatArray, RobotCalibration
from lasercal_hw.outputs.report import ReportData, render_report
from lasercal_hw.run.outputs import transform_error, write_text
from lasercal_hw.run.records import Timings
from lasercal_hw.verify.active import ActiveCalibration
from lasercal_hw.verify.drift import DriftTest, RangeChange
from lasercal_hw.verify.identity import IdentityCheck
from lasercal_hw.verify.selection import Selection
from lasercal_hw.verify.verdict import Verdict

VERIFY_FILE = "verify.json"
REPORT_FILE = "verify.png"


@dataclass(frozen=True)
class VerifyOutcome:
    """Everything a verify found (waypoint numbers are those of the job's trajectory)."""

    calibration: ActiveCalibration
    job: JobConfig
    selection: Selection
    identity: list[IdentityCheck]
    test: DriftTest | None
    verdict: Verdict
    visited_by_calibration: list[bool]
    skipped: list[tuple[int, str]]
    #: Waypoints the re-fit could not fit again, left out of the test (index, reason).
    not_refitted: list[tuple[int, str]]
    timings: Timings
    #: The robot's own kinematics calibration during this verify (None: unknown).
    robot_calibration: RobotCalibration | None = None

    def time_fraction(self) -> float | None:
        """Motion plus dwell of this verify over that of the calibration (None: not recorded)."""
        reference_s = self.calibration.motion_and_dwell_s
        if reference_s is None:
            return None
        return (self.timings.motion_s + self.timings.dwell_s) / reference_s


def _floats(values: Any) -> list[Any]:
    return np.asarray(values, dtype=float).tolist()


def _range_change_document(change: RangeChange) -> dict[str, Any]:
    return {
        "offset_mm": change.offset_m * 1e3,
        "std_mm": change.std_m * 1e3,
        "remainder_chi_square": change.remainder_chi_square,
        "remainder_dof": change.remainder_dof,
        "remainder_threshold": change.remainder_threshold,
        "explains": change.explains,
        "meaning": "the one range change along every beam that best explains the residuals, and "
        "what it leaves; a diagnosis of a flagged test (a scanner warming up), not part of it",
    }


def _test_document(test: DriftTest, visited: list[bool]) -> dict[str, Any]:
    shift_mm, shift_std_mm = test.shift_norm_mm()
    turn_deg, turn_std_deg = test.turn_norm_deg()
    residual_mm = test.residual_mm
    return {
        "chi_square": test.chi_square,
        "dof": test.dof,
        "threshold": test.threshold,
        "p_value": test.p_value,
        "false_alarm_rate": test.false_alarm_rate,
        "changed": test.changed,
        "post_fit_chi_square": test.post_fit_chi_square,
        "post_fit_dof": test.post_fit_dof,
        "rigid": test.rigid,
        "range_change": None if test.range_change is None else _range_change_document(test.range_change),
        "detectable": {
            "shift_mm": _floats(test.detectable_shift_mm),
            "turn_deg": _floats(test.detectable_turn_deg),
            "weakest_shift_mm": test.weakest.shift_mm,
            "weakest_shift_direction": _floats(test.weakest.shift_direction),
            "weakest_turn_deg": test.weakest.turn_deg,
            "weakest_turn_axis": _floats(test.weakest.turn_axis),
            "detection_probability": test.detection_probability,
            "meaning": "shift_mm / turn_deg: the smallest shift along / turn about each base axis the "
            "test flags with this probability at its false-alarm rate; weakest_*: the smallest shift / "
            "turn it flags so in the direction it sees least (a unit vector in base axes), which the "
            "verdict weighs against the tolerance",
        },
        "correction": {
            "shift_mm": _floats(test.shift_mm),
            "std_shift_mm": _floats(test.std_shift_mm),
            "turn_deg": _floats(test.turn_deg),
            "std_turn_deg": _floats(test.std_turn_deg),
            "shift_norm_mm": shift_mm,
            "std_shift_norm_mm": shift_std_mm,
            "turn_norm_deg": turn_deg,
            "std_turn_norm_deg": turn_std_deg,
            "covariance": _floats(test.correction_covariance),
            "axes": "shift of the scanner origin along, and turn about, the robot base x, y, z",
        },
        "waypoints": [
            {
                "index": index,
                "measured_uv_m": _floats(test.measured_uv_m[k]),
                "predicted_uv_m": _floats(test.predicted_uv_m[k]),
                "residual_mm": _floats(residual_mm[k]),
                "whitened_norm": float(test.whitened_norm[k]),
                "visited_by_calibration": visited[k],
            }
            for k, index in enumerate(test.indices)
        ],
    }


def verify_document(outcome: VerifyOutcome, *, ground_truth: FloatArray | None = None) -> dict[str, Any]:
    """``verify.json``: the verdict, the test, the identity checks, the timings."""
    test, robot_calibration = outcome.test, outcome.robot_calibration
    selection = outcome.selection
    timings = outcome.timings
    document: dict[str, Any] = {
        "verdict": outcome.verdict.status,
        "reason": outcome.verdict.reason,
        "calibration": {
            "path": str(outcome.calibration.path),
            "T_base_laser": outcome.calibration.result.T_base_laser,
            "std_translation_mm": outcome.calibration.result.std_translation_mm,
            "std_rotation_deg": outcome.calibration.result.std_rotation_deg,
            "rod": outcome.calibration.rod_note(),
            "flute_phase": outcome.calibration.flute_note(),
        },
        "tolerance": {"mm": outcome.job.verify.tolerance_mm, "deg": outcome.job.verify.tolerance_deg},
        "identity": [
            {"name": c.name, "recorded": c.recorded, "current": c.current, "matches": c.matches}
            for c in outcome.identity
        ],
        "robot_calibration": None if robot_calibration is None else robot_calibration.as_dict(),
        "selection": {
            "waypoints": selection.indices,
            "candidates": selection.candidates,
            "candidates_from": outcome.calibration.waypoints_note(),
            "expected_std_shift_mm": selection.expected_std_shift_mm,
            "expected_std_turn_deg": selection.expected_std_turn_deg,
            "centre_noise": selection.centre_noise,
            "choice": selection.choice,
            "left_out": selection.left_out,
        },
        "test": None if test is None else _test_document(test, outcome.visited_by_calibration),
        "skipped": [{"index": i, "reason": r} for i, r in outcome.skipped],
        "not_refitted": [{"index": i, "reason": r} for i, r in outcome.not_refitted],
        "timings": {
            "wall_s": timings.wall_s,
            "motion_s": timings.motion_s,
            "dwell_s": timings.dwell_s,
            "calibration_motion_and_dwell_s": outcome.calibration.motion_and_dwell_s,
            "fraction_of_calibration": outcome.time_fraction(),
        },
    }
    if test is not None:
        document["T_base_laser_corrected"] = _floats(
            test.corrected_T_base_laser(outcome.calibration.T_base_laser)
        )
    if ground_truth is not None:
        truth = np.asarray(ground_truth, dtype=float)
        document["ground_truth"] = {
            "T_base_laser": truth.tolist(),
            "calibration_error": transform_error(outcome.calibration.T_base_laser, truth),
        }
    return document


def _report_data(outcome: VerifyOutcome) -> ReportData:
    test = outcome.test
    assert test is not None
    result = outcome.calibration.result
    single_limit = float(np.sqrt(chi2.ppf(1.0 - test.false_alarm_rate, 2)))
    shift_mm, shift_std = test.shift_norm_mm()
    turn_deg, turn_std = test.turn_norm_deg()
    notes = [
        f"verdict: {outcome.verdict.status.upper()}: {outcome.verdict.reason}",
        f"estimated move: shift {shift_mm:.2f} +- {shift_std:.2f} mm, "
        f"turn {turn_deg:.3f} +- {turn_std:.3f} deg",
        f"shift (x, y, z) mm: {np.round(test.shift_mm, 2).tolist()}; "
        f"turn deg: {np.round(test.turn_deg, 3).tolist()}",
        f"red: waypoint residual beyond {single_limit:.2f} sigma "
        f"(chi-square 2 dof, {test.false_alarm_rate:.0%})",
        *(c.describe() for c in outcome.identity),
    ]
    fraction = outcome.time_fraction()
    if fraction is not None:
        notes.append(f"motion and dwell: {100 * fraction:.0f} % of the calibration's")
    return ReportData(
        title=f"lasercal verify: {outcome.verdict.status} ({outcome.calibration.path})",
        T_base_laser=result.T_base_laser,
        std_translation_mm=result.std_translation_mm,
        std_rotation_deg=result.std_rotation_deg,
        indices=test.indices,
        measured_uv_m=test.measured_uv_m,
        predicted_uv_m=test.predicted_uv_m,
        used=[bool(w <= single_limit) for w in test.whitened_norm],
        tcp_poses=test.tcp_poses,
        notes=notes,
    )


def write_verify_outputs(
    out_dir: Path, outcome: VerifyOutcome, *, ground_truth: FloatArray | None = None
) -> dict[str, Path]:
    """Write ``verify.json`` and (when the job asks for reports and there is a test) the PNG."""
    files = {"verify": out_dir / VERIFY_FILE}
    document = verify_document(outcome, ground_truth=ground_truth)
    write_text(files["verify"], json.dumps(document, indent=2, allow_nan=False) + "\n")
    if outcome.job.output.report and outcome.test is not None:
        files["report"] = render_report(_report_data(outcome), out_dir / REPORT_FILE)
    return files
