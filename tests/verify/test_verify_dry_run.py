"""``lasercal verify --dry-run`` against the fake cell: the real drivers, the run's
sequencer, the verdicts for an unmoved scanner, a moved one and another scanner."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fakes.ur_controller.kinematics_calibration import KinematicsCalibration
from lasercal_hw.config import with_overrides
from lasercal_hw.errors import ExitCode
from lasercal_hw.session.reader import read_session
from lasercal_hw.verify import VerifyRequest, verify
from tests.verify_helpers import fake_robot_calibration, fast_job, moved_scene, write_calibration

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(240)]

SHIFT_M = np.array([0.003, -0.004, 0.0])  # 5 mm
TURN_RAD = np.radians(0.5) * np.array([0.6, 0.0, 0.8])  # 0.5 deg


def test_cli_unmoved_scanner_is_not_flagged_and_a_blind_verify_says_so(tmp_path: Path) -> None:
    """Four waypoints of a quick calibration cannot see a 0.2 deg turn: the verify finds
    nothing, and says it cannot vouch for the tolerance (inconclusive, exit 1), not ok."""
    calibration = write_calibration(tmp_path / "calibration", fast_job())
    out = tmp_path / "verify"
    completed = subprocess.run(
        [
            sys.executable,
            "-m",
            "lasercal_hw.cli.main",
            "verify",
            "--calibration",
            str(calibration),
            "--dry-run",
            "--json",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=200,
        stdin=subprocess.DEVNULL,
    )
    assert completed.returncode == ExitCode.QUALITY_GATE_FAILED, completed.stderr[-2000:]
    document = json.loads(completed.stdout)
    test = document["test"]
    assert test["chi_square"] <= test["threshold"] and test["dof"] == 8 and not test["changed"]
    seen = test["detectable"]
    assert seen["weakest_turn_deg"] > document["tolerance"]["deg"], seen
    assert seen["weakest_turn_deg"] >= max(seen["turn_deg"]) - 1e-9, seen
    assert document["verdict"] == "inconclusive", document["reason"]
    assert "more waypoints" in document["reason"] and "dwell longer" in document["reason"]
    assert document["selection"]["choice"].endswith("an unmoved scanner's verdict is likely inconclusive")
    assert "of 10 (D-optimal: no subset found sees a 2 mm shift" in completed.stderr + completed.stdout
    assert all(w["visited_by_calibration"] for w in test["waypoints"])
    assert all(check["matches"] for check in document["identity"])
    assert {"session", "verify", "report"} <= set(document["outputs"])
    assert (out / "verify.png").stat().st_size > 10_000
    recording = read_session(out / "session.mcap")
    assert recording.meta["procedure"] == "verify"  # so no resume or rebuild takes it for a calibration
    assert [e["verdict"] for e in recording.events_of("verify_verdict")] == ["inconclusive"]
    assert len(recording.events_of("observation")) == 4


def test_moved_scanner_needs_recalibration_and_the_move_is_estimated(tmp_path: Path) -> None:
    calibration = write_calibration(tmp_path / "calibration", fast_job())
    scene = moved_scene(tmp_path / "moved.toml", SHIFT_M, TURN_RAD)
    events = []
    unreported = with_overrides(fast_job(), {"output.report": False})  # the CLI test above reads verify.png
    report = verify(
        VerifyRequest(out_dir=tmp_path / "verify", dry_run=True, scene=scene, job=unreported),
        calibration,
        on_event=events.append,
    )
    assert report.verdict.status == "recalibrate", report.verdict.reason
    test = report.outcome.test
    assert test is not None and test.changed and test.rigid
    truth = np.concatenate([SHIFT_M, TURN_RAD])
    std = np.sqrt(np.diag(test.correction_covariance))
    assert np.all(np.abs(test.correction - truth) <= 2.0 * std), (test.correction - truth) / std
    assert events[-1].kind == "verdict" and events[-1].data["verdict"] == "recalibrate"
    document = report.document()
    assert document["verdict"] == "recalibrate" and "beyond the tolerance" in document["reason"]
    assert np.allclose(document["ground_truth"]["T_base_laser"][0][3], 0.303)


def test_another_scanner_needs_recalibration_before_anything_moves(tmp_path: Path) -> None:
    calibration = write_calibration(tmp_path / "calibration", fast_job(), scanner_serial="H7654321")
    report = verify(VerifyRequest(out_dir=tmp_path / "verify", dry_run=True), calibration)
    assert report.verdict.status == "recalibrate"
    assert "scanner serial is H0123456, the calibration was made with H7654321" in report.verdict.reason
    assert report.outcome.test is None and report.outcome.timings.motion_s == 0.0
    document = json.loads((tmp_path / "verify" / "verify.json").read_text())
    assert document["verdict"] == "recalibrate" and document["test"] is None


def test_a_changed_robot_calibration_needs_recalibration_naming_the_robot(tmp_path: Path) -> None:
    """The robot's joint 3 was replaced since the calibration (the fake controller's scene
    says so): verify answers recalibrate before anything moves, naming the robot's
    calibration and both checksums, and records the calibration it read."""
    calibration = write_calibration(tmp_path / "calibration", fast_job())
    replaced = KinematicsCalibration().with_joint_replaced(3)
    scene = tmp_path / "replaced_joint.toml"
    scene.write_text(f"[robot_kinematics]\nchecksums = {list(replaced.checksums)}\n", encoding="utf-8")
    report = verify(VerifyRequest(out_dir=tmp_path / "verify", dry_run=True, scene=scene), calibration)
    before, after = fake_robot_calibration().checksum, fake_robot_calibration(replaced).checksum
    assert report.verdict.status == "recalibrate"
    assert report.verdict.reason == (
        f"the robot's kinematics calibration changed since the calibration: checksum {before} -> {after}"
    )
    assert report.outcome.test is None and report.outcome.timings.motion_s == 0.0
    document = json.loads((tmp_path / "verify" / "verify.json").read_text())
    assert document["robot_calibration"]["checksum"] == after
    check = next(c for c in document["identity"] if c["name"] == "robot kinematics calibration")
    assert check["recorded"] == before and not check["matches"]
