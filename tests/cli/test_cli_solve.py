"""``lasercal solve`` and ``lasercal simulate`` end to end, as a user runs them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lasercal_hw.calibration.observations import write_observations_csv
from tests.calibration.test_solver_helpers import TRUTH, observations
from tests.cli_helpers import assert_one_line_error, run_cli

pytestmark = pytest.mark.integration


def _csv(tmp_path: Path, **kwargs: object) -> Path:
    """Simulated observations with the noise of a real run (3 mm), so that a good solve also
    passes the quality gates `solve` applies (the paper's 10 mm simulation would not)."""
    path = tmp_path / "observations.csv"
    write_observations_csv(path, observations(**{"laser_noise_m": 0.003, **kwargs}))  # type: ignore[arg-type]
    return path


def test_solve_json_is_the_result_document(tmp_path: Path) -> None:
    out = tmp_path / "result.json"
    result = run_cli("solve", str(_csv(tmp_path, points=30)), "--json", "--output", str(out))
    assert result.returncode == 0, result.stderr
    document = json.loads(result.stdout)
    matrix = np.array(document["T_base_laser"])
    assert matrix.shape == (4, 4)
    assert np.linalg.norm(matrix[:3, 3] - TRUTH[:3, 3]) < 0.03
    assert json.loads(out.read_text()) == document


def test_solve_prints_a_readable_table(tmp_path: Path) -> None:
    result = run_cli("solve", str(_csv(tmp_path, points=30)), "--no-robust")
    assert result.returncode == 0, result.stderr
    assert "T_base_laser" in result.stdout and "t_z (mm)" in result.stdout and "CRB" in result.stdout


def test_axis_options_change_the_rod_line(tmp_path: Path) -> None:
    path = _csv(tmp_path, points=30, laser_noise_m=0.0, robot_noise_m=0.0)
    moved = run_cli("solve", str(path), "--json", "--axis-origin", "0,0,0.1", "--axis-direction", "0,0,2")
    assert moved.returncode == 0, moved.stderr
    # The rod's origin slides along its own axis: same line, same answer.
    np.testing.assert_allclose(json.loads(moved.stdout)["T_base_laser"], TRUTH, atol=1e-8)
    bad = run_cli("solve", str(path), "--axis-direction", "0,0")
    assert_one_line_error(bad, 2, "--axis-direction must have 3 numbers")


def test_too_few_rows_exit_4(tmp_path: Path) -> None:
    assert_one_line_error(run_cli("solve", str(_csv(tmp_path, points=3))), 4, "at least 5")


def test_parallel_axes_exit_4(tmp_path: Path) -> None:
    result = run_cli("solve", str(_csv(tmp_path, points=20, tilt_deg=1e-9)))
    assert_one_line_error(result, 4, "parallel", "tilting the rod")


def test_number_typo_exit_2_naming_line_and_column(tmp_path: Path) -> None:
    path = _csv(tmp_path, points=10)
    lines = path.read_text().splitlines()
    fields = lines[4].split(",")
    fields[7] = "0.3x"
    lines[4] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n")
    assert_one_line_error(run_cli("solve", str(path)), 2, "line 5, column u", "'0.3x'")


def test_missing_column_exit_2_naming_it(tmp_path: Path) -> None:
    path = tmp_path / "obs.csv"
    path.write_text("index,tcp_x,tcp_y,tcp_z,tcp_rx,tcp_ry,tcp_rz,u\n0,0,0,0,0,0,0,0\n")
    assert_one_line_error(run_cli("solve", str(path)), 2, "missing column(s) v")


def test_missing_file_exit_2(tmp_path: Path) -> None:
    assert_one_line_error(run_cli("solve", str(tmp_path / "absent.csv")), 2, "does not exist")


def test_unwritable_output_is_a_one_line_error(tmp_path: Path) -> None:
    csv_path = _csv(tmp_path, points=30)
    targets = ((tmp_path / "absent" / "result.json", "No such file"), (tmp_path, "Is a directory"))
    for target, reason in targets:
        result = run_cli("solve", str(csv_path), "--output", str(target))
        assert_one_line_error(result, 2, "cannot write", reason, "writable directory")


def test_directory_instead_of_a_file_exit_2(tmp_path: Path) -> None:
    assert_one_line_error(run_cli("solve", str(tmp_path)), 2, "is a directory", "observations.csv")

LASER_NOISE = "--laser-noise-mm must be a finite number > 0 and at most 1000 (mm), got "
ROBOT_NOISE = "--robot-noise-mm must be a finite number >= 0 and at most 1000 (mm), got "


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--trials", "0"), "--trials must be at least 1, got 0"),
        (("--trials", "-3"), "--trials must be at least 1, got -3"),
        (("--laser-noise-mm", "-1"), LASER_NOISE + "-1"),
        (("--laser-noise-mm", "0"), LASER_NOISE + "0"),
        (("--laser-noise-mm", "inf"), LASER_NOISE + "inf"),
        (("--laser-noise-mm", "nan"), LASER_NOISE + "nan"),
        (("--robot-noise-mm", "-0.5"), ROBOT_NOISE + "-0.5"),
        (("--robot-noise-mm", "inf"), ROBOT_NOISE + "inf"),
        (("--robot-noise-mm", "nan"), ROBOT_NOISE + "nan"),
        (("--laser-noise-mm", "1e6"), LASER_NOISE + "1e+06"),
        (("--robot-noise-mm", "1e300"), ROBOT_NOISE + "1e+300"),
        (("--seed", "-1"), "--seed must be 0 or more, got -1"),
        (("--tilt-deg", "90"), "--tilt-deg must be between 0 and 60"),
        (("--tilt-deg", "inf"), "--tilt-deg must be between 0 and 60"),
        (("--tilt-deg", "nan"), "--tilt-deg must be between 0 and 60"),
    ],
)
def test_simulate_names_the_bad_option_and_its_value(args: tuple[str, ...], message: str) -> None:
    """Refused as the option's value (exit 2), never as the NaN waypoints an infinite noise
    makes (exit 4)."""
    assert_one_line_error(run_cli("simulate", *args), 2, message)


