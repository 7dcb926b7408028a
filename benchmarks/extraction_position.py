"""One rod position of ``benchmarks.extraction_physical`` repeated over many dwells' noise.

    .venv/bin/python -m benchmarks.extraction_position --material steel_drill --radius-mm 20 \
        --range-m 0.3 --wall far --bearing-rad 0.0413 [--model physical] [--dwells 200] \
        [--first-seed 1000] [--scans 40]

A centre more than 3 reported std off at one seed is either a chance draw of the dwell's
noise (rare at every seed: the position is fine) or an error the covariance does not carry
(frequent, or biased: the position is not). This prints which: the error's mean and RMS along
and across the bearing beside the median reported std there, how many centres are more than 3
std off (silent or warned), the largest, and how many dwells found no rod.  ``--misses`` of
the main benchmark prints a silent centre's bearing and seed.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from benchmarks.extraction_physical import BACKGROUNDS_M, OFF_STD, RODS, measure


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    shapes = sorted({shape for _, _, shape, _ in RODS})
    parser.add_argument("--material", required=True, help="a scanner-model material, e.g. steel_drill")
    parser.add_argument("--radius-mm", type=float, required=True)
    parser.add_argument("--shape", choices=shapes, default="cylinder")
    parser.add_argument("--range-m", type=float, required=True)
    parser.add_argument("--wall", choices=sorted(BACKGROUNDS_M), required=True)
    parser.add_argument("--bearing-rad", type=float, required=True)
    parser.add_argument("--model", choices=("physical", "ideal"), default="physical")
    parser.add_argument("--dwells", type=int, default=200, help="dwells, one noise seed each (default 200)")
    parser.add_argument("--first-seed", type=int, default=1000, help="first noise seed (default 1000)")
    parser.add_argument("--scans", type=int, default=40, help="scans per dwell (default 40, 1 s)")
    args = parser.parse_args(argv)
    if args.dwells < 2:
        parser.error("--dwells must be at least 2 to show a scatter")
    bearing = np.array([np.cos(args.bearing_rad), np.sin(args.bearing_rad)])
    side = np.array([-bearing[1], bearing[0]])
    errors_mm, stds_mm, whitened, warned, missed = [], [], [], [], 0
    for seed in range(args.first_seed, args.first_seed + args.dwells):
        outcome = measure(
            args.model, args.radius_mm / 1000.0, args.shape, args.material, args.range_m,
            BACKGROUNDS_M[args.wall], args.bearing_rad, seed, args.scans,
        )
        if outcome.error_m is None or outcome.covariance is None:
            missed += 1
            continue
        covariance = outcome.covariance
        errors_mm.append(1000.0 * np.array([bearing @ outcome.error_m, side @ outcome.error_m]))
        stds_mm.append(1000.0 * np.sqrt([bearing @ covariance @ bearing, side @ covariance @ side]))
        whitened.append(float(np.linalg.norm(outcome.whitened())))
        warned.append(outcome.warned)
    print(
        f"{args.model} model, {args.radius_mm:g} mm {args.shape} of {args.material} at {args.range_m} m, "
        f"{args.wall} wall, bearing {args.bearing_rad:+.4f} rad, seeds {args.first_seed}-"
        f"{args.first_seed + args.dwells - 1}, {args.scans} scans each"
    )
    print(f"no rod found: {missed} of {args.dwells}")
    if not errors_mm:
        return 0
    error, std = np.array(errors_mm), np.array(stds_mm)
    for column, name in enumerate(("along the bearing", "across it")):
        print(
            f"{name:17s}: error mean {error[:, column].mean():+.2f} mm, RMS "
            f"{np.sqrt(np.mean(error[:, column] ** 2)):.2f} mm; reported std median "
            f"{np.median(std[:, column]):.2f} mm (min {std[:, column].min():.2f})"
        )
    w, flagged = np.array(whitened), np.array(warned)
    off = w > OFF_STD
    print(
        f"> {OFF_STD:g} std: {int(np.sum(off & ~flagged))} silent, {int(np.sum(off & flagged))} warned "
        f"of {w.size}; largest {w.max():.2f} std"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
