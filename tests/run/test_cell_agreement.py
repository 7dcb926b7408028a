"""The cell's agreement test over the centres two scanners saw at one waypoint
(``run/cell.pair_agreement``): a watcher's centre where, by the solved poses, the rod ends short
of its plane, or farther from the rod than its radius, is not the rod's and is left out, saying
why; the rest still decide. Each centre loses what is left in it of its scanner's range error
curve, and its covariance grows with its solve's reduced chi-square (never shrinks)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from lasercal_hw.calibration.result import RangeErrorPoint, RangeOffset
from lasercal_hw.config import load_job
from lasercal_hw.geometry import euler_zyx_to_matrix, make_transform, matrix_to_pose
from lasercal_hw.run.cell import RecordedCentres, ScannerOutcome, first_pass_scatter_uv_m2, pair_agreement
from lasercal_hw.run.watchers import SolvedWatcher, as_first_pass
from lasercal_hw.scan.extraction import RodCentre, RodQuality

REPO = Path(__file__).resolve().parents[2]
JOB = load_job(REPO / "examples" / "cell.toml")  # a 0.30 m rod along the TCP's z axis
T_FRONT = make_transform(euler_zyx_to_matrix(*np.radians([5.0, 7.0, 3.0])), np.array([0.30, 0.50, 0.20]))
T_REAR = make_transform(euler_zyx_to_matrix(*np.radians([45.0, -6.0, 5.0])), np.array([-0.45, -0.40, 0.30]))
COVARIANCE_UV_M2 = np.eye(2) * 0.0003**2
POSE_COVARIANCE = np.diag([1e-8] * 3 + [np.radians(0.01) ** 2] * 3)
#: A rod pointing down, tilted 10 deg: the TCP at these heights puts both planes across it,
#: the last one ends above the front's plane.
TCP_POINTS_M = [(-0.10, -0.05, 0.45), (0.05, -0.15, 0.46), (-0.20, 0.05, 0.44), (0.0, 0.10, 0.45),
                (-0.05, -0.10, 0.55)]


def _tcp_pose(point_m: tuple[float, float, float]) -> np.ndarray:
    down = euler_zyx_to_matrix(0.0, np.radians(10.0), np.pi)
    return matrix_to_pose(make_transform(down, np.asarray(point_m)))


def _crossing_uv_m(T_base_laser: np.ndarray, tcp_pose: np.ndarray) -> np.ndarray:
    """Where the rod's line (extended past its ends) crosses the scanner's plane."""
    tcp = make_transform(euler_zyx_to_matrix(0.0, np.radians(10.0), np.pi), tcp_pose[:3])
    origin, direction = tcp[:3, 3], tcp[:3, 2]
    normal, point = T_base_laser[:3, 2], T_base_laser[:3, 3]
    along_m = normal @ (point - origin) / (normal @ direction)
    return (T_base_laser[:3, :3].T @ (origin + along_m * direction - point))[:2]


def _outcome(name: str, T_base_laser: np.ndarray) -> ScannerOutcome:
    return ScannerOutcome(name, Path(), True, T_base_laser.tolist(), POSE_COVARIANCE.tolist(), None, None,
                          JOB.for_scanner(name).rod.rod_line(), reduced_chi_square=2.0)


def _agreement_with_the_front_finding(index: int, off_m: float) -> tuple[list[str], dict]:
    """The rear's waypoints, each seen by both scanners; at ``index`` the front scanner found
    something ``off_m`` along its u axis from where the rod's line crosses its plane."""
    poses = [_tcp_pose(p) for p in TCP_POINTS_M]
    own = {i: (pose, _crossing_uv_m(T_REAR, pose), COVARIANCE_UV_M2) for i, pose in enumerate(poses)}
    watched = {i: (pose, _crossing_uv_m(T_FRONT, pose), COVARIANCE_UV_M2) for i, pose in enumerate(poses)}
    watched[index] = (poses[index], watched[index][1] + [off_m, 0.0], COVARIANCE_UV_M2)
    centres: dict[str, RecordedCentres] = {"front": {}, "rear": {None: own, "front": watched}}
    outcomes = {"front": _outcome("front", T_FRONT), "rear": _outcome("rear", T_REAR)}
    shared, agreement = pair_agreement("front", "rear", outcomes, centres, JOB)
    return [s.waypoint for s in shared], agreement


