"""Fuzz the SCIP driver with mutated conversations and print what became of them.

    .venv/bin/python -m benchmarks.fuzz_scip [--count 10000] [--first-seed 0]

Each conversation (open, II, one GD scan) against the fake UTM-30LX-EW's state machine
has one to three replies damaged (``tests/scip_fuzz.py`` describes the plan and the
outcomes). Prints the count of every outcome: clean errors, recovered (the true data
despite the damage), wrong data accepted (split by whether a checksum could see the
damage: the detectable count must be 0), crashes and hangs, and the damage behind every
wrong result.
"""

from __future__ import annotations

import argparse
import sys

from tests.scip_fuzz import OUTCOMES, run_many


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=10_000)
    parser.add_argument("--first-seed", type=int, default=0)
    args = parser.parse_args()
    counts, details, seconds = run_many(args.count, args.first_seed)
    print(f"{args.count} conversations (seeds {args.first_seed}..{args.first_seed + args.count - 1}) "
          f"in {seconds:.1f} s ({1000 * seconds / args.count:.1f} ms each)")
    for kind in OUTCOMES:
        print(f"  {kind:20s} {counts[kind]:6d}")
    for kind, lines in details.items():
        print(f"{kind}:")
        for line in lines:
            print(f"  {line}")
    failed = counts["wrong_detectable"] + counts["crash"] + counts["hang"]
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
