"""A twist drill's centres against its turn: is the centre's offset from the axis a function of
the bit's turn relative to the beam, and does ``calibration/flutes.py`` model it? Offline, on the
drill job as shipped (``accuracy_conditions``' ``drill-fluted`` case), not collected by pytest.

Run from the repository root::

    .venv/bin/python -m benchmarks.flute_phase [--seeds 3] [--first-seed 100] [--bias-off]
        [--case drill-fluted|drill-fluted-any-turn] [--bins-only]

Per seed, the job's waypoints are dwelt on (physical scanner model, the scene's fluted steel
drill; with ``--case drill-fluted-any-turn`` turned in its chuck as that case draws it per
seed) and each centre is extracted with the bit's *true* axis as a plain ellipse fit (no
``fluted`` allowance); its offset from the true axis crossing is split along the beam's
bearing (+: behind the axis) and across it, and set beside the bit's true turn there (the
angle from a flute's middle to the scanner, 0: a flute faces it; the fake turns the bit with
the tool and along its 30 deg helix) and ``flute_offsets_m`` at the true turn. ``--bias-off``:
the scanner's range bias off (else the fake's range error is in the along column).
Printed: one row per centre, sorted by turn, with the crossing's range, the centre's beams' mean
intensity and the fake's range bias at both (what to take out of the along column to compare
it with the model when the bias is on), then the RMS of the offsets and of what the model
leaves, along and across, and the same binned by the turn (10 deg bins from a flute's middle:
the model's error is not the same at every turn; ``run/flute_phase.py`` still widens every
centre by one flat allowance, and a table-shaped one did not pay off: docs/lab/solver-log.md,
"A facing-dependent allowance").
``--bins-only``: the summary and the bins without the per-centre rows.
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks.accuracy_conditions import ROBOT_ERROR_SEED_BASE, cases, seeded_scene
from benchmarks.dry_run_accuracy import dwell, world_with
from benchmarks.error_budget import _bias_off
from fakes.scanner_model.range_error import range_bias_m
from fakes.scene import load_scene
from lasercal_hw.calibration.flutes import facing_angles_rad, flute_offsets_m
from lasercal_hw.geometry import matrix_to_rotvec, pose_to_matrix
from lasercal_hw.models import RodLine
from lasercal_hw.run.retract import retract_candidates
from lasercal_hw.run.waypoints import listed_waypoints
from lasercal_hw.scan.extraction import RodNotFoundError, find_rod_centre

#: The fake's flute middle lies along (bit axis x TCP x) where the bit starts: a turn of 90 deg
#: plus the bit's turn in its chuck.
UNTURNED_PHASE0_DEG = 90.0
#: The width of the turn's bins (deg, from a flute's middle: 0-90).
BIN_DEG = 10.0


def rows(seed: int, bias_off: bool, case_name: str = "drill-fluted") -> list[tuple[float, ...]]:
    """(turn deg, along mm, across mm, model along mm, model across mm, range m, intensity,
    the fake's range bias at that range and intensity mm) per found centre."""
    case = {c.name: c for c in cases()}[case_name]
    scene = seeded_scene(load_scene(case.scene_path).model_copy(update={"model": "physical"}), case, seed)
    scene = _bias_off(scene) if bias_off else scene
    phase0_rad = float(np.radians(UNTURNED_PHASE0_DEG + scene.rod.chuck_turn_deg))
    world = world_with(scene, case.true_rod, ROBOT_ERROR_SEED_BASE + seed)
    job = case.job
    rng = np.random.default_rng(seed)
    waypoints = listed_waypoints(job)
    scans = round(case.dwell_s / scene.scanner.scan_period_s)
    background = dwell(world, retract_candidates(job, waypoints)[0], job.background.scans, rng)
    T = world.ground_truth_T_base_laser
    found = []
    for pose in waypoints:
        averaged = dwell(world, pose, scans, rng)
        true_tcp = world.robot_error.true_pose(pose_to_matrix(pose))
        point, axis = world.rod_shape_in_scanner(true_tcp)
        crossing = point[:2] - point[2] / axis[2] * axis[:2]
        try:
            centre = find_rod_centre(
                averaged,
                radius_m=case.true_rod.radius_m,
                background=background,
                axis_in_scanner=axis if axis[2] > 0 else -axis,
                expected_uv_m=crossing,
            )
        except RodNotFoundError:
            continue
        true_pose = np.concatenate([true_tcp[:3, 3], matrix_to_rotvec(true_tcp[:3, :3])])
        model = flute_offsets_m(phase0_rad, T, true_pose[None, :], case.true_rod)[0]
        bearing = crossing / np.linalg.norm(crossing)
        across = np.array([-bearing[1], bearing[0]])
        offset = centre.centre_uv_m - crossing
        turn = _turn_deg(phase0_rad, T, true_pose, case.true_rod)
        distance_m = float(np.linalg.norm(crossing))
        intensity = float(np.mean(averaged.intensities[centre.beam_indices]))
        bias_mm = 1e3 * float(range_bias_m(np.array([distance_m]), np.array([intensity]), scene.physics)[0])
        found.append(
            (
                turn,
                offset @ bearing * 1e3,
                offset @ across * 1e3,
                model @ bearing * 1e3,
                model @ across * 1e3,
                distance_m,
                intensity,
                bias_mm,
            )
        )
    return found


def _turn_deg(phase0_rad: float, T_base_laser: np.ndarray, pose: np.ndarray, rod: RodLine) -> float:
    """The angle from the nearest flute's middle to the scanner, seen from the bit (deg, 0-90)."""
    angle = float(np.degrees(facing_angles_rad(phase0_rad, T_base_laser, pose[None, :], rod)[0]))
    return abs((angle + 90.0) % 180.0 - 90.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--first-seed", type=int, default=100)
    parser.add_argument("--bias-off", action="store_true")
    parser.add_argument("--case", default="drill-fluted", choices=["drill-fluted", "drill-fluted-any-turn"])
    parser.add_argument("--bins-only", action="store_true")
    args = parser.parse_args()
    table = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        table += rows(seed, args.bias_off, args.case)
    table.sort()
    if not args.bins_only:
        print_rows(table)
    a = np.array(table)
    print(
        f"\n{len(a)} centres: offset RMS along {_rms(a[:, 1]):.2f} mm, across {_rms(a[:, 2]):.2f} mm; "
        f"left by the model along {_rms(a[:, 1] - a[:, 3]):.2f} mm, across {_rms(a[:, 2] - a[:, 4]):.2f} mm"
    )
    print_bins(a)


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def print_bins(a: np.ndarray) -> None:
    """What the model leaves (measured - model), along and across, per bin of the turn."""
    print(
        "\n| turn from a flute (deg) | centres | left along: mean / RMS (mm) | left across: mean / RMS (mm) |"
    )
    print("| --- | ---: | ---: | ---: |")
    for low in np.arange(0.0, 90.0, BIN_DEG):
        inside = (a[:, 0] >= low) & (a[:, 0] < low + BIN_DEG)
        if not inside.any():
            continue
        along, across = a[inside, 1] - a[inside, 3], a[inside, 2] - a[inside, 4]
        print(
            f"| {low:.0f}-{low + BIN_DEG:.0f} | {int(inside.sum())} "
            f"| {along.mean():+.2f} / {_rms(along):.2f} | {across.mean():+.2f} / {_rms(across):.2f} |"
        )


def print_rows(table: list[tuple[float, ...]]) -> None:
    """One row per centre, sorted by turn."""
    print(
        "| turn from a flute (deg) | along (mm, +: behind) | across (mm) | model along | model across "
        "| range (m) | intensity | fake's range bias (mm) |"
    )
    print("| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
    for turn, along, across, m_along, m_across, distance_m, intensity, bias_mm in table:
        print(
            f"| {turn:.0f} | {along:+.2f} | {across:+.2f} | {m_along:+.2f} | {m_across:+.2f} "
            f"| {distance_m:.3f} | {intensity:.0f} | {bias_mm:+.2f} |"
        )


if __name__ == "__main__":
    main()
