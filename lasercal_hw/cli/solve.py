"""``lasercal solve``: calibrate offline from recorded observations."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from typing import Annotated

import numpy as np
import typer
from rich.markup import escape
from rich.table import Table

from lasercal_hw.calibration.observations import SolveSettings, load_observations, read_solve_settings
from lasercal_hw.calibration.quality import evaluate_gates
from lasercal_hw.calibration.result import CalibrationResult
from lasercal_hw.calibration.solver import SolverOptions, solve
from lasercal_hw.cli.common import console, err_console, parse_vector, print_json
from lasercal_hw.config import QualityConfig, RobotConfig
from lasercal_hw.errors import ConfigError, ExitCode
from lasercal_hw.models import FloatArray, RodLine


def solve_command(
    input_path: Annotated[
        Path, typer.Argument(help="observations.csv, or the session.mcap of a run", show_default=False)
    ],
    axis_origin: str | None = typer.Option(
        None, "--axis-origin", help="Rod axis origin in the TCP frame (m) (default: the file's, else 0,0,0)."
    ),
    axis_direction: str | None = typer.Option(
        None, "--axis-direction", help="Rod axis direction, TCP frame (default: the file's, else 0,0,1)."
    ),
    robust: bool = typer.Option(True, "--robust/--no-robust", help="Robust loss and outlier rejection."),
    formulation: str | None = typer.Option(
        None, "--formulation", help="ours | paper (the paper's own problem: the pose alone) (default: ours)."
    ),
    sigma_mm: float | None = typer.Option(
        None, "--sigma-mm", help="Centre noise for rows without sigma_u, sigma_v (default: 5)."
    ),
    robot_sigma_mm: float | None = typer.Option(
        None, "--robot-sigma-mm", help="Robot TCP position noise per axis (default: the file's, else 1)."
    ),
    output: Annotated[Path | None, typer.Option("--output", "-o", help="Also write result.json.")] = None,
    as_json: bool = typer.Option(False, "--json", help="Print the result.json document instead of a table."),
    estimate_axis: bool = typer.Option(
        False, "--estimate-axis", help="Estimate the rod axis (2 offsets, 2 tilts) from the given one."
    ),
    estimate_range_offset: bool = typer.Option(
        False, "--estimate-range-offset", help="Estimate the scanner's range offset."
    ),
    use_recorded_centres: bool = typer.Option(
        False, "--use-recorded-centres", help="session.mcap: keep recorded centres where re-extraction fails."
    ),
    scanner: str | None = typer.Option(
        None, "--scanner", help="session.mcap of a cell job: the scanner whose run to solve (docs/cell.md)."
    ),
) -> None:
    """Solve for T_base_laser from observations (index,tcp_x..tcp_rz,u,v[,sigma_u,sigma_v[,rho_uv]]) or
    from a run's session.mcap (same extraction and solver as the live run; rod and noise from its job;
    a cell job's one recording: the run of the scanner named with --scanner).

    A run's observations.csv carries the rod, solver settings and gates of the run's final
    solve, so it solves as the run did; options given here change those. The quality gates of
    `lasercal run` apply (the file's or recording's own, else the defaults): exit 1 when one fails."""
    if formulation not in (None, "ours", "paper"):
        raise ConfigError(f"--formulation must be 'ours' or 'paper', got {formulation!r}")
    if (sigma_mm is not None and sigma_mm <= 0) or (robot_sigma_mm is not None and robot_sigma_mm < 0):
        raise ConfigError("--sigma-mm must be positive and --robot-sigma-mm not negative")
    if input_path.suffix.lower() not in (".csv", ".mcap") and not input_path.is_dir():
        raise ConfigError(
            f"cannot read {input_path.name!r}: unsupported file type {input_path.suffix!r} (supported: .csv "
            "observations, or a run's .mcap recording)"
        )
    if input_path.suffix.lower() == ".mcap":
        if (axis_origin, axis_direction, robust, formulation, sigma_mm, robot_sigma_mm) != (
            None, None, True, None, None, None
        ):
            raise ConfigError(
                "--axis-origin, --axis-direction, --no-robust, --formulation, --sigma-mm and "
                "--robot-sigma-mm apply to observations.csv; a session.mcap is solved with the rod and "
                "settings of its recorded job"
            )
        from lasercal_hw.run.replay import solve_recording  # its recording reader is not needed for a CSV

        overrides: dict[str, object] = {}
        if estimate_axis:
            overrides["rod.estimate_axis"] = True
        if estimate_range_offset:
            overrides["scanner.estimate_range_offset"] = True
        replay = solve_recording(
            input_path, use_recorded_centres=use_recorded_centres, job_overrides=overrides, scanner=scanner
        )
        for message in replay.messages:
            err_console.print(f"[yellow]replay:[/] {message}")
        result, gates = replay.solution.result, replay.job.quality
        commanded = replay.waypoints
    else:
        if use_recorded_centres or scanner is not None:
            raise ConfigError(
                "--use-recorded-centres and --scanner apply to a session.mcap, not to observations.csv"
            )
        observations = load_observations(input_path)
        settings = read_solve_settings(input_path) or SolveSettings(
            RodLine(), SolverOptions(robot_sigma_m=RobotConfig().position_accuracy_mm / 1e3), QualityConfig()
        )
        rod = replace(
            settings.rod,
            origin_m=settings.rod.origin_m if axis_origin is None else np.array(
                parse_vector(axis_origin, 3, "--axis-origin")
            ),
            direction=settings.rod.direction if axis_direction is None else _direction(axis_direction),
        )
        changes: dict[str, object] = {
            "default_sigma_uv_m": None if sigma_mm is None else sigma_mm / 1e3,
            "robot_sigma_m": None if robot_sigma_mm is None else robot_sigma_mm / 1e3,
            "estimate_axis": True if estimate_axis else None,
            "estimate_range_offset": True if estimate_range_offset else None,
            "formulation": formulation,
        }
        if formulation == "paper" and not (estimate_axis or estimate_range_offset):
            changes |= _pose_alone(settings.solver)
        options = settings.solver.model_copy(update={k: v for k, v in changes.items() if v is not None})
        result = solve(observations, rod, robust=robust, options=options)
        gates = settings.quality
        commanded = None  # a CSV holds the measured TCP poses, not the commanded ones
    verdict = evaluate_gates(result, gates, len(result.residuals))
    document = result.to_json_dict() | {"passed": verdict.passed, "verdict": verdict.as_dict()}
    if commanded is not None:  # the poses the recorded run commanded, for a verify's choice
        document["run"] = {"waypoints": commanded.tolist()}
    if output is not None:
        try:
            output.write_text(json.dumps(document, indent=2) + "\n", encoding="utf-8")
        except OSError as exc:
            raise ConfigError(
                f"cannot write {str(output)!r}: {exc.strerror or exc}; pass --output a file path in a "
                "writable directory"
            ) from exc
    if as_json:
        print_json(document)
    else:
        print_result(result)
        for check in verdict.checks:
            console.print(f"[{'green' if check.passed else 'red'}]{escape(check.describe())}[/]")
    if not verdict.passed:
        err_console.print(f"[bold red]quality gate failed:[/] {escape('; '.join(verdict.failures()))}")
        raise typer.Exit(int(ExitCode.QUALITY_GATE_FAILED))


def _pose_alone(solver: SolverOptions) -> dict[str, object]:
    """The paper's problem is the pose alone: a run's file that estimates the rod axis or the
    range error curve is solved without them (said on stderr), as ``--formulation paper`` asks."""
    dropped = [what for what, on in (("the rod axis", solver.estimate_axis),
                                     ("the range error curve", solver.estimate_range_offset)) if on]
    if dropped:
        err_console.print(
            f"[yellow]note:[/] --formulation paper estimates the pose alone, not {' or '.join(dropped)} "
            "as the file's settings do"
        )
    return {"estimate_axis": False, "estimate_range_offset": False}


def _direction(text: str) -> FloatArray:
    direction = np.array(parse_vector(text, 3, "--axis-direction"))
    if np.linalg.norm(direction) < 1e-9:
        raise ConfigError("--axis-direction must not be the zero vector")
    return direction


def print_result(result: CalibrationResult) -> None:
    """Print a calibration result as a readable table (solve and run share it)."""
    prov = result.provenance
    console.print(
        f"[bold]T_base_laser[/] ({prov.formulation} formulation, {result.waypoints_used} of "
        f"{len(result.residuals)} waypoints used, {prov.solve_time_s * 1e3:.1f} ms"
        f"{'' if prov.converged else ', [red]NOT CONVERGED[/]'})"
    )
    matrix = Table(show_header=False, box=None, padding=(0, 2))
    for row in result.T_base_laser:
        matrix.add_row(*(f"{v:+.6f}" for v in row))
    console.print(matrix)
    table = Table(title="Pose of the scanner in the base frame")
    for name in ("parameter", "value", "std", "CRB"):
        table.add_column(name, justify="left" if name == "parameter" else "right")
    for axis, value, std, crb in zip(
        "xyz", result.translation_m, result.std_translation_mm, result.crb_translation_mm, strict=True
    ):
        table.add_row(f"t_{axis} (mm)", f"{value * 1e3:.2f}", f"{std:.3f}", f"{crb:.3f}")
    for name, value, std, crb in zip(
        ("yaw", "pitch", "roll"),
        result.euler_zyx_deg,
        result.std_euler_zyx_deg,
        result.crb_euler_zyx_deg,
        strict=True,
    ):
        table.add_row(f"{name} (deg, ZYX)", f"{value:.4f}", f"{std:.4f}", f"{crb:.4f}")
    for axis, std, crb in zip("xyz", result.std_rotation_deg, result.crb_rotation_deg, strict=True):
        table.add_row(f"rotation about base {axis} (deg)", "", f"{std:.4f}", f"{crb:.4f}")
    console.print(table)
    console.print(
        f"RMS residual {result.rms_residual_mm:.2f} mm, reduced chi-square {result.reduced_chi_square:.2f}, "
        f"weakest direction: {result.observability.weakest_direction} "
        f"(singular-value ratio {result.observability.condition_ratio:.2e})"
    )
    for note in result.observability.notes:
        console.print(f"[yellow]note:[/] {note}")
    for line in result.estimate_lines():
        console.print(line)
    if result.outliers:
        outliers = Table(title="Waypoints left out")
        for name in ("index", "residual (mm)", "reason"):
            outliers.add_column(name)
        for o in result.outliers:
            outliers.add_row(str(o.index), f"{o.residual_mm:.1f}", o.reason)
        console.print(outliers)
