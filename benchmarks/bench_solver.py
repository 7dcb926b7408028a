"""Solver benchmark: time per solve, accuracy over the Cramér-Rao bound, and our
formulation against the paper's on the same data in the same run (interleaved, so both
see the same machine load).  Times are CPU time of this process (one BLAS thread).

Run: .venv/bin/python -m benchmarks.bench_solver [--quick]
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

from lasercal_hw.calibration.simulate import (  # noqa: E402
    Protocol,
    crb_covariance,
    paper_ground_truth,
    pose_errors,
    simulate_observations,
)
from lasercal_hw.calibration.solver import SolverOptions, solve  # noqa: E402
from lasercal_hw.models import RodLine  # noqa: E402

REPEATS = {20: 60, 75: 60, 1_000: 20, 10_000: 6}
FORMULATIONS = ("ours", "paper")


@dataclasses.dataclass
class _Stats:
    seconds: list[float] = dataclasses.field(default_factory=list)
    sq_translation: list[float] = dataclasses.field(default_factory=list)
    sq_rotation: list[float] = dataclasses.field(default_factory=list)
    not_converged: int = 0


def _run(
    points: int, repeats: int, seed: int, outlier_m: float = 0.0
) -> tuple[dict[str, _Stats], float, float]:
    """Solve the same data sets with both formulations; also return the mean CRB traces
    (translation mm^2, ZYX deg^2).  With ``outlier_m`` one centre per set is moved along u."""
    protocol = Protocol(points=points)
    truth = paper_ground_truth()
    rod = RodLine()
    options = SolverOptions(default_sigma_uv_m=protocol.laser_noise_m, robot_sigma_m=protocol.robot_noise_m)
    rng = np.random.default_rng(seed)
    stats = {name: _Stats() for name in FORMULATIONS}
    crb_t, crb_r = [], []
    for _ in range(repeats):
        obs, poses = simulate_observations(truth, rod, protocol, rng)
        if outlier_m:
            obs[0] = dataclasses.replace(obs[0], centre_uv_m=obs[0].centre_uv_m + np.array([outlier_m, 0.0]))
        crb = crb_covariance(truth, poses, rod, protocol)
        crb_t.append(np.trace(crb[:3, :3]))
        crb_r.append(np.trace(crb[3:, 3:]))
        for name in FORMULATIONS:
            start = time.process_time()
            result = solve(obs, rod, options=options, formulation=name)  # type: ignore[arg-type]
            stats[name].seconds.append(time.process_time() - start)
            stats[name].not_converged += not result.provenance.converged
            errors = pose_errors(truth, result.matrix())
            stats[name].sq_translation.append(errors[:3] @ errors[:3])
            stats[name].sq_rotation.append(errors[3:] @ errors[3:])
    return stats, float(np.mean(crb_t)), float(np.mean(crb_r))


def _ratios(stats: _Stats, crb_t: float, crb_r: float) -> str:
    return (
        f"{np.sqrt(np.mean(stats.sq_translation) / crb_t):.2f}, "
        f"{np.sqrt(np.mean(stats.sq_rotation) / crb_r):.2f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="a quarter of the repeats")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    console = Console(width=150)
    table = Table(title="lasercal solver benchmark (one core, paper protocol, 10 mm laser, 1 mm robot noise)")
    for name in (
        "waypoints", "data sets", "ours median", "ours RMS/CRB t, r", "paper median", "paper RMS/CRB t, r",
        "paper/ours time", "paper not converged",
    ):
        table.add_column(name, justify="right")
    for points, repeats in REPEATS.items():
        repeats = max(3, repeats // 4) if args.quick else repeats
        stats, crb_t, crb_r = _run(points, repeats, args.seed)
        ours, paper = np.median(stats["ours"].seconds), np.median(stats["paper"].seconds)
        table.add_row(
            f"{points:,}", str(repeats),
            f"{ours * 1e3:.2f} ms", _ratios(stats["ours"], crb_t, crb_r),
            f"{paper * 1e3:.2f} ms", _ratios(stats["paper"], crb_t, crb_r),
            f"{paper / ours:.1f}x", f"{stats['paper'].not_converged} of {repeats}",
        )
    console.print(table)
    repeats = 10 if args.quick else 40
    stats, crb_t, crb_r = _run(75, repeats, args.seed, outlier_m=0.2)
    outliers = Table(title=f"Same data with one centre moved 20 cm (75 waypoints, {repeats} data sets)")
    for name in ("formulation", "RMS/CRB t, r", "median time"):
        outliers.add_column(name, justify="right")
    for name in FORMULATIONS:
        median_ms = np.median(stats[name].seconds) * 1e3
        outliers.add_row(name, _ratios(stats[name], crb_t, crb_r), f"{median_ms:.2f} ms")
    console.print(outliers)
    console.print(
        "ours = robust mode (default): linear start, Huber loss with chi-square rejection, final LM. "
        "RMS/CRB = RMS error over the Cramér-Rao bound (t: translation, r: ZYX angles; 1.00 is efficient; "
        "few data sets at large sizes make it noisy). Times: median CPU seconds per solve."
    )


if __name__ == "__main__":
    main()
