"""The solver: exact recovery, statistical efficiency, outliers, degenerate data, paper formulation."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lasercal_hw.calibration.initial import linear_initial_pose
from lasercal_hw.calibration.model import (
    effective_covariance,
    plane_crossing,
    residuals_and_jacobian,
    rod_lines_in_base,
    whiten,
    whitening,
)
from lasercal_hw.calibration.simulate import Protocol, monte_carlo
from lasercal_hw.calibration.solver import SolverOptions, solve
from lasercal_hw.errors import DegenerateDataError
from lasercal_hw.geometry import matrix_to_pose, pose_to_matrix
from lasercal_hw.models import Observation, RodLine
from tests.calibration.test_solver_helpers import TRUTH, observations, translation_error_mm

PAPER_OPTIONS = SolverOptions(default_sigma_uv_m=0.01, robot_sigma_m=0.001)


def _cost(matrix: np.ndarray, obs: list[Observation], options: SolverOptions) -> float:
    poses = np.array([o.tcp_pose for o in obs])
    centres = np.array([o.centre_uv_m for o in obs])
    cov = np.array([o.covariance_uv_m2 for o in obs])
    origins, directions = rod_lines_in_base(poses, RodLine())
    residual, jac, slope = residuals_and_jacobian(matrix[:3, :3], matrix[:3, 3], origins, directions, centres)
    r, _ = whiten(whitening(effective_covariance(cov, slope, options.robot_sigma_m)), residual, jac)
    return float(r @ r)


@pytest.mark.parametrize("robust", [True, False])
def test_noise_free_data_is_recovered_exactly(robust: bool) -> None:
    result = solve(observations(points=20, laser_noise_m=0.0, robot_noise_m=0.0), RodLine(), robust=robust)
    np.testing.assert_allclose(result.matrix(), TRUTH, atol=1e-9)
    np.testing.assert_allclose(result.inverse_matrix() @ result.matrix(), np.eye(4), atol=1e-12)
    assert result.outliers == []
    assert result.rms_residual_mm < 1e-6


def test_linear_start_is_exact_without_noise_and_needs_no_guess() -> None:
    obs = observations(points=8, laser_noise_m=0.0, robot_noise_m=0.0)
    origins, directions = rod_lines_in_base(np.array([o.tcp_pose for o in obs]), RodLine())
    centres = np.array([o.centre_uv_m for o in obs])
    rotation, translation, _ = linear_initial_pose(origins, directions, centres, np.ones(len(obs)))
    np.testing.assert_allclose(rotation, TRUTH[:3, :3], atol=1e-9)
    np.testing.assert_allclose(translation, TRUTH[:3, 3], atol=1e-9)


@pytest.mark.parametrize(
    ("points", "tilt_deg", "noise_m"),
    [(75, 20.0, 0.01), (8, 5.0, 0.01), (6, 20.0, 0.02), (12, 3.0, 0.005)],
)
def test_solution_reaches_the_global_minimum_from_the_linear_start(
    points: int, tilt_deg: float, noise_m: float
) -> None:
    """The converged cost is no worse than the cost at the truth (a local minimum far
    from the truth would be worse) and the linear start was good enough to get there."""
    options = SolverOptions(default_sigma_uv_m=noise_m, robot_sigma_m=0.001)
    for seed in range(5):
        obs = observations(seed, points=points, tilt_deg=tilt_deg, laser_noise_m=noise_m)
        result = solve(obs, RodLine(), robust=False, options=options)
        assert _cost(result.matrix(), obs, options) <= _cost(TRUTH, obs, options) + 1e-9


def test_monte_carlo_errors_match_the_cramer_rao_bound() -> None:
    summary = monte_carlo(60, 11, Protocol())
    assert 0.8 < summary.rms_translation_mm / summary.crb_rms_translation_mm < 1.25
    assert 0.8 < summary.rms_rotation_deg / summary.crb_rms_rotation_deg < 1.25
    assert summary.mean["xyz"] < 9.581 and summary.mean["rot"] < 0.800  # below the paper's Table 1


def test_reported_std_agrees_with_the_bound_when_the_noise_model_is_right() -> None:
    result = solve(observations(3), RodLine(), options=PAPER_OPTIONS)
    assert 0.7 < result.reduced_chi_square < 1.3
    np.testing.assert_allclose(result.std_translation_mm, result.crb_translation_mm, rtol=0.2)
    np.testing.assert_allclose(result.std_euler_zyx_deg, result.crb_euler_zyx_deg, rtol=0.2)


def test_one_wrong_observation_is_flagged_and_does_not_pull_the_result() -> None:
    obs = observations(5, points=20)
    bad = 7
    obs[bad] = dataclasses.replace(obs[bad], centre_uv_m=obs[bad].centre_uv_m + np.array([0.2, 0.0]))
    result = solve(obs, RodLine(), options=PAPER_OPTIONS)
    assert [o.index for o in result.outliers] == [bad]
    assert "chi-square" in result.outliers[0].reason
    assert result.outliers[0].residual_mm > 150
    assert not result.residuals[bad].used and result.waypoints_used == 19
    clean = solve([o for o in obs if o.index != bad], RodLine(), options=PAPER_OPTIONS)
    np.testing.assert_allclose(result.matrix(), clean.matrix(), atol=1e-8)
    assert translation_error_mm(result.matrix()) < 2 * np.linalg.norm(result.crb_translation_mm)
    plain = solve(obs, RodLine(), robust=False, options=PAPER_OPTIONS)
    assert plain.outliers == []
    assert translation_error_mm(plain.matrix()) > translation_error_mm(result.matrix())


def test_an_optimistic_noise_model_inflates_the_std_instead_of_rejecting_everything() -> None:
    noisy = observations(9, points=40, laser_noise_m=0.03)
    obs = [dataclasses.replace(o, covariance_uv_m2=None) for o in noisy]
    result = solve(obs, RodLine(), options=SolverOptions(default_sigma_uv_m=0.005, robot_sigma_m=0.001))
    honest = solve(obs, RodLine(), options=SolverOptions(default_sigma_uv_m=0.03, robot_sigma_m=0.001))
    assert len(result.outliers) <= 2
    assert 20 < result.reduced_chi_square < 60
    assert any("times the stated noise" in note for note in result.observability.notes)
    np.testing.assert_allclose(result.std_translation_mm, honest.std_translation_mm, rtol=0.25)


def test_fewer_than_five_waypoints_are_refused() -> None:
    with pytest.raises(DegenerateDataError, match="at least 5"):
        solve(observations(points=4), RodLine())


def test_parallel_rod_axes_are_refused_with_advice() -> None:
    with pytest.raises(DegenerateDataError, match=r"parallel.*translation along the rod.*tilting the rod"):
        solve(observations(points=30, tilt_deg=1e-9), RodLine())


def test_rod_axes_in_the_scan_plane_are_refused() -> None:
    obs = observations(points=20, laser_noise_m=0.0, robot_noise_m=0.0)
    # Re-point every rod nearly along the scan plane's x axis (2 deg off), through the same crossing.
    plane_x, normal = TRUTH[:3, 0], TRUTH[:3, 2]
    flat = []
    for k, o in enumerate(obs):
        crossing = TRUTH[:3, :3] @ np.array([*o.centre_uv_m, 0.0]) + TRUTH[:3, 3]
        turn = np.radians(30.0 * np.sin(k))
        in_plane = np.cos(turn) * plane_x + np.sin(turn) * np.cross(normal, plane_x)
        d = np.cos(np.radians(2.0)) * in_plane - np.sin(np.radians(2.0)) * normal
        z_axis = d / np.linalg.norm(d)
        x_axis = np.cross([0.0, 0.0, 1.0], z_axis)
        x_axis /= np.linalg.norm(x_axis)
        tcp = np.eye(4)
        tcp[:3, :3] = np.column_stack([x_axis, np.cross(z_axis, x_axis), z_axis])
        tcp[:3, 3] = crossing - 0.2 * z_axis
        flat.append(dataclasses.replace(o, tcp_pose=matrix_to_pose(tcp)))
    with pytest.raises(DegenerateDataError, match="nearly in the scan plane"):
        solve(flat, RodLine())


def test_rods_through_one_point_name_the_unobservable_rotation() -> None:
    rng = np.random.default_rng(2)
    crossing_uv = np.array([0.4, -0.3])
    crossing = TRUTH[:3, :3] @ np.array([*crossing_uv, 0.0]) + TRUTH[:3, 3]
    obs = []
    for k in range(12):
        tcp = pose_to_matrix(np.array([0, 0, 0, np.pi + rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), 0]))
        tcp[:3, 3] = crossing - 0.3 * tcp[:3, 2]
        obs.append(Observation(index=k, tcp_pose=matrix_to_pose(tcp), centre_uv_m=crossing_uv))
    expected = r"3 directions \(rotation about base axis .* through \(0\.7\d, 0\.2\d, 0\.1\d\) m.*\) are not"
    expected += r" observable .*spread the crossing points"
    with pytest.raises(DegenerateDataError, match=expected):
        solve(obs, RodLine())


def test_non_finite_values_are_refused_naming_the_waypoint() -> None:
    obs = observations(points=10)
    obs[3] = dataclasses.replace(obs[3], centre_uv_m=np.array([np.nan, 0.1]))
    with pytest.raises(DegenerateDataError, match=r"waypoint\(s\) 3 contain NaN"):
        solve(obs, RodLine())


def test_rod_offset_from_the_tcp_is_honoured() -> None:
    rod = RodLine(origin_m=np.array([0.01, -0.02, 0.05]), direction=np.array([0.1, 0.0, 1.0]))
    poses = np.array([o.tcp_pose for o in observations(points=15)])
    origins, directions = rod_lines_in_base(poses, rod)
    crossing, _, _ = plane_crossing(TRUTH[:3, :3], TRUTH[:3, 3], origins, directions)
    obs = [
        Observation(index=i, tcp_pose=p, centre_uv_m=c)
        for i, (p, c) in enumerate(zip(poses, crossing, strict=True))
    ]
    np.testing.assert_allclose(solve(obs, rod).matrix(), TRUTH, atol=1e-9)


def test_paper_formulation_converges_on_the_paper_protocol() -> None:
    obs = observations(8)
    ours = solve(obs, RodLine(), options=PAPER_OPTIONS)
    paper = solve(obs, RodLine(), options=PAPER_OPTIONS, formulation="paper")
    assert paper.provenance.formulation == "paper" and paper.provenance.converged
    bound_mm = np.linalg.norm(paper.crb_translation_mm)
    assert translation_error_mm(paper.matrix()) < 4 * bound_mm
    assert np.linalg.norm(paper.matrix()[:3, 3] - ours.matrix()[:3, 3]) * 1e3 < bound_mm


def test_result_document_is_json_ready() -> None:
    document = solve(observations(points=10), RodLine()).to_json_dict()
    assert np.array(document["T_base_laser"]).shape == (4, 4)
    assert document["provenance"]["solver_options"]["robust"] is True
    assert document["provenance"]["software_version"]
    assert len(document["residuals"]) == 10
