"""``lasercal run``: calibrate the scanner against the robot, live (or against a fake cell
with ``--dry-run``), and write the results."""

from __future__ import annotations

import contextlib
import signal
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict
from datetime import UTC, datetime
from pathlib import Path
from types import FrameType
from typing import Annotated, Any

import numpy as np
import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, SpinnerColumn, TextColumn
from rich.progress import Progress as RichProgress

from drivers.hokuyo.client import HokuyoScanner
from drivers.ur.client import MotionLimits, URRobot
from lasercal_hw import __version__
from lasercal_hw.cli.common import console, err_console, print_json
from lasercal_hw.cli.solve import print_result
from lasercal_hw.config import JobConfig, load_job, with_overrides
from lasercal_hw.errors import ConfigError, ExitCode, InterruptedRunError, LasercalError
from lasercal_hw.models import FloatArray
from lasercal_hw.run.devices import Robot, Scanner
from lasercal_hw.run.dry_run import FakeCellProcess
from lasercal_hw.run.outputs import SESSION_FILE, transform_error, write_outputs
from lasercal_hw.run.preflight import PreflightReport
from lasercal_hw.run.resume import META_JOB, META_WAYPOINTS, recorded_job, resume_state
from lasercal_hw.run.sequencer import Progress, ResumeState, RunOutcome, Sequencer
from lasercal_hw.run.waypoints import job_waypoints
from lasercal_hw.session.reader import read_session
from lasercal_hw.session.recorder import SessionRecorder

OVERHEAD_TARGET = 0.10


class ProgressView:
    """Renders the sequencer's progress events live (a bar plus one line per waypoint)."""

    def __init__(self, target: Console) -> None:
        self._progress = RichProgress(
            SpinnerColumn(),
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[status]}"),
            console=target,
        )
        self._task = self._progress.add_task("starting", total=None, status="")

    def __enter__(self) -> ProgressView:
        self._progress.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self._progress.stop()

    @contextlib.contextmanager
    def paused(self) -> Iterator[None]:
        """Stop the live display (e.g. for a prompt), then resume it."""
        self._progress.stop()
        try:
            yield
        finally:
            self._progress.start()

    def __call__(self, event: Progress) -> None:
        """Show one progress event."""
        status = []
        if event.scans_averaged is not None:
            status.append(f"{event.scans_averaged} scans")
        if event.time_left_s is not None and event.waypoint_count:
            status.append(f"~{event.time_left_s:.0f} s left")
        self._progress.update(
            self._task,
            description=escape(event.message),
            total=event.waypoint_count or None,
            completed=event.completed,
            status=", ".join(status),
        )
        if event.stage in ("centre", "skip", "retry"):
            colour = {"centre": "green", "skip": "yellow", "retry": "yellow"}[event.stage]
            self._progress.console.print(f"[{colour}]{escape(event.message)}[/]")


@contextlib.contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """Turn SIGTERM into KeyboardInterrupt so it stops the arm like Ctrl-C does."""

    def interrupt(signum: int, frame: FrameType | None) -> None:
        raise KeyboardInterrupt(f"signal {signal.Signals(signum).name}")

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _require_confirmation_possible(yes: bool, dry_run: bool) -> None:
    if yes or dry_run or sys.stdin.isatty():
        return
    raise ConfigError(
        "refusing to move the robot without confirmation: standard input is not a terminal, so "
        "nobody can answer the prompt; check the cell and pass --yes to run unattended"
    )


def _confirm(
    job: JobConfig, waypoints: FloatArray, view: ProgressView, ui: Console
) -> Callable[[PreflightReport], None]:
    def ask(report: PreflightReport) -> None:
        motion = job.motion
        with view.paused():
            ui.print(
                f"Preflight passed. About to move the {report.robot.model} at {job.robot.host} (serial "
                f"{report.robot.serial_number}) to its retract pose and through {len(waypoints)} waypoints, "
                f"{motion.move} moves capped at {motion.speed_m_s} m/s and {motion.accel_m_s2} m/s^2, "
                f"dwelling {job.dwell_s:g} s each. Keep clear of the arm."
            )
            try:
                agreed = typer.confirm("Start the motion?", default=False, err=True)
            except typer.Abort:  # Ctrl-C, SIGTERM or end of input at the prompt
                raise InterruptedRunError("interrupted at the confirmation prompt; nothing moved") from None
            if not agreed:
                raise InterruptedRunError("the operator declined at the confirmation prompt; nothing moved")

    return ask


