"""``lasercal run``: calibrate the scanner against the robot, live (or against a fake cell
with ``--dry-run``), and write the results. A thin adapter: options in, the engine
(``lasercal_hw.run.engine``), the events rendered, an exit code out."""

from __future__ import annotations

import contextlib
import shlex
import signal
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from types import FrameType
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, SpinnerColumn, TextColumn
from rich.progress import Progress as RichProgress

from lasercal_hw.cli.common import (
    DryRunOption,
    FoxgloveOption,
    FoxglovePortOption,
    JsonOption,
    RobotOption,
    SceneOption,
    YesOption,
    check_scene,
    console,
    err_console,
    foxglove_line,
    print_json,
)
from lasercal_hw.cli.solve import print_result
from lasercal_hw.config import JobConfig, load_job, with_overrides
from lasercal_hw.errors import ConfigError, ExitCode, InterruptedRunError
from lasercal_hw.live.foxglove import FoxgloveLiveView, foxglove_view
from lasercal_hw.run.cell import CELL_FILE, CellReport, CellRunRequest, calibrate_cell, names_a_cell
from lasercal_hw.run.engine import MotionPlan, RunEvent, RunReport, RunRequest, calibrate, default_out_dir

OVERHEAD_TARGET = 0.10


_LINE_COLOURS = {"centre": "green", "skip": "yellow", "warning": "yellow", "scanner_result": "bold"}


class ProgressView:
    """Renders a run's events: one line per waypoint, stage, skip and warning, and on a
    terminal a live bar below them, shown from the first progress step on (an error before it
    prints alone) and stopped before anything goes to stderr (no line glued to the bar). A log
    or a pipe gets the lines only."""

    def __init__(self, target: Console) -> None:
        self._live = target.is_terminal
        self._started = False
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
        return self

    def __exit__(self, *exc_info: object) -> None:
        self._stop()

    def _stop(self) -> None:
        if self._started:
            self._progress.stop()
            self._started = False

    @contextlib.contextmanager
    def paused(self) -> Iterator[None]:
        """Stop the live display (e.g. for a prompt), then resume it."""
        was_started = self._started
        self._stop()
        try:
            yield
        finally:
            if was_started:
                self._progress.start()
                self._started = True

    def __call__(self, event: RunEvent) -> None:
        """Show one run event: progress moves the bar; centres, skips, retries, warnings and
        where the recording was kept are printed as lines, each led by its scanner's name in a
        cell job."""
        data = event.data
        text = escape(_scanner_led(event))
        if event.kind == "progress":
            if self._live and not self._started:
                self._progress.start()
                self._started = True
            status = []
            if data["scans_averaged"] is not None:
                status.append(f"{data['scans_averaged']} scans")
            if data["time_left_s"] is not None and data["waypoint_count"]:
                status.append(f"~{data['time_left_s']:.0f} s left")
            self._progress.update(
                self._task,
                description=text,
                total=data["waypoint_count"] or None,
                completed=data["completed"],
                status=", ".join(status),
            )
            if data["stage"] == "retry":
                self._progress.console.print(f"[yellow]{text}[/]")
        elif event.kind in _LINE_COLOURS:
            self._progress.console.print(f"[{_LINE_COLOURS[event.kind]}]{text}[/]")
        elif event.kind == "stage":
            self._progress.console.print(text)
        elif event.kind == "stopped":  # where the recording is: with the error, on stderr
            self._stop()
            err_console.print(escape(stopped_line(event.message, event.data)))


def _scanner_led(event: RunEvent) -> str:
    """The event's message, led by ``NAME:`` where a cell job's scanner run sent it (its
    ``scanner_result`` names the scanner itself)."""
    scanner = event.data.get("scanner")
    if scanner is None or event.kind == "scanner_result":
        return event.message
    return f"{scanner}: {event.message}"


def stopped_line(message: str, data: dict[str, Any]) -> str:
    """The engine's ``stopped`` event in the CLI's words: where the recording is and the
    command that resumes it (the recording alone says whether it was a dry run); the event's
    own message when nothing was recorded."""
    session = data.get("session")
    if session is None:
        return message
    if not data.get("resumable"):
        return f"recording kept in {session}; start again"
    command = f"lasercal run --resume {shlex.quote(str(data.get('resume') or session))}"
    when = "" if data.get("interrupted") else "after fixing the cause, "
    return f"recording kept in {session}; {when}continue with: {command}"


@contextlib.contextmanager
def interrupt_once() -> Iterator[None]:
    """Ctrl-C (SIGINT) and SIGTERM stop the run as KeyboardInterrupt; later ones are ignored
    until the run has stopped the arm and closed its recording (a terminal sends SIGINT to
    the whole process group, and an impatient operator presses Ctrl-C twice)."""
    stopping = (signal.SIGINT, signal.SIGTERM)

    def interrupt(signum: int, frame: FrameType | None) -> None:
        for each in stopping:
            signal.signal(each, signal.SIG_IGN)
        raise KeyboardInterrupt() if signum == signal.SIGINT else KeyboardInterrupt(
            f"signal {signal.Signals(signum).name}"
        )

    previous = {each: signal.signal(each, interrupt) for each in stopping}
    try:
        yield
    finally:
        for each, handler in previous.items():
            signal.signal(each, handler)


