"""Search semicircle parameters that minimise the Cramér-Rao bound (not collected by pytest).

Run from the repository root::

    .venv/bin/python -m benchmarks.preset_design [--preset paper] [--config examples/drill.toml]
        [--samples 3000] [--seed 0]

Starting from a preset's parameters, draws random variations (centre, radii, heights,
arc start, tilt, tool yaw, tilt pattern seed), keeps those whose every waypoint passes
the layout rules of the default scene (the rod crosses the true scan plane inside the
rod with a margin at both ends, 0.35-1.5 m from the scanner and 5 degrees inside the
field of view, line of sight clear of the base column, the offline preflight, one IK
branch without a wrist flip or big jump), and scores them by the CRB with the solver's
noise model: ``max(max translation std / 2 mm, max rotation std / 0.3 deg)``.
The best candidate's parameters are printed to paste into ``trajectories/presets.py``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from benchmarks.dry_run_accuracy import crb_std
from fakes.world import World
from lasercal_hw.config import WorkspaceConfig, load_job
from lasercal_hw.geometry import matrix_to_pose
from lasercal_hw.models import RodLine
from lasercal_hw.ur5_kinematics import inverse_kinematics_pose
from trajectories.checks import check_waypoints
from trajectories.plane_crossing import rod_plane_crossings
from trajectories.presets import get_preset
from trajectories.semicircles import SemicircleParameters, semicircle_waypoints
from trajectories.waypoint import Waypoint, waypoint_matrices

FOV_LIMIT_RAD = np.deg2rad(135.0 - 5.0)
COLUMN_CLEARANCE_M = 0.13
#: Elbow angle kept (a margin over the preset tests' 0.3 rad, so rounded parameters still pass).
ELBOW_MIN_RAD = 0.45
Q_START = np.array([np.pi, -np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2, 0.0])


#: Crossing distance from the scanner (m); a thin drill bit needs a tighter maximum.
RANGE_LIMITS_M = (0.3, 1.5)


def layout_violation(
    matrices: np.ndarray,
    rod: RodLine,
    T_base_laser: np.ndarray,
    end_margin_m: float,
    range_limits_m: tuple[float, float] = RANGE_LIMITS_M,
) -> float:
    """How far (summed over waypoints, metres or radians) the scanner-side rules are broken:
    crossing on the rod with a margin, in range and view, not behind the column; 0 when kept."""
    crossings = rod_plane_crossings(matrices, rod, T_base_laser)
    s = np.nan_to_num(crossings.along_rod_m, nan=-1.0, posinf=-1.0, neginf=-1.0)
    excess = np.maximum(0.0, end_margin_m - s) + np.maximum(0.0, s - (rod.length_m - end_margin_m))
    excess += np.maximum(0.0, range_limits_m[0] - crossings.range_m)
    excess += np.maximum(0.0, crossings.range_m - range_limits_m[1])
    excess += np.maximum(0.0, np.abs(crossings.bearing_rad) - FOV_LIMIT_RAD)
    points = crossings.uv_m @ T_base_laser[:2, :2].T + T_base_laser[:2, 3]
    scanner = T_base_laser[:2, 3]
    beam = points - scanner
    along = np.clip((-scanner @ beam.T) / np.sum(beam * beam, axis=1), 0.0, 1.0)
    excess += np.maximum(0.0, COLUMN_CLEARANCE_M - np.linalg.norm(scanner + along[:, None] * beam, axis=1))
    return float(np.nan_to_num(excess, nan=1.0).sum())


def arm_ok(poses: np.ndarray, rods: list[RodLine]) -> bool:
    """Preflight (IK, workspace box with every rod) and one branch without flips or big jumps."""
    for rod in rods:
        report = check_waypoints(
            [Waypoint(index=i, tcp_pose=tuple(float(v) for v in p)) for i, p in enumerate(poses)],
            inverse_kinematics=inverse_kinematics_pose,
            workspace=WorkspaceConfig(),
            rod=rod,
        )
        if not report.ok:
            return False
    q = Q_START
    trajectory = []
    for pose in poses:
        q = inverse_kinematics_pose(pose, q)
        if q is None:
            return False
        trajectory.append(q)
    joints = np.array(trajectory)
    return bool(
        np.all(joints[:, 2] > ELBOW_MIN_RAD)
        and np.all(joints[:, 4] < -0.5)
        and np.abs(np.diff(joints, axis=0)).max() < 1.6
    )


def score(crb_t_mm: np.ndarray, crb_r_deg: np.ndarray) -> float:
    """The design objective: the worse of the translation and rotation bounds, each relative
    to the acceptance limit (2 mm, 0.3 deg)."""
    return max(float(crb_t_mm.max()) / 2.0, float(crb_r_deg.max()) / 0.3)


def evaluate(
    params: SemicircleParameters,
    rods: list[RodLine],
    T_base_laser: np.ndarray,
    end_margin_m: float,
    robot_sigma_m: float,
    range_limits_m: tuple[float, float] = RANGE_LIMITS_M,
) -> tuple[float, float, np.ndarray, np.ndarray]:
    """(rule violation, score, CRB translation mm, CRB rotation deg) of a parameter set; the
    CRB is that of the last rod (the job's) and only computed when no rule is broken."""
    waypoints = semicircle_waypoints(params.model_copy(update={"scan_plane_z_m": None}))
    matrices = waypoint_matrices(waypoints)
    violation = sum(
        layout_violation(matrices, rod, T_base_laser, end_margin_m, range_limits_m) for rod in rods
    )
    if violation > 0.0:
        return violation, np.inf, np.full(3, np.inf), np.full(3, np.inf)
    crb_t, crb_r = crb_std(matrix_to_pose(matrices), rods[-1], T_base_laser, robot_sigma_m=robot_sigma_m)
    return 0.0, score(crb_t, crb_r), crb_t, crb_r


def perturb(params: SemicircleParameters, rng: np.random.Generator, scale: float) -> SemicircleParameters:
    """A random neighbour of ``params`` (``scale`` 1: wide steps)."""
    cx, cy = params.centre_m
    radii = [max(0.05, r + rng.normal(0, 0.05 * scale)) for r in params.radii_m]
    heights = [h + rng.normal(0, 0.03 * scale) for h in params.heights_m]
    span = params.end_deg - params.start_deg
    start = params.start_deg + rng.normal(0, 20 * scale)
    update = {
        "centre_m": (cx + rng.normal(0, 0.05 * scale), cy + rng.normal(0, 0.05 * scale)),
        "radii_m": tuple(radii),
        "heights_m": tuple(heights),
        "start_deg": start,
        "end_deg": start + span,
        "tilt_deg": float(np.clip(params.tilt_deg + rng.normal(0, 3 * scale), 5.0, 30.0)),
        "tool_yaw_deg": params.tool_yaw_deg + rng.normal(0, 30 * scale),
    }
    if rng.random() < 0.2 * scale:
        update["seed"] = None if rng.random() < 0.3 else int(rng.integers(0, 1000))
    return params.model_copy(update=update)


def random_parameters(
    params: SemicircleParameters, rng: np.random.Generator, max_tilt_deg: float
) -> SemicircleParameters:
    """A random parameter set anywhere in front of the robot, with ``params``' arc count and step."""
    arcs = len(params.radii_m)
    start = float(rng.uniform(-180.0, 180.0))
    return params.model_copy(
        update={
            "centre_m": (float(rng.uniform(0.1, 0.8)), float(rng.uniform(-0.5, 0.6))),
            "radii_m": tuple(float(r) for r in rng.uniform(0.08, 0.5, arcs)),
            "heights_m": tuple(float(h) for h in rng.uniform(0.22, 0.5, arcs)),
            "start_deg": start,
            "end_deg": start + (params.end_deg - params.start_deg),
            "tilt_deg": float(rng.uniform(10.0, max_tilt_deg)),
            "tool_yaw_deg": float(rng.uniform(-180.0, 180.0)),
            "seed": None if rng.random() < 0.5 else int(rng.integers(0, 1000)),
        }
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="paper")
    parser.add_argument("--config", type=Path, default=None, help="job file whose rod the CRB uses")
    parser.add_argument("--start", default=None, help="JSON object of parameters to start from instead")
    parser.add_argument("--global-samples", type=int, default=0, help="random draws before the local search")
    parser.add_argument("--samples", type=int, default=3000, help="local perturbations of the best")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--end-margin", type=float, default=0.04, help="crossing distance from the rod ends (m)"
    )
    parser.add_argument("--max-tilt", type=float, default=30.0)
    parser.add_argument(
        "--range", type=float, nargs=2, default=RANGE_LIMITS_M, help="crossing range limits (m)"
    )
    parser.add_argument(
        "--min-radius-step", type=float, default=0.1, help="least difference of the radii (m)"
    )
    parser.add_argument(
        "--min-height-step", type=float, default=0.05, help="least difference of the heights (m)"
    )
    args = parser.parse_args()

    preset = get_preset(args.preset)
    job = load_job(args.config)
    job_rod = job.rod.rod_line() if args.config is not None else preset.rod
    robot_sigma_m = job.robot.position_accuracy_mm / 1000.0
    T_base_laser = World.from_scene(None).ground_truth_T_base_laser
    rng = np.random.default_rng(args.seed)

    best = preset.parameters
    if args.start is not None:
        best = best.model_copy(update=json.loads(args.start))
    rods = [preset.rod, job_rod]
    limits = (args.end_margin, robot_sigma_m, tuple(args.range))

    def poses_of(params: SemicircleParameters) -> np.ndarray:
        return matrix_to_pose(
            waypoint_matrices(semicircle_waypoints(params.model_copy(update={"scan_plane_z_m": None})))
        )

    best_violation, best_score, crb_t, crb_r = evaluate(best, rods, T_base_laser, *limits)
    if best_violation == 0.0 and not arm_ok(poses_of(best), rods):
        best_violation = 1e-9  # the arm rules fail: any layout-clean, reachable candidate is better
    print(
        f"start: violation {best_violation:.3f}, score {best_score:.3f}, CRB t {np.round(crb_t, 2)} mm "
        f"r {np.round(crb_r, 3)} deg"
    )
    for k in range(args.global_samples + args.samples):
        if k < args.global_samples:
            candidate = random_parameters(best, rng, args.max_tilt)
        else:
            scale = 1.0 if k < args.global_samples + args.samples // 2 else 0.4
            candidate = perturb(best, rng, scale)
        if (
            candidate.tilt_deg > args.max_tilt
            or np.ptp(candidate.radii_m) < args.min_radius_step
            or np.ptp(candidate.heights_m) < args.min_height_step
        ):
            continue
        violation, value, crb_t, crb_r = evaluate(candidate, rods, T_base_laser, *limits)
        if violation > 0.0:
            if violation < best_violation:
                best, best_violation = candidate, violation
            continue
        if value >= best_score and best_violation == 0.0:
            continue
        if not arm_ok(poses_of(candidate), rods):
            continue
        best, best_violation, best_score = candidate, 0.0, value
        print(f"{k}: score {value:.3f}, CRB t {np.round(crb_t, 2)} mm r {np.round(crb_r, 3)} deg", flush=True)
    print("\nbest parameters:")
    print(best.model_dump_json(indent=1))


if __name__ == "__main__":
    main()