def _connect(job: JobConfig, stack: contextlib.ExitStack) -> tuple[Robot, Scanner]:
    assert job.robot.host is not None
    limits = MotionLimits(
        max_speed_m_s=job.motion.speed_m_s,
        max_accel_m_s2=job.motion.accel_m_s2,
        max_joint_speed_rad_s=job.motion.joint_speed_rad_s,
        max_joint_accel_rad_s2=job.motion.joint_accel_rad_s2,
    )
    robot = URRobot.connect(job.robot.host, limits=limits)
    stack.callback(robot.close)
    scanner = HokuyoScanner.open(job.scanner.url, timeout_s=job.scanner.timeout_s)
    stack.callback(scanner.close)
    return robot, scanner


def _warn_if_rods_differ(job: JobConfig, cell_rod: dict[str, Any] | None, ui: Console) -> None:
    """A dry run only finds the rod the fake cell holds: say so when the job describes another."""
    if cell_rod is None:
        return
    rod = job.rod.rod_line()
    same = (
        np.allclose(cell_rod["origin_m"], rod.origin_m, atol=1e-3)
        and np.allclose(np.asarray(cell_rod["direction"]) / np.linalg.norm(cell_rod["direction"]),
                        rod.unit_direction(), atol=1e-3)
        and abs(cell_rod["radius_m"] - rod.radius_m) < 1e-4
    )
    if not same:
        ui.print(
            f"[yellow]warning:[/] the fake cell's rod {escape(str(cell_rod))} differs from the job's rod; "
            "give the dry run a --scene whose \\[rod] matches the job (docs/extraction.md)"
        )


def _toml_floats(values: FloatArray) -> str:
    """A TOML array of floats at full precision."""
    return "[" + ", ".join(repr(float(v)) for v in values) + "]"


def _write_rod_scene(job: JobConfig, path: Path) -> Path:
    """A scene file that changes only the default scene's rod to the job's rod (kept with
    the outputs, so the dry run can be repeated with ``--scene``)."""
    rod = job.rod.rod_line()
    path.write_text(
        "# Written by `lasercal run --dry-run`: the default scene, holding the job's rod.\n"
        f"[rod]\norigin_m = {_toml_floats(rod.origin_m)}\ndirection = {_toml_floats(rod.direction)}\n"
        f"radius_m = {rod.radius_m!r}\nlength_m = {rod.length_m!r}\n",
        encoding="utf-8",
    )
    return path


def _default_out_dir() -> Path:
    return Path("lasercal-out") / datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")


def _prepare_out_dir(out_dir: Path) -> Path:
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"cannot create the output folder {out_dir}: {exc.strerror or exc}") from exc
    if (out_dir / SESSION_FILE).exists():
        raise ConfigError(f"{out_dir / SESSION_FILE} already exists; choose another --out or use --resume")
    return out_dir


def _overhead_with_io(outcome: RunOutcome, command_s: float) -> float:
    """Overhead share counting connecting and writing the outputs too."""
    busy_s = outcome.timings.motion_s + outcome.timings.dwell_s
    return (command_s - busy_s) / busy_s if busy_s > 0 else 0.0


def _print_summary(
    outcome: RunOutcome, files: dict[str, Path], truth_error: dict[str, float] | None, command_s: float
) -> None:
    print_result(outcome.result)
    console.print(f"[dim]{escape(outcome.refinement)}[/]")
    for skipped in outcome.skipped:
        console.print(f"[yellow]waypoint {skipped.index} skipped:[/] {escape(skipped.reason)}")
    for check in outcome.verdict.checks:
        colour = "green" if check.passed else "red"
        console.print(f"[{colour}]{escape(check.describe())}[/]")
    timings = outcome.timings
    console.print(
        f"time: wall {timings.wall_s:.1f} s, motion {timings.motion_s:.1f} s, dwell {timings.dwell_s:.1f} s; "
        f"overhead {100 * timings.overhead_fraction:.1f} % of motion+dwell "
        f"(target under {100 * OVERHEAD_TARGET:.0f} %); with connecting and writing outputs "
        f"{command_s:.1f} s, {100 * _overhead_with_io(outcome, command_s):.1f} %"
    )
    if truth_error is not None:
        e = truth_error
        console.print(
            f"dry run: error against the fake cell's ground truth {e['translation_mm']:.2f} mm, "
            f"{e['rotation_deg']:.3f} deg (first pass {e['first_pass_translation_mm']:.2f} mm, "
            f"{e['first_pass_rotation_deg']:.3f} deg)"
        )
    for name, path in files.items():
        console.print(f"  {name}: {escape(str(path))}")
    verdict = "[bold green]PASSED[/]" if outcome.verdict.passed else "[bold red]QUALITY GATE FAILED[/]"
    console.print(f"verdict: {verdict}")


