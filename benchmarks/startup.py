"""Start-up of the ``lasercal`` command, loading ``observations.csv``, and BLAS threads.

Prints, all measured in the same run (start-up commands interleaved, so each sees the same
machine load; medians of ``--runs`` runs):

* wall time of ``python -c pass``, ``python -c "import numpy"``, ``lasercal --help`` and
  ``lasercal solve obs.csv`` (2,000 generated rows), with ratios against the numpy import
  (target: ``--help`` within 0.3 s of the numpy import), and their CPU time (user + system),
  which a busy machine inflates less than wall time;
* ``load_observations`` against ``np.loadtxt`` on the same 2,000- and 20,000-row files;
* ``lasercal solve`` of 20,000 rows with the command's own BLAS thread limit against
  OpenBLAS's default (one thread per core, forced with ``OPENBLAS_NUM_THREADS``).

    .venv/bin/python -m benchmarks.startup [--runs 7]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from lasercal_hw.calibration.observations import load_observations, write_observations_csv
from lasercal_hw.calibration.simulate import Protocol, paper_ground_truth, simulate_observations
from lasercal_hw.models import RodLine

START_ROWS = 2_000
THREAD_ROWS = 20_000
HELP_MARGIN_S = 0.3


def _lasercal() -> list[str]:
    """The installed ``lasercal`` script beside this interpreter (what a user runs)."""
    script = Path(sys.executable).with_name("lasercal")
    return [str(script)] if script.exists() else [sys.executable, "-m", "lasercal_hw.cli.main"]


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _timed(argv: Sequence[str], env: Mapping[str, str] | None = None) -> tuple[float, float, str]:
    """Wall and CPU time of one command (it must finish: exit 0, or 1 for a solve whose quality
    gate failed, as the paper's noise level fails the default RMS gate) and its standard output."""
    cpu_before_s, start = _children_cpu_s(), time.perf_counter()
    done = subprocess.run(argv, capture_output=True, text=True, stdin=subprocess.DEVNULL, env=env,
                          check=False)
    elapsed_s, cpu_s = time.perf_counter() - start, _children_cpu_s() - cpu_before_s
    if done.returncode not in (0, 1):
        sys.exit(f"{' '.join(argv)} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    return elapsed_s, cpu_s, done.stdout


def _write_observations(path: Path, rows: int) -> None:
    protocol = Protocol(points=rows)
    observations, _ = simulate_observations(paper_ground_truth(), RodLine(), protocol,
                                            np.random.default_rng(rows))
    write_observations_csv(path, observations)


def _median_call_s(call: Callable[[], object], runs: int) -> float:
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def startup(csv_path: Path, runs: int) -> None:
    """Start-up beside a bare interpreter and the numpy import."""
    commands = {
        "python -c pass": [sys.executable, "-c", "pass"],
        "python -c 'import numpy'": [sys.executable, "-c", "import numpy"],
        "lasercal --help": [*_lasercal(), "--help"],
        f"lasercal solve obs.csv ({START_ROWS:,} rows)": [*_lasercal(), "solve", str(csv_path), "--json"],
    }
    wall: dict[str, list[float]] = {name: [] for name in commands}
    cpu: dict[str, list[float]] = {name: [] for name in commands}
    for _ in range(runs):
        for name, argv in commands.items():
            elapsed_s, cpu_s, _ = _timed(argv)
            wall[name].append(elapsed_s)
            cpu[name].append(cpu_s)
    wall_s = {name: statistics.median(values) for name, values in wall.items()}
    cpu_s = {name: statistics.median(values) for name, values in cpu.items()}
    numpy = "python -c 'import numpy'"
    print(f"start-up, median of {runs} runs:")
    for name in commands:
        print(f"  {name:<36} wall {wall_s[name] * 1e3:6.0f} ms ({wall_s[name] / wall_s[numpy]:5.2f}x numpy), "
              f"CPU {cpu_s[name] * 1e3:6.0f} ms ({cpu_s[name] / cpu_s[numpy]:5.2f}x numpy)")
    help_over_s = wall_s["lasercal --help"] - wall_s[numpy]
    verdict = "met" if help_over_s <= HELP_MARGIN_S else "NOT met"
    print(f"  --help minus numpy import: wall {help_over_s * 1e3:.0f} ms "
          f"(target <= {HELP_MARGIN_S * 1e3:.0f} ms: {verdict}), "
          f"CPU {(cpu_s['lasercal --help'] - cpu_s[numpy]) * 1e3:.0f} ms")


def csv_loading(paths: Sequence[Path], runs: int) -> None:
    """``load_observations`` against ``np.loadtxt`` of the same file."""
    print(f"observations.csv loading, median of {runs} runs:")
    for path in paths:
        ours_s = _median_call_s(lambda p=path: load_observations(p), runs)
        numpy_s = _median_call_s(lambda p=path: np.loadtxt(p, delimiter=",", skiprows=1), runs)
        rows = len(path.read_text().splitlines()) - 1
        print(f"  {rows:>6,} rows: load_observations {ours_s * 1e3:7.1f} ms, "
              f"np.loadtxt {numpy_s * 1e3:7.1f} ms, ratio {ours_s / numpy_s:.2f}")


def threads(csv_path: Path, runs: int) -> None:
    """The 20,000-row solve with the command's thread limit against one thread per core."""
    cores = os.cpu_count() or 1
    base = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    variants = {"lasercal's own limit": base,
                f"OpenBLAS default ({cores} threads)": base | {"OPENBLAS_NUM_THREADS": str(cores)}}
    wall: dict[str, list[float]] = {name: [] for name in variants}
    solve: dict[str, list[float]] = {name: [] for name in variants}
    for _ in range(runs):
        for name, env in variants.items():
            elapsed_s, _, stdout = _timed([*_lasercal(), "solve", str(csv_path), "--json"], env=env)
            wall[name].append(elapsed_s)
            solve[name].append(json.loads(stdout)["provenance"]["solve_time_s"])
    print(f"lasercal solve, {THREAD_ROWS:,} rows, median of {runs} runs on {cores} cores:")
    reference = statistics.median(solve["lasercal's own limit"])
    for name in variants:
        solve_s = statistics.median(solve[name])
        print(f"  {name:<28} wall {statistics.median(wall[name]):6.2f} s, solve {solve_s:6.2f} s"
              f" ({solve_s / reference:.2f}x the limited solve)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7, help="Runs per figure (medians).")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        small, large = Path(folder) / "obs.csv", Path(folder) / "obs_large.csv"
        _write_observations(small, START_ROWS)
        _write_observations(large, THREAD_ROWS)
        startup(small, args.runs)
        csv_loading((small, large), args.runs)
        threads(large, max(3, args.runs // 2))


if __name__ == "__main__":
    main()
