"""The visit's estimate (``run.timing``) against the clock, for a dry-run calibration and a
dry-run verify of it (offline; not collected by pytest; about 3 min for the default job).

Runs ``lasercal run --dry-run`` with the job (fake cell child, real drivers) and then
``lasercal verify --dry-run`` on its ``result.json``, and reads each run's own timings
(``Timings``: motion is moves and settling, dwell includes the background) and recording:

- per waypoint, from the end of the one before (the background for the first, a second
  pass's preflight for its first) to its ``dwell_start`` event: the move and the settle;
- from ``dwell_start`` to ``dwell_end``: the settle margin, the dwell and the closing scan;
- the rest of motion plus dwell: the move from the arm's start to the retract pose and the
  background.

The estimate is ``run.timing.visit_timeline`` of the poses visited, with the job each visit
planned with (the verify's: the calibration as the scanner's nominal pose). Run from the
repository root::

    .venv/bin/python -m benchmarks.visit_time [--config examples/drill.toml] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from lasercal_hw.run.timing import VisitTimeline, visit_timeline
from lasercal_hw.session.reader import read_session
from lasercal_hw.verify.active import load_active_calibration
from lasercal_hw.verify.procedure import verify_job

#: Events after which the arm moves to a waypoint: a second pass (an adaptive run's second
#: design) moves after its preflight.
_MOVE_STARTS = ("background", "preflight_ok", "observation", "waypoint_skipped")


def dry_run(command: list[str], out: Path) -> dict[str, Any]:
    """``lasercal <command> --dry-run --yes --json --out out``: its JSON document."""
    result = subprocess.run(
        [sys.executable, "-m", "lasercal_hw.cli.main", *command,
         "--dry-run", "--yes", "--json", "--out", str(out)],
        capture_output=True, text=True, stdin=subprocess.DEVNULL, check=False,
    )
    if not result.stdout.strip():
        sys.exit(f"{command[0]} failed ({result.returncode}):\n{result.stderr[-2000:]}")
    return json.loads(result.stdout)


def clock_parts_s(recording_path: Path, motion_s: float, dwell_s: float) -> tuple[float, float, float]:
    """(to the retract pose and background, moves and settles, dwells) as the run's clock saw them."""
    events = read_session(recording_path, include_scans=False).events
    moves_s = dwells_s = 0.0
    end_s = started_s = None
    for event in events:
        kind, at_s = event["kind"], event["host_time_s"]
        if kind in _MOVE_STARTS:
            end_s = at_s
        elif kind == "dwell_start" and end_s is not None:
            moves_s += at_s - end_s
            started_s = at_s
        elif kind == "dwell_end" and started_s is not None:
            dwells_s += at_s - started_s
    return motion_s + dwell_s - moves_s - dwells_s, moves_s, dwells_s


def row(name: str, timeline: VisitTimeline | None, document: dict[str, Any], recording_path: Path) -> str:
    """One line of the table: clock and estimate, whole and by part."""
    timings = document["timings"] if "timings" in document else document["run"]["timings"]
    clock_s = timings["motion_s"] + timings["dwell_s"]
    start_s, moves_s, dwells_s = clock_parts_s(recording_path, timings["motion_s"], timings["dwell_s"])
    if timeline is None:
        return f"| {name} | {clock_s:.2f} | unreachable | | | | |"
    estimate_s = timeline.total_s
    parts = (
        f"{start_s:.2f} / {timeline.to_retract_s + timeline.background_s:.2f}",
        f"{moves_s:.2f} / {sum(timeline.moves_s):.2f}",
        f"{dwells_s:.2f} / {len(timeline.moves_s) * timeline.dwell_each_s:.2f}",
    )
    return (f"| {name} | {clock_s:.2f} | {estimate_s:.2f} | {100 * (estimate_s / clock_s - 1):+.1f} % | "
            + " | ".join(parts) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, help="job file (default: the default job)")
    parser.add_argument("--out", type=Path, help="keep both runs' folders here (default: a temporary one)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        root = args.out or Path(folder)
        config = ["--config", str(args.config.resolve())] if args.config else []
        calibration = dry_run(["run", *config], root / "run")
        result_path = root / "run" / "result.json"
        verify = dry_run(["verify", "--calibration", str(result_path)], root / "verify")
        active = load_active_calibration(result_path)
        job, poses = active.job, active.waypoints()
        if job is None or poses is None:
            sys.exit(f"{result_path} records no job or no waypoints")
        chosen = verify["selection"]["waypoints"]
        checking = verify_job(job, np.asarray(active.T_base_laser))
        print("| visit | clock motion+dwell (s) | estimate (s) | estimate/clock | to retract + background "
              "(clock / estimate, s) | moves and settles | dwells |")
        print("| --- | --- | --- | --- | --- | --- | --- |")
        print(row(f"calibration, {len(poses)} waypoints", visit_timeline(job, poses), calibration,
                  root / "run" / "session.mcap"))
        print(row(f"verify, waypoints {chosen}", visit_timeline(checking, poses[chosen]), verify,
                  root / "verify" / "session.mcap"))
        share = verify["timings"]["fraction_of_calibration"]
        print(f"verify's measured share of the calibration's motion and dwell: {share:.3f} "
              f"(verify.max_time_fraction {job.verify.max_time_fraction:g})")


if __name__ == "__main__":
    main()