def test_a_centre_where_the_rod_ends_short_of_the_watchers_plane_is_left_out() -> None:
    last = len(TCP_POINTS_M) - 1  # what the front found where its nominal pose put the rod: 12 mm off

    shared, agreement = _agreement_with_the_front_finding(last, 0.012)

    assert shared == [f"rear {i}" for i in range(last)]
    assert agreement["left_out"] == [f"rear {last}"]
    assert "the rod ends short of a plane" in agreement["reason"], agreement["reason"]
    assert agreement["verdict"] == "agree", agreement


def test_a_centre_farther_from_the_rod_than_its_radius_is_left_out_and_a_nearer_one_kept() -> None:
    shared, agreement = _agreement_with_the_front_finding(1, 0.05)  # the rod crosses, something else found
    assert "rear 1" not in shared and agreement["left_out"] == ["rear 1", "rear 4"]
    assert agreement["verdict"] == "agree", agreement

    shared, agreement = _agreement_with_the_front_finding(1, 0.012)  # off, but it could be the rod: tested
    assert "rear 1" in shared
    assert agreement["verdict"] == "disagree", agreement


def test_the_agreement_gives_the_centres_it_compared_by_scanner() -> None:
    """What cell.json's agreement and the job's ``pair_agreement`` event show: at each tested
    waypoint both scanners' centres and covariances as the test took them (here no range error
    to move them back; each covariance scaled by its solve's reduced chi-square, 2)."""
    shared, agreement = _agreement_with_the_front_finding(1, 0.004)
    pose = _tcp_pose(TCP_POINTS_M[1])

    tested = agreement["centres"]

    assert [entry["waypoint"] for entry in tested] == shared == agreement["waypoints"]
    assert tested[1]["waypoint"] == "rear 1"
    found_uv_m = np.add(_crossing_uv_m(T_FRONT, pose), [0.004, 0.0])
    np.testing.assert_allclose(tested[1]["centres_uv_m"]["front"], found_uv_m)
    np.testing.assert_allclose(tested[1]["centres_uv_m"]["rear"], _crossing_uv_m(T_REAR, pose))
    for name in ("front", "rear"):
        np.testing.assert_allclose(tested[1]["covariances_uv_m2"][name], 2.0 * COVARIANCE_UV_M2)


def _agreement_with_every_front_centre_off(
    off_m: float, scatter_uv_m2: np.ndarray | None, *, front: ScannerOutcome | None = None
) -> dict:
    """The rear's first four waypoints, each front centre ``off_m`` along u and -v (a first-pass
    centre's error) and carrying the front's first-pass scatter as given (``as_first_pass``: a
    watcher's centre whose second pass found no rod)."""
    poses = [_tcp_pose(p) for p in TCP_POINTS_M[:4]]
    own = {i: (pose, _crossing_uv_m(T_REAR, pose), COVARIANCE_UV_M2) for i, pose in enumerate(poses)}
    view = SolvedWatcher(T_FRONT, JOB.rod.rod_line(), None, scatter_uv_m2)
    watched = {}
    for i, pose in enumerate(poses):
        found = RodCentre(_crossing_uv_m(T_FRONT, pose) + np.array([off_m, -off_m]), COVARIANCE_UV_M2,
                          RodQuality(10, 0.0, 30.0, None, 0))
        centre = as_first_pass(found, view)
        watched[i] = (pose, centre.centre_uv_m, centre.covariance_uv_m2)
    centres: dict[str, RecordedCentres] = {"front": {}, "rear": {None: own, "front": watched}}
    outcomes = {"front": front or _outcome("front", T_FRONT), "rear": _outcome("rear", T_REAR)}
    return pair_agreement("front", "rear", outcomes, centres, JOB)[1]


