"""Rod-centre accuracy against range noise (not collected by pytest).

Run from the repository root: ``.venv/bin/python -m benchmarks.extraction_accuracy``.
For rods at several ranges and radii (random bearings, a wall 0.5 m behind), averaged
scans with the UTM-30LX-EW's 10 mm sigma over a 3 s dwell (120 scans, 0.91 mm per beam):
RMS centre error of the fit and of the paper's R*pi/4 seed alone, the fit's error as a
ratio to the per-beam noise, and the mean Mahalanobis distance of the error under the
reported covariance (2 if the covariance is honest).  Then the whole path in the
default fake world (all noise models, robot error): wire values -> average_scans ->
find_rod_centre with a background, for random rod poses tilted up to about 25 degrees,
fitted as the tilted ellipse and as a plain circle.  Last, scans as issue 18's real ones
(``tests.synthetic_scans.real_like_scans``): steady mixed-pixel ramps of 4-16 beams per side
in 25-100 mm steps, 2-5 mm per reading, a range bias of up to 12 mm, the rod's edge beams
valid in 70-100 % of the scans, without a background: found rate, how many centres lie more
than 3 reported std from what the scanner shows (the truth pushed out by the bias, which is
the solver's range curve's part), and the share of error components within 2.5 std.
"""

from __future__ import annotations

import numpy as np

from fakes.world import World
from lasercal_hw.geometry import euler_zyx_to_matrix, make_transform
from lasercal_hw.models import LaserScan
from lasercal_hw.scan.average import AveragedScan, average_scans
from lasercal_hw.scan.extraction import RodNotFoundError, find_rod_centre, seed_centre_pi4
from tests.synthetic_scans import averaged, real_like_scans, rod_ranges

SIGMA_MEAN_M = 0.010 / np.sqrt(120)
TRIALS = 40


def _dwell(world: World, T_base_tcp: np.ndarray, rng: np.random.Generator) -> AveragedScan:
    scans = []
    for k in range(120):
        mm, intensities = world.scan_mm(T_base_tcp, rng)
        ranges_m = np.where(mm >= 23, mm / 1000.0, np.nan)
        scans.append(LaserScan(k, world.geometry, ranges_m, mm, intensities, 0.025 * k, 0.025 * k))
    return average_scans(scans)


def default_world() -> None:
    """Centre errors through the whole path in the default fake world."""
    world = World.from_scene(None)
    rng = np.random.default_rng(2)
    T_base_laser = world.ground_truth_T_base_laser
    background = _dwell(world, T_base_laser @ make_transform(np.eye(3), [0.0, 0.0, 3.0]), rng)
    ellipse, circle, failures = [], [], 0
    for _ in range(TRIALS):
        range_m, bearing = rng.uniform(0.3, 1.2), rng.uniform(-1.8, 1.8)
        R = euler_zyx_to_matrix(rng.uniform(-np.pi, np.pi), rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4))
        crossing = np.array([range_m * np.cos(bearing), range_m * np.sin(bearing), 0.0])
        T = T_base_laser @ make_transform(R, crossing - 0.15 * R[:, 2])
        scan = _dwell(world, T, rng)
        start, axis = world.rod_shape_in_scanner(world.robot_error.true_pose(T))
        truth = start[:2] - start[2] / axis[2] * axis[:2]
        try:
            tilted = find_rod_centre(scan, radius_m=0.02, background=background, axis_in_scanner=axis)
            plain = find_rod_centre(scan, radius_m=0.02, background=background)
        except RodNotFoundError:
            failures += 1
            continue
        ellipse.append(np.linalg.norm(tilted.centre_uv_m - truth))
        circle.append(np.linalg.norm(plain.centre_uv_m - truth))
    print(f"\ndefault world, 20 mm rod at 0.3-1.2 m, {TRIALS} poses, {failures} not found:")
    print(f"  ellipse fit (axis known): RMS {np.sqrt(np.mean(np.square(ellipse))) * 1000:.2f} mm, "
          f"max {np.max(ellipse) * 1000:.2f} mm")
    print(f"  circle fit (axis ignored): RMS {np.sqrt(np.mean(np.square(circle))) * 1000:.2f} mm, "
          f"max {np.max(circle) * 1000:.2f} mm")