_NO_CONFIRMATION = (
    "refusing to move the robot without confirmation: standard input is not a terminal, so "
    "nobody can answer the prompt; check the cell and pass --yes to run unattended"
)


def require_confirmation_possible(yes: bool, dry_run: bool) -> None:
    """Refuse before connecting when nobody could confirm the motion (``dry_run``: nothing to
    confirm, or not known yet: a resumed recording says whether it was a dry run)."""
    if yes or dry_run or sys.stdin.isatty():
        return
    raise ConfigError(_NO_CONFIRMATION)


def confirm_before_motion(view: ProgressView, ui: Console) -> Callable[[MotionPlan], None]:
    def ask(plan: MotionPlan) -> None:
        if plan.dry_run:  # a fake cell's arm: nothing to confirm
            return
        if not sys.stdin.isatty():
            raise ConfigError(_NO_CONFIRMATION)
        with view.paused():
            ui.print(f"Preflight passed. {plan.summary()} Keep clear of the arm.")
            try:
                agreed = typer.confirm("Start the motion?", default=False, err=True)
            except typer.Abort:  # Ctrl-C, SIGTERM or end of input at the prompt
                raise InterruptedRunError("interrupted at the confirmation prompt; nothing moved") from None
            if not agreed:
                raise InterruptedRunError("the operator declined at the confirmation prompt; nothing moved")

    return ask


def _print_summary(report: RunReport) -> None:
    outcome = report.outcome
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
        f"{report.command_s:.1f} s, {100 * report.overhead_fraction_with_io:.1f} %"
    )
    e = report.truth_error()
    if e is not None:
        console.print(
            f"dry run: error against the fake cell's ground truth {e['translation_mm']:.2f} mm, "
            f"{e['rotation_deg']:.3f} deg (first pass {e['first_pass_translation_mm']:.2f} mm, "
            f"{e['first_pass_rotation_deg']:.3f} deg)"
        )
    for name, path in report.files.items():
        console.print(f"  {name}: {escape(str(path))}")
    verdict = "[bold green]PASSED[/]" if outcome.verdict.passed else "[bold red]QUALITY GATE FAILED[/]"
    console.print(f"verdict: {verdict}")


@contextlib.contextmanager
def _live_view(port: int | None, ui: Console) -> Iterator[FoxgloveLiveView | None]:
    """The ``--foxglove`` view on ``port`` (None: none) for the run, its address said once."""
    with foxglove_view(port) as live:
        if live is not None:
            ui.print(escape(foxglove_line(live.url)))
        yield live


def _run_cell(
    job: JobConfig, scanner_name: str | None, robot: str | None, dry_run: bool, scene: Path | None,
    resume: Path | None, *, yes: bool, as_json: bool, live_port: int | None,
) -> None:
    """``lasercal run`` of a job with ``[scanners.NAME]``: every scanner (or the one named) in
    turn, one folder each, the scanner-to-scanner transforms at the end (docs/cell.md); shown
    in the Foxglove view on ``live_port`` (every scanner in one scene) when given."""
    ui = err_console if as_json else console
    request = CellRunRequest(
        job=job,
        out_dir=job.output.dir or default_out_dir(),
        scanners=None if scanner_name is None else (scanner_name,),
        robot_host=robot,
        dry_run=dry_run,
        scene=scene,
        resume=resume,
        title=f"lasercal {'dry run' if dry_run else 'run'}",
    )
    with interrupt_once(), ProgressView(ui) as view, _live_view(live_port, ui) as live:
        report = calibrate_cell(
            request, on_event=live.watch_cell(request, view) if live else view,
            confirm=None if yes or dry_run else confirm_before_motion(view, ui),
        )
    if as_json:
        print_json(report.document())
    else:
        _print_cell_summary(report)
    if not report.passed:
        failed = ", ".join(name for name, outcome in report.scanners.items() if not outcome.passed)
        err_console.print(f"[bold red]quality gate failed:[/] scanner {escape(failed)}")
        raise typer.Exit(int(ExitCode.QUALITY_GATE_FAILED))


