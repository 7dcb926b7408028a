"""Solver benchmark: time per solve, accuracy over the Cramér-Rao bound, and our
formulation against the paper's on the same data in the same run.

Run: .venv/bin/python benchmarks/bench_solver.py [--quick]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from rich.console import Console  # noqa: E402
from rich.table import Table  # noqa: E402

from lasercal_hw.models import RodLine  # noqa: E402
from lasercal_hw.simulate import (  # noqa: E402
    Protocol,
    crb_covariance,
    paper_ground_truth,
    pose_errors,
    simulate_observations,
)
from lasercal_hw.solver import SolverOptions, solve  # noqa: E402

SIZES = {20: 60, 75: 60, 1_000: 10, 10_000: 5}
PAPER_REPEATS = {20: 20, 75: 20, 1_000: 3, 10_000: 1}


def _run(
    points: int, repeats: int, formulation: str, seed: int, outlier_m: float = 0.0
) -> tuple[float, float, float, int]:
    """Median solve time (s), RMS translation and rotation error over the CRB, non-converged
    count; with ``outlier_m`` one centre per data set is moved that far along u."""
    protocol = Protocol(points=points)
    truth = paper_ground_truth()
    rod = RodLine()
    options = SolverOptions(default_sigma_uv_m=protocol.laser_noise_m, robot_sigma_m=protocol.robot_noise_m)
    rng = np.random.default_rng(seed)
    times, sq_t, sq_r, crb_t, crb_r, failed = [], [], [], [], [], 0
    for _ in range(repeats):
        obs, poses = simulate_observations(truth, rod, protocol, rng)
        if outlier_m:
            obs[0] = dataclasses.replace(obs[0], centre_uv_m=obs[0].centre_uv_m + np.array([outlier_m, 0.0]))
        start = time.perf_counter()
        result = solve(obs, rod, options=options, formulation=formulation)  # type: ignore[arg-type]
        times.append(time.perf_counter() - start)
        failed += not result.provenance.converged
        errors = pose_errors(truth, result.matrix())
        crb = crb_covariance(truth, poses, rod, protocol)
        sq_t.append(errors[:3] @ errors[:3])
        sq_r.append(errors[3:] @ errors[3:])
        crb_t.append(np.trace(crb[:3, :3]))
        crb_r.append(np.trace(crb[3:, 3:]))
    ratio_t = float(np.sqrt(np.mean(sq_t) / np.mean(crb_t)))
    ratio_r = float(np.sqrt(np.mean(sq_r) / np.mean(crb_r)))
    return float(np.median(times)), ratio_t, ratio_r, failed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="fewer repeats")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    console = Console(width=150)
    table = Table(title="lasercal solver benchmark (one core, paper protocol, 10 mm / 1 mm noise)")
    for name in (
        "waypoints", "ours median", "ours RMS/CRB t, r", "paper median", "paper RMS/CRB t, r",
        "paper/ours time", "paper not converged",
    ):
        table.add_column(name, justify="right")
    for points, repeats in SIZES.items():
        repeats = max(3, repeats // 4) if args.quick else repeats
        paper_repeats = max(1, PAPER_REPEATS[points] // 4) if args.quick else PAPER_REPEATS[points]
        ours_s, ours_t, ours_r, _ = _run(points, repeats, "ours", args.seed)
        paper_s, paper_t, paper_r, failed = _run(points, paper_repeats, "paper", args.seed)
        table.add_row(
            f"{points:,}",
            f"{ours_s * 1e3:.2f} ms",
            f"{ours_t:.2f}, {ours_r:.2f}",
            f"{paper_s * 1e3:.1f} ms",
            f"{paper_t:.2f}, {paper_r:.2f}",
            f"{paper_s / ours_s:.1f}x",
            f"{failed} of {paper_repeats}",
        )
        console.print(f"done {points} waypoints")
    console.print(table)
    outliers = Table(title="Same data with one centre moved 20 cm (75 waypoints)")
    for name in ("formulation", "RMS/CRB translation", "RMS/CRB rotation", "median time"):
        outliers.add_column(name, justify="right")
    repeats = 10 if args.quick else 40
    for formulation in ("ours", "paper"):
        seconds, ratio_t, ratio_r, _ = _run(75, repeats, formulation, args.seed, outlier_m=0.2)
        outliers.add_row(formulation, f"{ratio_t:.2f}", f"{ratio_r:.2f}", f"{seconds * 1e3:.1f} ms")
    console.print(outliers)
    console.print(
        "ours = robust mode (default): linear start, Huber loss with chi-square rejection, final LM; "
        "RMS/CRB = RMS error over the Cramér-Rao bound (t: translation, r: ZYX angles; 1.00 is efficient)"
    )


if __name__ == "__main__":
    main()
