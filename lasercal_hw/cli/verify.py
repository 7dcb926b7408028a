"""``lasercal verify``: is the active calibration still right? A thin adapter: options in,
``lasercal_hw.verify.verify`` (on the run's engine), the events rendered, an exit code
out. The heavy modules are imported when the command runs, not when the CLI starts."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from lasercal_hw.cli.common import (
    DryRunOption,
    JsonOption,
    RobotOption,
    ScannerOption,
    SceneOption,
    YesOption,
    check_scene,
)
from lasercal_hw.errors import ExitCode

if TYPE_CHECKING:
    from lasercal_hw.verify.procedure import VerifyReport

CalibrationOption = Annotated[
    Path, typer.Option("--calibration", help="The result.json of the calibration to check.")
]
ConfigOption = Annotated[
    Path | None,
    typer.Option("--config", help="Job file (TOML); default: the job recorded with the calibration."),
]
WaypointsOption = Annotated[
    int | None,
    typer.Option("--waypoints", min=2, max=20, help="Waypoints to visit (default verify.waypoints, 4)."),
]
OutOption = Annotated[
    Path | None, typer.Option("--out", help="Output folder (./lasercal-out/verify-<time>).")
]

_VERDICT_COLOURS = {
    "ok": "bold green",
    "inconclusive": "bold yellow",
    "degraded": "bold yellow",
    "recalibrate": "bold red",
}


def _triple(values: list[float], digits: int) -> str:
    return "(" + ", ".join(f"{v:.{digits}f}" for v in values) + ")"


def _print_summary(report: VerifyReport) -> None:
    from rich.markup import escape

    from lasercal_hw.cli.common import console

    outcome = report.outcome
    document = report.document()
    test = document["test"]
    console.print(f"checked {escape(str(outcome.calibration.path))} at waypoints {outcome.selection.indices}")
    for check in outcome.identity:
        console.print(f"[{'green' if check.matches else 'red'}]{escape(check.describe())}[/]")
    for index, reason in outcome.skipped:
        console.print(f"[yellow]waypoint {index} skipped:[/] {escape(reason)}")
    if test is not None:
        for waypoint in test["waypoints"]:
            du, dv = waypoint["residual_mm"]
            console.print(
                f"  waypoint {waypoint['index']:3d}: measured - predicted ({du:+.2f}, {dv:+.2f}) mm, "
                f"{waypoint['whitened_norm']:.2f} sigma"
            )
        c = test["correction"]
        console.print(
            f"chi-square {test['chi_square']:.2f} on {test['dof']} dof (limit {test['threshold']:.2f} at "
            f"{test['false_alarm_rate']:.0%} false alarms, p = {test['p_value']:.3g}); estimated move "
            f"{c['shift_norm_mm']:.2f} +- {c['std_shift_norm_mm']:.2f} mm, {c['turn_norm_deg']:.3f} +- "
            f"{c['std_turn_norm_deg']:.3f} deg"
        )
        seen = test["detectable"]
        console.print(
            f"smallest move it detects ({seen['detection_probability']:.0%} of the time): shift "
            f"{_triple(seen['shift_mm'], 2)} mm along base x, y, z; turn {_triple(seen['turn_deg'], 3)} deg "
            f"about them; in its weakest direction shift {seen['weakest_shift_mm']:.2f} mm, turn "
            f"{seen['weakest_turn_deg']:.3f} deg (tolerance {document['tolerance']['mm']:g} mm, "
            f"{document['tolerance']['deg']:g} deg)"
        )
    timings = document["timings"]
    fraction = timings["fraction_of_calibration"]
    share = f", {100 * fraction:.0f} % of the calibration's" if fraction is not None else ""
    console.print(f"time: motion {timings['motion_s']:.1f} s, dwell {timings['dwell_s']:.1f} s{share}")
    for name, path in report.files.items():
        console.print(f"  {name}: {escape(str(path))}")
    status = outcome.verdict.status
    console.print(
        f"verdict: [{_VERDICT_COLOURS[status]}]{status.upper()}[/]: {escape(outcome.verdict.reason)}"
    )


def verify_command(
    calibration: CalibrationOption,
    robot: RobotOption = None,
    scanner: ScannerOption = None,
    config: ConfigOption = None,
    waypoints: WaypointsOption = None,
    yes: YesOption = False,
    as_json: JsonOption = False,
    out: OutOption = None,
    dry_run: DryRunOption = False,
    scene: SceneOption = None,
) -> None:
    """Check a calibration: visit a few of its waypoints, compare the rod centres with
    what it predicts, and check the scanner, robot and rod are the ones it was made with.

    Exit codes: 0 ok, 1 inconclusive, degraded or recalibrate (the verdict and its reason are printed;
    with --json in the "verdict" field), 2 bad input, 3 device error (including a
    protective stop), 4 nothing to verify with (e.g. no waypoint crosses the calibrated
    plane), 130 interrupted (the arm is stopped).
    """
    from rich.markup import escape

    from lasercal_hw.cli.common import console, err_console, print_json
    from lasercal_hw.cli.run import (
        ProgressView,
        confirm_before_motion,
        interrupt_once,
        require_confirmation_possible,
    )
    from lasercal_hw.config import load_job
    from lasercal_hw.run.engine import default_out_dir
    from lasercal_hw.verify.procedure import VerifyRequest, verify

    check_scene(scene, dry_run)
    require_confirmation_possible(yes, dry_run)
    ui = err_console if as_json else console
    stamp = default_out_dir()
    request = VerifyRequest(
        out_dir=out or stamp.with_name(f"verify-{stamp.name}"),
        job=load_job(config) if config is not None else None,
        robot_host=robot,
        scanner_url=scanner,
        waypoints=waypoints,
        dry_run=dry_run,
        scene=scene,
    )
    with interrupt_once(), ProgressView(ui) as view:
        confirm = None if yes or dry_run else confirm_before_motion(view, ui)
        report = verify(request, calibration, on_event=view, confirm=confirm)
    if as_json:
        print_json(report.document())
    else:
        _print_summary(report)
    if report.verdict.status != "ok":
        err_console.print(f"[bold red]verify: {report.verdict.status}:[/] {escape(report.verdict.reason)}")
        raise typer.Exit(int(ExitCode.QUALITY_GATE_FAILED))