def _json_document(
    outcome: RunOutcome,
    files: dict[str, Path],
    truth: FloatArray | None,
    cell: dict[str, Any] | None,
    command_s: float,
) -> dict[str, Any]:
    result = outcome.result
    document: dict[str, Any] = {
        "passed": outcome.verdict.passed,
        "verdict": outcome.verdict.as_dict(),
        "T_base_laser": result.T_base_laser,
        "translation_m": result.translation_m,
        "euler_zyx_deg": result.euler_zyx_deg,
        "quaternion_xyzw": result.quaternion_xyzw,
        "std_translation_mm": result.std_translation_mm,
        "std_rotation_deg": result.std_rotation_deg,
        "rms_residual_mm": result.rms_residual_mm,
        "observations": len(outcome.observations),
        "skipped": [{"index": s.index, "reason": s.reason} for s in outcome.skipped],
        "refinement": outcome.refinement,
        "timings": {
            "wall_s": outcome.timings.wall_s,
            "motion_s": outcome.timings.motion_s,
            "dwell_s": outcome.timings.dwell_s,
            "overhead_fraction": outcome.timings.overhead_fraction,
            "command_s": command_s,
            "overhead_fraction_with_io": _overhead_with_io(outcome, command_s),
        },
        "outputs": {name: str(path) for name, path in files.items()},
        "dry_run": cell is not None,
    }
    if cell is not None:
        document["fake_cell"] = cell
    if truth is not None:
        document["ground_truth"] = {
            "T_base_laser": np.asarray(truth).tolist(),
            "error": transform_error(result.matrix(), truth),
            "first_pass_error": transform_error(outcome.first_pass.matrix(), truth),
        }
    return document


RobotOption = Annotated[str | None, typer.Option("--robot", help="Robot controller host, e.g. 192.168.1.10.")]
ScannerOption = Annotated[
    str | None, typer.Option("--scanner", help="Scanner URL (default scip+tcp://192.168.0.10:10940).")
]
ConfigOption = Annotated[Path | None, typer.Option("--config", help="Job file (TOML); defaults without it.")]
DwellOption = Annotated[float | None, typer.Option("--dwell", help="Dwell per waypoint in s (default 3).")]
YesOption = Annotated[bool, typer.Option("--yes", "-y", help="Do not ask before moving the robot.")]
JsonOption = Annotated[bool, typer.Option("--json", help="Print one JSON document (progress on stderr).")]
OutOption = Annotated[Path | None, typer.Option("--out", help="Output folder (./lasercal-out/<time>).")]
DryRunOption = Annotated[
    bool, typer.Option("--dry-run", help="Run against a fake cell started on a free loopback address.")
]
ResumeOption = Annotated[Path | None, typer.Option("--resume", help="Continue an interrupted session.mcap.")]
SceneOption = Annotated[Path | None, typer.Option("--scene", help="Scene file for the --dry-run fake cell.")]