def test_simulate_json_reports_statistics_against_the_bound() -> None:
    result = run_cli("simulate", "--trials", "5", "--points", "20", "--seed", "3", "--json")
    assert result.returncode == 0, result.stderr
    document = json.loads(result.stdout)
    assert document["trials"] == 5 and document["failures"] == 0
    assert set(document["mean"]) == {"x", "y", "z", "xyz", "rot_x", "rot_y", "rot_z", "rot"}
    assert document["paper_mean"]["xyz"] == 9.581
    assert 0.2 < document["rms_translation_mm"] / document["crb_rms_translation_mm"] < 5


def test_simulate_table_and_bad_option() -> None:
    result = run_cli("simulate", "--trials", "3", "--formulation", "paper")
    assert result.returncode == 0, result.stderr
    for fragment in ("paper mu", "9.581", "RMS translation error"):
        assert fragment in result.stdout
    assert_one_line_error(run_cli("simulate", "--points", "3"), 2, "--points at least 5")


def test_a_runs_observations_csv_solves_exactly_as_the_run_did(tmp_path: Path) -> None:
    """The rod axis, the noise model and the gates travel with the observations: the drill-like
    case (axis estimated from a shifted nominal line, 2 mm robot noise, tight gates)."""
    from lasercal_hw.run.outputs import write_outputs
    from tests.doubles import MemoryRecorder, run_calibration, semicircle_waypoints
    from tests.run.test_sequencer import fast_job, make_cell

    job = fast_job(
        rod={"origin_m": [0.0, 0.001, 0.0], "estimate_axis": True},
        robot={"position_accuracy_mm": 2.0},
        quality={"max_std_translation_mm": 0.05},
        output={"report": False},
    )
    clock, robot, scanner = make_cell(job)
    outcome = run_calibration(robot, scanner, MemoryRecorder(), job, semicircle_waypoints(10), clock=clock)
    files = write_outputs(tmp_path, outcome, job)
    solved = run_cli("solve", str(files["observations"]), "--json")
    assert solved.returncode == 1, solved.stderr  # the run failed its tight gate, and so does the solve
    document = json.loads(solved.stdout)
    np.testing.assert_allclose(document["T_base_laser"], outcome.result.T_base_laser, atol=1e-9)
    np.testing.assert_allclose(document["covariance"], outcome.result.model_dump()["covariance"], rtol=1e-6)
    assert document["rod_axis"]["estimated"]
    live_checks = outcome.verdict.as_dict()["checks"]
    assert [(c["name"], c["passed"], c["limit"]) for c in document["verdict"]["checks"]] == [
        (c["name"], c["passed"], c["limit"]) for c in live_checks
    ]
    np.testing.assert_allclose([c["value"] for c in document["verdict"]["checks"]],
                               [c["value"] for c in live_checks], rtol=1e-9)
    # Given explicitly, an option still wins over the file's settings.
    noisier_run = run_cli("solve", str(files["observations"]), "--json", "--robot-sigma-mm", "5")
    noisier = json.loads(noisier_run.stdout)
    assert noisier["std_translation_mm"] != document["std_translation_mm"]


def test_an_unsupported_file_names_both_kinds_solve_reads(tmp_path: Path) -> None:
    readme = tmp_path / "README.md"
    readme.write_text("# not observations\n")
    assert_one_line_error(run_cli("solve", str(readme)), 2, "supported: .csv observations, or a run's .mcap")


def test_formulation_paper_solves_a_runs_file_that_estimates_the_range_curve(tmp_path: Path) -> None:
    """docs/solver.md's `solve observations.csv --formulation paper` on a run's file, whose settings
    estimate the range error curve (the default job's): the paper's problem, the pose alone, with
    a note; asked for explicitly, an estimate the paper cannot make is still refused."""
    from lasercal_hw.calibration.observations import SolveSettings
    from lasercal_hw.calibration.solver import SolverOptions
    from lasercal_hw.config import QualityConfig
    from lasercal_hw.models import RodLine

    path = tmp_path / "observations.csv"
    settings = SolveSettings(RodLine(), SolverOptions(estimate_range_offset=True), QualityConfig())
    write_observations_csv(path, observations(points=30, laser_noise_m=0.003), settings)
    solved = run_cli("solve", str(path), "--formulation", "paper", "--json")
    assert solved.returncode == 0, solved.stderr
    assert "estimates the pose alone, not the range error curve" in solved.stderr
    assert np.linalg.norm(np.array(json.loads(solved.stdout)["T_base_laser"])[:3, 3] - TRUTH[:3, 3]) < 0.03
    explicit = run_cli("solve", str(path), "--formulation", "paper", "--estimate-axis")
    assert_one_line_error(explicit, 2, "cannot estimate the rod axis")
