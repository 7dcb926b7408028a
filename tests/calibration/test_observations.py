"""observations.csv reading/writing and the input-file seam."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lasercal_hw.calibration.observations import (
    load_observations,
    read_observations_csv,
    write_observations_csv,
)
from lasercal_hw.errors import ConfigError
from tests.calibration.test_solver_helpers import observations

HEADER = "index,tcp_x,tcp_y,tcp_z,tcp_rx,tcp_ry,tcp_rz,u,v"


def _write(tmp_path: Path, text: str, name: str = "observations.csv") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_round_trip_keeps_every_value_bit_exact(tmp_path: Path) -> None:
    original = observations(points=7)
    path = tmp_path / "observations.csv"
    write_observations_csv(path, original)
    loaded = load_observations(path)
    assert [o.index for o in loaded] == [o.index for o in original]
    for a, b in zip(original, loaded, strict=True):
        np.testing.assert_array_equal(a.tcp_pose, b.tcp_pose)
        np.testing.assert_array_equal(a.centre_uv_m, b.centre_uv_m)
        np.testing.assert_allclose(a.covariance_uv_m2, b.covariance_uv_m2, rtol=1e-15)


def test_rows_without_sigma_have_no_covariance_and_comments_are_skipped(tmp_path: Path) -> None:
    path = _write(tmp_path, f"# recorded 2026\n{HEADER},note\n3, 0.1,0.2,0.3, 0,0,0, 0.5,-0.25,first\n")
    (obs,) = read_observations_csv(path)
    assert obs.index == 3 and obs.covariance_uv_m2 is None
    np.testing.assert_array_equal(obs.centre_uv_m, [0.5, -0.25])


def test_a_typo_in_a_number_names_line_and_column(tmp_path: Path) -> None:
    path = _write(tmp_path, f"{HEADER}\n0,0.1,0.2,0.3,0,0,0,0.5,0.1\n1,0.1,0.2,0.3,0,0,0,0.5,O.12\n")
    with pytest.raises(ConfigError, match=r"observations.csv line 3, column v: 'O.12' is not a number"):
        read_observations_csv(path)


def test_a_missing_column_is_named(tmp_path: Path) -> None:
    path = _write(tmp_path, "index,tcp_x,tcp_y,tcp_z,tcp_rx,tcp_rz,u,v\n0,1,2,3,4,5,6,7\n")
    with pytest.raises(ConfigError, match=r"missing column\(s\) tcp_ry"):
        read_observations_csv(path)


def test_one_sigma_column_alone_is_rejected(tmp_path: Path) -> None:
    path = _write(tmp_path, f"{HEADER},sigma_u\n0,0,0,0,0,0,0,0,0,0.01\n")
    with pytest.raises(ConfigError, match="column sigma_v is missing"):
        read_observations_csv(path)


@pytest.mark.parametrize(
    ("row", "message"),
    [
        ("0,0,0,0,0,0,0,0,0,0.01,0", "sigma_u and sigma_v must be positive"),
        ("0,0,0,0,0,0,0,0,0,0.01", "10 values, header has 11"),
        ("0.5,0,0,0,0,0,0,0,0,0.01,0.01", "column index: 0.5 is not an integer"),
        ("0,0,0,0,0,0,0,inf,0,0.01,0.01", "column u: 'inf' is not finite"),
    ],
)
def test_bad_rows_are_rejected_with_the_reason(tmp_path: Path, row: str, message: str) -> None:
    path = _write(tmp_path, f"{HEADER},sigma_u,sigma_v\n{row}\n")
    with pytest.raises(ConfigError, match=message):
        read_observations_csv(path)


def test_duplicate_index_names_both_lines(tmp_path: Path) -> None:
    path = _write(tmp_path, f"{HEADER}\n4,0,0,0,0,0,0,0,0\n4,0,0,0,0,0,0,0,0\n")
    with pytest.raises(ConfigError, match="line 3: index 4 repeats line 2"):
        read_observations_csv(path)


def test_missing_empty_and_unsupported_files_are_config_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        load_observations(tmp_path / "nope.csv")
    with pytest.raises(ConfigError, match=r"is a directory; pass the observations\.csv file"):
        load_observations(tmp_path)
    with pytest.raises(ConfigError, match="empty file"):
        load_observations(_write(tmp_path, "\n\n"))
    with pytest.raises(ConfigError, match=r"unsupported file type '.txt' \(supported: .csv\)"):
        load_observations(_write(tmp_path, HEADER, "observations.txt"))


def test_a_quoted_cell_is_read_row_by_row_to_the_same_observations(tmp_path: Path) -> None:
    original = observations(points=5)
    plain = tmp_path / "observations.csv"
    write_observations_csv(plain, original)
    lines = plain.read_text().splitlines()
    quoted = _write(tmp_path, "\n".join([f"{lines[0]},note", *(f'{line},"a, b"' for line in lines[1:])]),
                    "quoted.csv")
    for a, b in zip(read_observations_csv(plain), read_observations_csv(quoted), strict=True):
        assert a.index == b.index
        np.testing.assert_array_equal(a.tcp_pose, b.tcp_pose)
        np.testing.assert_array_equal(a.centre_uv_m, b.centre_uv_m)
        np.testing.assert_array_equal(a.covariance_uv_m2, b.covariance_uv_m2)


def test_a_row_short_of_an_extra_column_is_still_rejected(tmp_path: Path) -> None:
    path = _write(tmp_path, f"{HEADER},note\n0,0,0,0,0,0,0,0,0,a\n1,0,0,0,0,0,0,0,0\n")
    with pytest.raises(ConfigError, match="line 3: 9 values, header has 10"):
        read_observations_csv(path)


def test_a_file_of_only_a_header_has_no_observations(tmp_path: Path) -> None:
    assert read_observations_csv(_write(tmp_path, f"# nothing recorded\n{HEADER}\n")) == []


def test_correlated_covariances_and_solve_settings_round_trip(tmp_path) -> None:
    from lasercal_hw.calibration.observations import SolveSettings, read_solve_settings
    from lasercal_hw.calibration.solver import SolverOptions
    from lasercal_hw.config import QualityConfig
    from lasercal_hw.models import Observation, RodLine

    covariance = np.array([[4e-6, -1.5e-6], [-1.5e-6, 1e-6]])
    written = [Observation(i, np.arange(6.0) + i, np.array([1.0, 0.5]), covariance) for i in range(3)]
    settings = SolveSettings(
        RodLine(origin_m=np.array([0.0, 0.002, 0.1]), direction=np.array([0.0, 0.1, 1.0]), radius_m=0.005),
        SolverOptions(robot_sigma_m=0.002, estimate_axis=True),
        QualityConfig(max_std_translation_mm=3.0),
    )
    path = tmp_path / "observations.csv"
    write_observations_csv(path, written, settings)
    for read in read_observations_csv(path):
        np.testing.assert_allclose(read.covariance_uv_m2, covariance, rtol=1e-12)
    again = read_solve_settings(path)
    assert again is not None and again.solver == settings.solver and again.quality == settings.quality
    np.testing.assert_array_equal(again.rod.origin_m, settings.rod.origin_m)
    assert again.rod.radius_m == 0.005

    path.write_text(path.read_text().replace('"robot_sigma_m":0.002', '"robot_sigma_m":-1'))
    damaged = r"line 1: the lasercal-solve settings are damaged \(solver.robot_sigma_m"
    with pytest.raises(ConfigError, match=damaged):
        read_solve_settings(path)
