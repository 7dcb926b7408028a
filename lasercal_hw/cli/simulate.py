"""``lasercal simulate``: Monte Carlo study of the paper's simulation protocol (section 4.2)."""

from __future__ import annotations

import math

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from lasercal_hw.calibration.simulate import (
    METRICS,
    PAPER_TABLE1_MEAN,
    PAPER_TABLE1_STD,
    MonteCarloSummary,
    Protocol,
    monte_carlo,
)
from lasercal_hw.cli.common import console, err_console, print_json
from lasercal_hw.errors import ConfigError

_LABELS = {
    "x": "|e_x| mm", "y": "|e_y| mm", "z": "|e_z| mm", "xyz": "|e_xyz| mm",
    "rot_x": "|e_rot_x| deg", "rot_y": "|e_rot_y| deg", "rot_z": "|e_rot_z| deg", "rot": "|e_rot| deg",
}


MAX_NOISE_MM = 1000.0
"""The largest noise simulated: a metre, the size of the cell (more makes impossible poses)."""


def _check_noise_mm(option: str, noise_mm: float, zero_allowed: bool) -> None:
    """A noise the simulation can draw: finite (inf or nan would make NaN waypoints), at most
    ``MAX_NOISE_MM``, and positive or, when ``zero_allowed``, zero."""
    too_small = noise_mm < 0 or (noise_mm == 0 and not zero_allowed)
    if not math.isfinite(noise_mm) or too_small or noise_mm > MAX_NOISE_MM:
        bound = ">= 0" if zero_allowed else "> 0"
        raise ConfigError(
            f"{option} must be a finite number {bound} and at most {MAX_NOISE_MM:g} (mm), got {noise_mm:g}"
        )


def simulate_command(
    trials: int = typer.Option(200, "--trials", help="Number of simulated calibrations."),
    seed: int = typer.Option(0, "--seed", help="Random seed."),
    laser_noise_mm: float = typer.Option(10.0, "--laser-noise-mm", help="Centre noise on u and v."),
    robot_noise_mm: float = typer.Option(1.0, "--robot-noise-mm", help="TCP position noise per axis."),
    points: int = typer.Option(75, "--points", help="Waypoints per calibration."),
    tilt_deg: float = typer.Option(20.0, "--tilt-deg", help="Maximum tool tilt about base x and y."),
    formulation: str = typer.Option("ours", "--formulation", help="ours | paper"),
    as_json: bool = typer.Option(False, "--json", help="Print the statistics as JSON."),
) -> None:
    """Reproduce the paper's Table 1 by Monte Carlo and compare with the Cramér-Rao bound."""
    if trials < 1:
        raise ConfigError(f"--trials must be at least 1, got {trials}")
    if seed < 0:
        raise ConfigError(f"--seed must be 0 or more, got {seed}")
    if points < 5:
        raise ConfigError(
            f"too few waypoints: need --points at least 5 (6 unknowns, 2 equations each), got {points}"
        )
    _check_noise_mm("--laser-noise-mm", laser_noise_mm, zero_allowed=False)
    _check_noise_mm("--robot-noise-mm", robot_noise_mm, zero_allowed=True)
    if not 0 < tilt_deg < 60:
        raise ConfigError(f"--tilt-deg must be between 0 and 60 degrees (exclusive), got {tilt_deg:g}")
    if formulation not in ("ours", "paper"):
        raise ConfigError(f"--formulation must be 'ours' or 'paper', got {formulation!r}")
    protocol = Protocol(
        points=points,
        tilt_deg=tilt_deg,
        laser_noise_m=laser_noise_mm / 1e3,
        robot_noise_m=robot_noise_mm / 1e3,
    )
    with Progress(
        TextColumn("simulating"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
        console=err_console, transient=True, disable=not err_console.is_terminal,
    ) as progress:
        task = progress.add_task("trials", total=trials)
        summary = monte_carlo(
            trials, seed, protocol, formulation="paper" if formulation == "paper" else "ours",
            progress=lambda done: progress.update(task, completed=done),
        )
    if as_json:
        print_json({"protocol": protocol.__dict__, "formulation": formulation, "seed": seed,
                    "paper_mean": PAPER_TABLE1_MEAN, "paper_std": PAPER_TABLE1_STD, **summary.to_dict()})
    else:
        _print_summary(summary, formulation)


def _print_summary(summary: MonteCarloSummary, formulation: str) -> None:
    table = Table(title=f"Table 1 reproduction: {summary.trials} trials, {formulation} formulation")
    for name in ("metric", "run mu", "paper mu", "CRB mu", "run sigma", "paper sigma", "CRB sigma"):
        table.add_column(name, justify="left" if name == "metric" else "right")
    for key in METRICS:
        table.add_row(
            _LABELS[key],
            f"{summary.mean[key]:.3f}", f"{PAPER_TABLE1_MEAN[key]:.3f}", f"{summary.crb_mean[key]:.3f}",
            f"{summary.std[key]:.3f}", f"{PAPER_TABLE1_STD[key]:.3f}", f"{summary.crb_std[key]:.3f}",
        )
    console.print(table)
    console.print(
        "run: this Monte Carlo; paper: Table 1 (its translation sigmas are printed in um, probably mm); "
        "rot_x, rot_y, rot_z: roll, pitch, yaw (ZYX) angle differences; CRB: N(0, CRB) draws per trial"
    )
    console.print(
        f"RMS translation error {summary.rms_translation_mm:.3f} mm "
        f"vs CRB {summary.crb_rms_translation_mm:.3f} mm "
        f"(ratio {summary.rms_translation_mm / summary.crb_rms_translation_mm:.3f}); RMS rotation error "
        f"{summary.rms_rotation_deg:.4f} deg vs CRB {summary.crb_rms_rotation_deg:.4f} deg "
        f"(ratio {summary.rms_rotation_deg / summary.crb_rms_rotation_deg:.3f})"
    )
    console.print(
        f"median solve time {summary.median_solve_time_s * 1e3:.2f} ms; "
        f"trials not converged: {summary.failures}"
    )
