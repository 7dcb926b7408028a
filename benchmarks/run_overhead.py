"""How much of a calibration run is neither motion nor dwell (target: under 10 %).

Runs ``lasercal run --dry-run`` (fake cell child, real drivers, real recorder, solver,
report) with a trajectory preset and reads the run's own timings: wall time, motion time
(moves and settling), dwell time (background included). The overhead ratio is
``(wall - motion - dwell) / (motion + dwell)``, both measured in the same run.

    .venv/bin/python -m benchmarks.run_overhead [--preset paper] [--dwell 3.0]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="paper")
    parser.add_argument("--dwell", type=float, default=3.0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        root = Path(folder)
        (root / "job.toml").write_text(
            f"dwell_s = {args.dwell}\n[trajectory]\npreset = \"{args.preset}\"\n"
            "[motion]\njoint_speed_rad_s = 1.2\njoint_accel_rad_s2 = 3.0\n"
        )
        result = subprocess.run(
            [sys.executable, "-m", "lasercal_hw.cli.main", "run", "--dry-run", "--json",
             "--config", str(root / "job.toml"), "--out", str(root / "out")],
            capture_output=True, text=True, stdin=subprocess.DEVNULL, check=False,
        )
        if result.returncode not in (0, 1):
            sys.exit(f"dry run failed ({result.returncode}):\n{result.stderr[-2000:]}")
        document = json.loads(result.stdout)
        timings = document["timings"]
    busy_s = timings["motion_s"] + timings["dwell_s"]
    overhead_s = timings["wall_s"] - busy_s
    print(f"preset {args.preset}: {document['observations']} observations, "
          f"{len(document['skipped'])} skipped, dwell {args.dwell:g} s, "
          f"error vs truth {document['ground_truth']['error']['translation_mm']:.1f} mm / "
          f"{document['ground_truth']['error']['rotation_deg']:.2f} deg, passed {document['passed']}")
    print(f"sequencer wall {timings['wall_s']:.2f} s = motion {timings['motion_s']:.2f} s "
          f"+ dwell {timings['dwell_s']:.2f} s + overhead {overhead_s:.2f} s")
    print(f"overhead / (motion + dwell) = {overhead_s / busy_s:.3f} (target < 0.10)")
    print(f"with connecting and writing outputs ({timings['command_s']:.2f} s): "
          f"{timings['overhead_fraction_with_io']:.3f}")


if __name__ == "__main__":
    main()