def _print_cell_summary(report: CellReport) -> None:
    document = report.document()
    for name, entry in document["scanners"].items():
        verdict = "[green]passed[/]" if entry["passed"] else "[red]QUALITY GATE FAILED[/]"
        truth = entry.get("ground_truth_error")
        against = "" if truth is None else (
            f"; against the fake cell's truth {truth['translation_mm']:.2f} mm, "
            f"{truth['rotation_deg']:.3f} deg"
        )
        console.print(f"scanner {escape(name)}: {verdict}{against}; {escape(entry['result'])}")
    for pair in document["pairs"]:
        std_mm = ", ".join(f"{v:.2f}" for v in pair["std_translation_mm"])
        std_deg = ", ".join(f"{v:.3f}" for v in pair["std_rotation_deg"])
        line = f"{pair['from']} -> {pair['to']}: std {std_mm} mm, {std_deg} deg"
        truth = pair.get("ground_truth_error")
        if truth is not None:
            line += (
                f"; against the truth {truth['translation_mm']:.2f} mm, {truth['rotation_deg']:.3f} deg, "
                f"largest axis {truth['max_axis_in_std']:.2f} std"
            )
        console.print(escape(line))
        agreement = pair["agreement"]
        console.print(escape(f"  agreement: {agreement['verdict']} ({agreement['reason']})"))
        for note in agreement.get("watcher_centres", {}).get("notes", []):  # reused or left out, and why
            console.print(f"  [yellow]watcher centre:[/] {escape(note)}")
        if "joint" in pair:
            joint_mm = ", ".join(f"{v:.2f}" for v in pair["joint"]["std_translation_mm"])
            console.print(escape(f"  with the shared centres used jointly: std {joint_mm} mm (its joint)"))
    console.print(f"cell: {escape(str(report.out_dir / CELL_FILE))}")
    verdict = "[bold green]PASSED[/]" if report.passed else "[bold red]QUALITY GATE FAILED[/]"
    console.print(f"verdict: {verdict}")


RunScannerOption = Annotated[str | None, typer.Option(
    "--scanner", help="Scanner URL (default: the job's scanner.url), or the name of one of the job's "
    "scanners (scanners.NAME) to calibrate that one alone.")]
ConfigOption = Annotated[Path | None, typer.Option("--config", help="Job file (TOML); defaults without it.")]
DwellOption = Annotated[float | None, typer.Option("--dwell", help="Dwell per waypoint in s (default 3).")]
OutOption = Annotated[Path | None, typer.Option("--out", help="Output folder (./lasercal-out/<time>).")]
ResumeOption = Annotated[Path | None, typer.Option(
    "--resume", help="Continue an interrupted session.mcap, or a cell job's folder.")]


def run_command(
    robot: RobotOption = None,
    scanner: RunScannerOption = None,
    config: ConfigOption = None,
    dwell: DwellOption = None,
    yes: YesOption = False,
    as_json: JsonOption = False,
    out: OutOption = None,
    dry_run: DryRunOption = False,
    resume: ResumeOption = None,
    scene: SceneOption = None,
    adaptive: Annotated[bool, typer.Option("--adaptive", help="Design waypoints as the run goes.")] = False,
    foxglove: FoxgloveOption = False,
    foxglove_port: FoxglovePortOption = 8765,
) -> None:
    """Run a calibration: preflight, background, waypoints, solve, quality gates, outputs.

    Exit codes: 0 passed, 1 a quality gate failed (results still written), 2 bad
    configuration, 3 device error (including a protective stop), 4 calibration impossible
    (degenerate data), 130 interrupted (the arm is stopped; continue with --resume).
    """
    check_scene(scene, dry_run)
    require_confirmation_possible(yes, dry_run or resume is not None)
    ui = err_console if as_json else console
    if resume is not None and (config is not None or dwell is not None or out is not None):
        raise ConfigError("--resume continues the recorded job: leave out --config, --dwell and --out")
    flags = {"trajectory.adaptive": True} if adaptive else {}
    job = with_overrides(load_job(config), {"dwell_s": dwell, "output.dir": out} | flags)
    scanner_name = None if scanner is None or "://" in scanner else scanner
    live_port = foxglove_port if foxglove else None
    if robot is None and job.robot.host is None and not dry_run and resume is None:
        raise ConfigError("no robot given: pass --robot HOST (or set robot.host in the job file)")
    if job.scanners or (resume is not None and names_a_cell(resume)):
        _run_cell(job, scanner_name, robot, dry_run, scene, resume, yes=yes, as_json=as_json,
                  live_port=live_port)
        return
    if scanner_name is not None:  # a one-scanner job's scanner is named "default"
        job.for_scanner(scanner_name)
        scanner = None
    request = RunRequest(
        job=job,
        out_dir=job.output.dir or default_out_dir(),
        robot_host=robot,
        scanner_url=scanner,
        dry_run=dry_run,
        scene=scene,
        resume=resume,
        title=f"lasercal {'dry run' if dry_run else 'run'}",
    )
    with interrupt_once(), ProgressView(ui) as view, _live_view(live_port, ui) as live:
        report = calibrate(
            request, on_event=live.watch(request, view) if live else view,
            confirm=None if yes or dry_run else confirm_before_motion(view, ui)
        )
    if as_json:
        print_json(report.document())
    else:
        _print_summary(report)
    if not report.outcome.verdict.passed:
        failures = "; ".join(report.outcome.verdict.failures())
        err_console.print(f"[bold red]quality gate failed:[/] {escape(failures)}")
        raise typer.Exit(int(ExitCode.QUALITY_GATE_FAILED))