def real_like(trials: int = 60) -> None:
    """Issue 18's failure modes, per range band, with and without the expected position."""
    rng = np.random.default_rng(5)
    z_axis = np.array([0.0, 0.0, 1.0])
    print(f"\nreal-like scans (issue 18), axis known, {trials} rods per row, no background:")
    print(f"{'range m':>9s} {'radius mm':>9s} {'expected':>8s} {'found':>7s} {'> 3 std':>7s} "
          f"{'RMS mm':>7s} {'in 2.5 std':>10s}")
    for low, high in ((0.13, 0.44), (0.5, 1.1), (1.2, 2.0), (2.5, 3.0)):
        for radius_m in (0.045, 0.02):
            for with_expected in (False, True):
                found, wrong, errors, within = 0, 0, [], []
                for _ in range(trials):
                    range_m, bearing = rng.uniform(low, high), rng.uniform(-1.5, 1.5)
                    truth = range_m * np.array([np.cos(bearing), np.sin(bearing)])
                    bias_m = rng.uniform(-0.012, 0.012)
                    dwell = real_like_scans(
                        truth, radius_m, rng, background_m=range_m + rng.uniform(0.3, 3.0),
                        ramp_beams=(int(rng.integers(4, 17)), int(rng.integers(4, 17))),
                        ramp_step_m=rng.uniform(0.025, 0.1), reading_sigma_m=rng.uniform(0.002, 0.005),
                        range_bias_m=bias_m, edge_valid_fraction=rng.uniform(0.7, 1.0),
                    )
                    seen = truth * (1.0 + bias_m / range_m)
                    try:
                        result = find_rod_centre(
                            average_scans(dwell), radius_m=radius_m, axis_in_scanner=z_axis,
                            expected_uv_m=truth if with_expected else None,
                        )
                    except RodNotFoundError:
                        continue
                    found += 1
                    error = result.centre_uv_m - seen
                    std = np.sqrt(np.diag(result.covariance_uv_m2))
                    wrong += bool(error @ np.linalg.solve(result.covariance_uv_m2, error) > 9.0)
                    errors.append(float(np.linalg.norm(error)))
                    within.extend(np.abs(error) / std < 2.5)
                rms = f"{np.sqrt(np.mean(np.square(errors))) * 1000:7.2f}" if errors else f"{'-':>7s}"
                share = f"{np.mean(within):10.1%}" if within else f"{'-':>10s}"
                print(f"{low:4.2f}-{high:4.2f} {radius_m * 1000:9.0f} {with_expected!s:>8s} "
                      f"{found:>3d}/{trials:<3d} {wrong:7d} {rms} {share}")


def main() -> None:
    rng = np.random.default_rng(1)
    print(f"per-beam sigma (averaged): {SIGMA_MEAN_M * 1000:.2f} mm; {TRIALS} rods per row")
    print(f"{'range m':>7s} {'radius mm':>9s} {'beams':>5s} {'found':>5s} {'fit mm':>7s} {'fit/sigma':>9s} "
          f"{'seed mm':>7s} {'seed/fit':>8s} {'mahal.':>6s}")
    for range_m in (0.3, 0.5, 1.0, 2.0, 4.0):
        for radius_m in (0.003, 0.005, 0.010, 0.020, 0.025):
            fit, seed, mahal, beams, failures = [], [], [], [], []
            for _ in range(TRIALS):
                bearing = rng.uniform(-2.0, 2.0)
                centre = range_m * np.array([np.cos(bearing), np.sin(bearing)])
                scan = averaged(rod_ranges(centre, radius_m, wall_behind_m=0.5), SIGMA_MEAN_M, rng)
                try:
                    result = find_rod_centre(scan, radius_m=radius_m)
                except RodNotFoundError as exc:
                    failures.append(str(exc).split(";")[0])
                    continue
                error = result.centre_uv_m - centre
                fit.append(np.linalg.norm(error))
                points = scan.points_m()[result.beam_indices]
                seed.append(np.linalg.norm(seed_centre_pi4(points, radius_m) - centre))
                mahal.append(error @ np.linalg.solve(result.covariance_uv_m2, error))
                beams.append(result.quality.beams_used)
            row = f"{range_m:7.1f} {radius_m * 1000:9.0f}"
            found = f"{len(fit)}/{TRIALS}"
            if not fit:
                print(f"{row} {'-':>5s} {found:>5s}   not found: {failures[0]}")
                continue
            fit_rms = float(np.sqrt(np.mean(np.square(fit))))
            seed_rms = float(np.sqrt(np.mean(np.square(seed))))
            print(
                f"{row} {np.median(beams):5.0f} {found:>5s} {fit_rms * 1000:7.3f} "
                f"{fit_rms / SIGMA_MEAN_M:9.2f} {seed_rms * 1000:7.3f} {seed_rms / fit_rms:8.2f} "
                f"{np.mean(mahal):6.2f}"
            )


if __name__ == "__main__":
    main()
    default_world()
    real_like()