def run_command(
    robot: RobotOption = None,
    scanner: ScannerOption = None,
    config: ConfigOption = None,
    dwell: DwellOption = None,
    yes: YesOption = False,
    as_json: JsonOption = False,
    out: OutOption = None,
    dry_run: DryRunOption = False,
    resume: ResumeOption = None,
    scene: SceneOption = None,
) -> None:
    """Run a calibration: preflight, background, waypoints, solve, quality gates, outputs.

    Exit codes: 0 passed, 1 a quality gate failed (results still written), 2 bad
    configuration, 3 device error (including a protective stop), 4 calibration impossible
    (degenerate data), 130 interrupted (the arm is stopped; continue with --resume).
    """
    if scene is not None and not dry_run:
        raise ConfigError("--scene only applies to --dry-run")
    _require_confirmation_possible(yes, dry_run)
    ui = err_console if as_json else console
    overrides: dict[str, Any] = {"robot.host": robot, "scanner.url": scanner}
    if resume is not None:
        if config is not None or dwell is not None or out is not None:
            raise ConfigError("--resume continues the recorded job: leave out --config, --dwell and --out")
        previous = read_session(resume)
        job, waypoints = recorded_job(previous)
        job = with_overrides(job, overrides)
        out_dir = resume.parent
        state: ResumeState | None = resume_state(previous)
    else:
        job = with_overrides(load_job(config), overrides | {"dwell_s": dwell, "output.dir": out})
        waypoints = job_waypoints(job)
        out_dir = _prepare_out_dir(job.output.dir or _default_out_dir())
        state = None

    truth: FloatArray | None = None
    cell_info: dict[str, Any] | None = None
    with _sigterm_as_interrupt(), contextlib.ExitStack() as stack:
        if dry_run:
            ui.print("starting a fake cell for the dry run ...")
            if scene is None:  # the fake cell holds the rod the job describes
                scene = _write_rod_scene(job, out_dir / "dry_run_scene.toml")
            cell = stack.enter_context(FakeCellProcess(scene=scene))
            truth = cell.ground_truth
            cell_info = {"address": cell.address, "pid": cell.pid}
            job = with_overrides(job, {"robot.host": cell.robot_host, "scanner.url": cell.scanner_url})
            ui.print(f"fake cell on {cell.address} (pid {cell.pid}): scanner {cell.scanner_url}")
            _warn_if_rods_differ(job, cell.info.get("rod"), ui)
        if job.robot.host is None:
            raise ConfigError("no robot given: pass --robot HOST (or set robot.host in the job file)")
        started_s = time.monotonic()
        robot_device, scanner_device = _connect(job, stack)
        meta = {
            META_JOB: job.model_dump(mode="json"),
            META_WAYPOINTS: np.asarray(waypoints).tolist(),
            "software_version": __version__,
            "dry_run": dry_run,
            "started_utc": datetime.now(UTC).isoformat(),
            "robot": asdict(robot_device.identity()) | {"host": job.robot.host},
            "scanner": asdict(scanner_device.identity()) | {"url": job.scanner.url},
        }
        if truth is not None:
            meta["ground_truth_T_base_laser"] = truth.tolist()
        session_path = resume if resume is not None else out_dir / SESSION_FILE
        if resume is not None:
            recorder = SessionRecorder.resume(resume, meta)
        else:
            recorder = SessionRecorder(session_path, meta)
        stack.callback(recorder.close)
        view = stack.enter_context(ProgressView(ui))
        sequencer = Sequencer(
            robot_device,
            scanner_device,
            recorder,
            job,
            waypoints,
            on_progress=view,
            before_motion=None if yes or dry_run else _confirm(job, waypoints, view, ui),
            resume=state,
        )
        try:
            outcome = sequencer.run()
        except (LasercalError, KeyboardInterrupt):
            err_console.print(
                f"recording kept in {escape(str(session_path))}; after fixing the cause continue with: "
                f"lasercal run --resume {escape(str(session_path))}"
            )
            raise
        files = {"session": session_path} | write_outputs(
            out_dir, outcome, job, ground_truth=truth, title=f"lasercal {'dry run' if dry_run else 'run'}"
        )
        command_s = time.monotonic() - started_s

    if as_json:
        print_json(_json_document(outcome, files, truth, cell_info, command_s))
    else:
        error = None
        if truth is not None:
            first = transform_error(outcome.first_pass.matrix(), truth)
            error = transform_error(outcome.result.matrix(), truth) | {
                f"first_pass_{key}": value for key, value in first.items()
            }
        _print_summary(outcome, files, error, command_s)
    if not outcome.verdict.passed:
        failures = "; ".join(outcome.verdict.failures())
        err_console.print(f"[bold red]quality gate failed:[/] {escape(failures)}")
        raise typer.Exit(int(ExitCode.QUALITY_GATE_FAILED))