def test_a_watchers_first_pass_error_within_its_scanners_first_pass_scatter_agrees() -> None:
    # The front's own waypoints: its first-pass centres 2 mm from its solved ones either way.
    first = {i: np.array([0.5 + 0.01 * i, 0.1]) for i in range(4)}
    solved = {i: first[i] + (-1) ** i * np.array([0.002, -0.002]) for i in range(4)}
    front = _outcome("front", T_FRONT)
    scatter = first_pass_scatter_uv_m2(first, solved, front)
    assert np.allclose(scatter, [[4e-6, -4e-6], [-4e-6, 4e-6]])
    assert first_pass_scatter_uv_m2(dict(list(first.items())[:2]), solved, front) is None

    assert _agreement_with_every_front_centre_off(0.002, None)["verdict"] == "disagree"
    assert _agreement_with_every_front_centre_off(0.002, scatter)["verdict"] == "agree"
    assert _agreement_with_every_front_centre_off(0.012, scatter)["verdict"] == "disagree"


def test_a_solves_reduced_chi_square_above_one_widens_its_centres_and_below_one_never_narrows_them() -> None:
    def front_fitting(reduced_chi_square: float) -> dict:  # its centres 1.5 mm off, 0.3 mm std
        front = replace(_outcome("front", T_FRONT), reduced_chi_square=reduced_chi_square)
        return _agreement_with_every_front_centre_off(0.0015, None, front=front)

    assert front_fitting(1.0)["verdict"] == "disagree"
    assert front_fitting(30.0)["verdict"] == "agree"  # its solve showed its centres 5.5 times worse
    assert front_fitting(0.1)["chi_square"] == front_fitting(1.0)["chi_square"]


def _constant_range_error(error_mm: float) -> RangeOffset:
    """A range error of ``error_mm`` at every distance over 0.3-1.5 m."""
    curve = [RangeErrorPoint(distance_m=d, error_mm=error_mm, std_mm=0.1) for d in (0.3, 0.9, 1.5)]
    return RangeOffset(offset_mm=error_mm, std_mm=0.1, terms_mm=[error_mm], terms_std_mm=[0.1], curve=curve)


def _agreement_with_the_rear_reading_long(reads_long_mm: float, applied_mm: float) -> dict:
    """The rear's solved centres each ``reads_long_mm`` beyond the rod along its bearing, the rear's
    range error 5 mm at every distance, of which its second pass took out ``applied_mm``."""
    poses = [_tcp_pose(p) for p in TCP_POINTS_M[:4]]
    own = {}
    for i, pose in enumerate(poses):
        uv = _crossing_uv_m(T_REAR, pose)
        own[i] = (pose, uv * (1.0 + reads_long_mm / 1000.0 / np.linalg.norm(uv)), COVARIANCE_UV_M2)
    watched = {i: (pose, _crossing_uv_m(T_FRONT, pose), COVARIANCE_UV_M2) for i, pose in enumerate(poses)}
    centres: dict[str, RecordedCentres] = {"front": {}, "rear": {None: own, "front": watched}}
    rear = replace(_outcome("rear", T_REAR), range_offset=_constant_range_error(5.0),
                   range_offset_applied_m=applied_mm / 1000.0)
    outcomes = {"front": _outcome("front", T_FRONT), "rear": rear}
    return pair_agreement("front", "rear", outcomes, centres, JOB)[1]


def test_a_solved_centre_loses_what_its_second_pass_left_of_the_range_error() -> None:
    # The solver models the curve less the applied offset in the solved centres: they read long by it.
    assert _agreement_with_the_rear_reading_long(5.0, applied_mm=0.0)["verdict"] == "agree"
    assert _agreement_with_the_rear_reading_long(2.0, applied_mm=3.0)["verdict"] == "agree"
    assert _agreement_with_the_rear_reading_long(0.0, applied_mm=5.0)["verdict"] == "agree"
    # Read as if the applied offset had taken out all of it, 5 mm long is a disagreement.
    assert _agreement_with_the_rear_reading_long(5.0, applied_mm=5.0)["verdict"] == "disagree"
