"""``lasercal trajectory ...``: list presets, show waypoints, check them offline, design them
for a cell (the search itself is ``trajectories.design``)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from pydantic import ValidationError
from rich.table import Table

from lasercal_hw.cli.common import console, err_console, parse_vector, print_json
from lasercal_hw.config import JobConfig, WorkspaceConfig, load_job
from lasercal_hw.errors import ConfigError, ExitCode
from lasercal_hw.geometry import euler_zyx_to_matrix, make_transform
from lasercal_hw.models import RodLine
from lasercal_hw.ur_kinematics import MODELS, URModel, inverse_kinematics_pose, offline_model, robot_model
from trajectories.checks import check_waypoints
from trajectories.presets import DEFAULT_PRESET, PRESETS, get_preset, preset_names
from trajectories.waypoint import Waypoint
from trajectories.waypoint_file import load_waypoints

trajectory_app = typer.Typer(no_args_is_help=True)  # its help is in cli/main.py, where it is listed

_PRESET_ARG = typer.Argument(DEFAULT_PRESET, help=f"Preset name ({', '.join(preset_names())}).")
_FILE_OPT = typer.Option(None, "--file", "-f", help="A waypoint file (.csv or .toml) instead of a preset.")
_JSON_OPT = typer.Option(False, "--json", help="Print one JSON document instead of a table.")
_MODEL_OPT = typer.Option(
    None, "--robot-model", help=f"Robot model of the offline kinematics ({', '.join(MODELS)}; default ur5)."
)


_ROBOT_OPT = typer.Option(
    None, "--robot", help="Read this robot's own kinematics calibration (its primary interface, read only) "
    "and use its DH values instead of a published model's.",
)


def _kinematics(robot: str | None, model_name: str | None) -> URModel:
    """The robot's own kinematics (``--robot``), else the named model, else the UR5."""
    if robot is None:
        return robot_model(model_name or "ur5")
    from drivers.access import DeviceAccess

    calibration = DeviceAccess().read_robot_calibration(robot)
    err_console.print(f"kinematics: the robot's own calibration ({calibration.model}, checksum "
                      f"{calibration.checksum})", markup=False)
    return offline_model(calibration)


def _offline_ik(model: URModel):
    """The offline IK of ``model`` for one UR pose vector."""
    return lambda pose: inverse_kinematics_pose(pose, model=model)


def _rod_document(rod: RodLine) -> dict[str, Any]:
    return {
        "origin_m": [float(v) for v in rod.origin_m],
        "direction": [float(v) for v in rod.unit_direction()],
        "radius_m": rod.radius_m,
        "length_m": rod.length_m,
    }


def _source(preset: str, file: Path | None) -> tuple[str, list[Waypoint], RodLine | None]:
    """Name, waypoints and (for presets) the rod of what the user picked."""
    if file is not None:
        return str(file), load_waypoints(file), None
    chosen = get_preset(preset)
    return chosen.name, chosen.waypoints(), chosen.rod


def list_presets(json_output: bool = _JSON_OPT) -> None:
    """List the trajectory presets."""
    if json_output:
        print_json(
            [
                {"name": n, "description": PRESETS[n].description, "waypoints": len(PRESETS[n].waypoints())}
                for n in preset_names()
            ]
        )
        return
    table = Table("preset", "waypoints", "description")
    for name in preset_names():
        label = f"{name} (default)" if name == DEFAULT_PRESET else name
        table.add_row(label, str(len(PRESETS[name].waypoints())), PRESETS[name].description)
    console.print(table)


def show(preset: str = _PRESET_ARG, file: Path | None = _FILE_OPT, json_output: bool = _JSON_OPT) -> None:
    """Show the waypoints of a preset (or a waypoint file): TCP poses in the base frame."""
    name, waypoints, rod = _source(preset, file)
    if json_output:
        document: dict[str, Any] = {"source": name}
        if file is None:
            document["description"] = PRESETS[name].description
            document["parameters"] = PRESETS[name].parameters.model_dump(mode="json")
        if rod is not None:
            document["rod"] = _rod_document(rod)
        document["waypoints"] = [w.model_dump(mode="json") for w in waypoints]
        print_json(document)
        return
    table = Table("index", "x m", "y m", "z m", "rx rad", "ry rad", "rz rad", "label", title=name)
    for w in waypoints:
        table.add_row(str(w.index), *(f"{v:+.4f}" for v in w.tcp_pose), w.label)
    console.print(table)


_DEFAULT_BOX_MIN = ",".join(str(v) for v in WorkspaceConfig().min_m)
_DEFAULT_BOX_MAX = ",".join(str(v) for v in WorkspaceConfig().max_m)


def check(
    preset: str = _PRESET_ARG,
    file: Path | None = _FILE_OPT,
    box_min: str = typer.Option(_DEFAULT_BOX_MIN, "--box-min", help="Workspace box minimum x,y,z (m)."),
    box_max: str = typer.Option(_DEFAULT_BOX_MAX, "--box-max", help="Workspace box maximum x,y,z (m)."),
    robot_model_name: str | None = _MODEL_OPT,
    robot: str | None = _ROBOT_OPT,
    json_output: bool = _JSON_OPT,
) -> None:
    """Check waypoints offline against a UR5 (CB3) or UR5e model, or the robot's own kinematics
    (--robot: its primary interface, read only), and the workspace box.

    Exit code 2 when any waypoint is unreachable or outside the box (all are listed).
    On a real cell the run's preflight asks the controller instead.
    """
    name, waypoints, rod = _source(preset, file)
    try:
        box = WorkspaceConfig(
            min_m=parse_vector(box_min, 3, "--box-min"), max_m=parse_vector(box_max, 3, "--box-max")
        )
    except ValidationError as exc:
        raise ConfigError(f"--box-min/--box-max: {exc.errors()[0]['msg']}") from None
    model = _kinematics(robot, robot_model_name)
    report = check_waypoints(waypoints, inverse_kinematics=_offline_ik(model), workspace=box, rod=rod)
    if json_output:
        print_json(
            {
                "source": name,
                "ok": report.ok,
                "checked": report.checked,
                "problems": [
                    {"index": p.index, "label": p.label, "reason": p.reason} for p in report.problems
                ],
                "joint_solutions_rad": {
                    str(i): [float(v) for v in np.asarray(q)] for i, q in report.joint_solutions_rad.items()
                },
            }
        )
    else:
        console.print(report.summary(), markup=False)
    if not report.ok:
        raise typer.Exit(code=int(ExitCode.BAD_INPUT))


ScannerPoseOption = Annotated[
    tuple[float, float, float, float, float, float] | None,
    typer.Option(
        "--scanner-pose",
        metavar="X Y Z YAW PITCH ROLL",
        help="Rough scanner pose in the robot base frame: X Y Z (m) YAW PITCH ROLL (deg, ZYX); "
        "default: the job's scanner.nominal.",
    ),
]
ConfigOption = Annotated[
    Path | None, typer.Option("--config", help="Job file: rod, workspace box, gates, dwell.")
]
WaypointCountOption = Annotated[
    int, typer.Option("--waypoints", min=6, max=200, help="How many waypoints to design.")
]
DesignModelOption = Annotated[
    str | None,
    typer.Option(
        "--robot-model", help=f"Robot model ({', '.join(MODELS)}); default: the job's robot.model, or ur5."
    ),
]
OutOption = Annotated[Path, typer.Option("--out", help="Waypoint file to write (CSV).")]
ForceOption = Annotated[
    bool, typer.Option("--force", help="Replace the --out file if it exists (kept otherwise).")
]
SeedOption = Annotated[int, typer.Option("--seed", help="Seed of the search (same seed, same waypoints).")]
ScannerNameOption = Annotated[
    str | None,
    typer.Option(
        "--scanner",
        help="A cell job's scanner to design for (its scanners.NAME table: nominal pose, rod, gates).",
    ),
]
SharedWithOption = Annotated[
    str | None,
    typer.Option(
        "--shared-with",
        help="Another scanner of the cell job: add --shared waypoints whose rod crosses its plane too, at "
        "the distances its own waypoints span (docs/cell.md: shared waypoints).",
    ),
]
SharedCountOption = Annotated[
    int, typer.Option("--shared", min=1, max=20, help="How many shared waypoints --shared-with adds.")
]
SharedUncertaintyOption = Annotated[
    tuple[float, float],
    typer.Option(
        "--shared-pose-uncertainty",
        metavar="METRES DEGREES",
        help="How far off both rough poses may be at the shared waypoints (the scanner's own keep "
        "--pose-uncertainty): shared crossings are rare, a tape measure's 0.05 m 5 deg leaves few.",
    ),
]
UncertaintyOption = Annotated[
    tuple[float, float] | None,
    typer.Option(
        "--pose-uncertainty",
        metavar="METRES DEGREES",
        help="How far off the rough pose may be: metres and degrees; default: the job's "
        "trajectory.pose_uncertainty (0.05 m, 5 deg unless set).",
    ),
]


def _rough_pose(job: JobConfig, scanner_pose: tuple[float, ...] | None) -> np.ndarray:
    """``T_base_laser`` from ``--scanner-pose`` or the job's nominal pose."""
    if scanner_pose is not None:
        x, y, z, yaw, pitch, roll = scanner_pose
        return make_transform(euler_zyx_to_matrix(*np.radians([yaw, pitch, roll])), [x, y, z])
    if job.scanner.nominal is not None:
        return job.scanner.nominal.matrix()
    raise ConfigError(
        "no scanner pose: pass --scanner-pose X Y Z YAW PITCH ROLL (metres, degrees; a tape measure "
        "or the CAD model is enough) or set [scanner.nominal] in the job file"
    )


def _shared_request(job: JobConfig, name: str, count: int, uncertainty: tuple[float, float]) -> Any:
    """What ``--shared-with NAME`` asks of the design: the cell job's scanner ``name``, its rough
    pose and the distances its own waypoints cross its plane at."""
    from lasercal_hw.run.waypoints import job_waypoint_list
    from trajectories.candidates import PoseUncertainty
    from trajectories.plane_crossing import rod_plane_crossings
    from trajectories.shared import SharedRequest
    from trajectories.waypoint import waypoint_matrices

    watcher = job.for_scanner(name)
    if watcher.scanner.nominal is None:
        raise ConfigError(f"--shared-with {name}: the job gives no [scanners.{name}.nominal] pose to "
                          "design for")
    T_base_laser = watcher.scanner.nominal.matrix()
    own = job_waypoint_list(watcher)
    ranges_m = rod_plane_crossings(waypoint_matrices(own), watcher.rod.rod_line(), T_base_laser).range_m
    ranges_m = ranges_m[np.isfinite(ranges_m)]
    if not len(ranges_m):
        raise ConfigError(f"--shared-with {name}: none of its waypoints crosses its plane; design "
                          "those first")
    span_m = (float(ranges_m.min()), float(ranges_m.max()))
    return SharedRequest(name, T_base_laser, span_m, count, PoseUncertainty(*uncertainty))


def design(
    scanner_pose: ScannerPoseOption = None,
    pose_uncertainty: UncertaintyOption = None,
    config: ConfigOption = None,
    scanner_name: ScannerNameOption = None,
    shared_with: SharedWithOption = None,
    shared_count: SharedCountOption = 4,
    shared_uncertainty: SharedUncertaintyOption = (0.03, 3.0),
    waypoints: WaypointCountOption = 20,
    robot_model_name: DesignModelOption = None,
    robot: str | None = _ROBOT_OPT,
    out: OutOption = Path("waypoints.csv"),
    force: ForceOption = False,
    seed: SeedOption = 0,
    json_output: bool = _JSON_OPT,
) -> None:
    """Design waypoints for your cell that minimise the calibration's Cramér-Rao bound.

    Every waypoint keeps the rules a run checks (reach on one IK branch, no wrist flip,
    bounded joint steps, workspace box, rod crossing the scan plane with a margin that
    holds anywhere inside the pose uncertainty, field of view, range, line of sight past the
    robot's base), in a short visiting order. Prints the predicted std per axis and writes a
    waypoint file for `lasercal run` (trajectory.waypoints_file) and `trajectory check`.
    With rod.estimate_axis in the job, the std are those of the pose with the rod's axis
    estimated alongside, and the tool turns widely about the rod to make that possible.
    In a cell job, --scanner NAME designs for that scanner, and --shared-with OTHER adds
    waypoints where OTHER sees the rod too, inside the distances OTHER is calibrated at.
    """
    from rich.progress import BarColumn, Progress, TextColumn

    from lasercal_hw.calibration.model import extended_fisher_information
    from trajectories.candidates import PoseUncertainty
    from trajectories.design import design as design_waypoints
    from trajectories.design import request_for_job
    from trajectories.waypoint_file import waypoints_to_csv

    if out.exists() and not force:  # checked before the design's minutes, and no file is lost
        raise ConfigError(f"{out} already exists: choose another --out, or pass --force to replace it")
    cell = load_job(config)
    job = cell.for_scanner(scanner_name) if scanner_name is not None else cell
    if shared_with is not None and shared_with == scanner_name:
        raise ConfigError(f"--shared-with {shared_with}: name another scanner of the job than --scanner")
    translation_m, rotation_deg = pose_uncertainty or job.trajectory.pose_uncertainty
    for option, (metres, degrees) in (("--pose-uncertainty", (translation_m, rotation_deg)),
                                      ("--shared-pose-uncertainty", shared_uncertainty)):
        if not (0.0 <= metres <= 0.5 and 0.0 <= degrees <= 45.0):
            raise ConfigError(f"{option} {metres:g} {degrees:g}: give 0-0.5 m and 0-45 deg")
    shared = None
    if shared_with is not None:
        shared = _shared_request(cell, shared_with, shared_count, shared_uncertainty)
    model = _kinematics(robot, robot_model_name or job.robot.model)
    request = request_for_job(
        job,
        _rough_pose(job, scanner_pose),
        model,
        uncertainty=PoseUncertainty(translation_m, rotation_deg),
        waypoints=waypoints,
        seed=seed,
    )
    with Progress(TextColumn("{task.description}"), BarColumn(), console=err_console, transient=True) as bar:
        task = bar.add_task("designing", total=1.0)
        if shared is None:
            result = design_waypoints(
                request,
                extended_fisher_information,
                lambda stage, f: bar.update(task, description=stage, completed=f),
            )
        else:
            from trajectories.shared import design_with_shared

            bar.update(task, description="shared crossings, then the scanner's own")
            result = design_with_shared(request, shared, extended_fisher_information)
    if not result.waypoints:
        raise ConfigError(f"no waypoint keeps every rule for this scanner pose: {result.weak_direction}")
    report = check_waypoints(
        result.waypoints,
        inverse_kinematics=_offline_ik(model),
        workspace=job.workspace,
        rod=request.rules.rod,
    )
    if not report.ok:  # the search keeps these rules itself: this would be a bug
        raise ConfigError("the design fails trajectory check:\n" + report.summary())
    try:
        out.write_text(waypoints_to_csv(result.waypoints), encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"cannot write {out}: {exc.strerror or exc}") from None
    if json_output:
        print_json(
            {
                "out": str(out),
                "robot_model": model.name,
                "waypoints": [w.model_dump(mode="json") for w in result.waypoints],
                "predicted_std_translation_mm": result.std_translation_mm.tolist(),
                "predicted_std_rotation_deg": result.std_rotation_deg.tolist(),
                "rod_axis_estimated": request.estimate_axis,
                "score": result.score,
                "weak_direction": result.weak_direction,
                "notes": result.notes,
                "candidates": {"drawn": result.candidates_drawn, "kept": result.candidates_kept},
            }
        )
        return
    _print_design(result, request, model, out, _job_lines(out, config, scanner_name))


def _job_lines(out: Path, config: Path | None, scanner_name: str | None) -> str:
    """Where the designed file goes in the job: its table, and its path as the job file reads it
    (relative to the job file's folder, as ``load_job`` resolves it; absolute outside that folder)."""
    scope = f"scanners.{scanner_name}." if scanner_name is not None else ""
    path = out
    if config is not None:
        folder = config.resolve().parent
        path = out.resolve()
        path = path.relative_to(folder) if path.is_relative_to(folder) else path
    where = f" in {config}" if config is not None else ""
    return (
        f"[{scope}trajectory] waypoints_file = \"{path.as_posix()}\"{where}, "
        f"and the scanner pose as [{scope or 'scanner.'}nominal]"
    )


def _print_design(result: Any, request: Any, model: URModel, out: Path, job_lines: str) -> None:
    """The predicted std per axis, what stays weak, and how to use the file (``job_lines``)."""
    gate_mm, gate_deg = request.targets.translation_mm, request.targets.rotation_deg
    title = f"{len(result.waypoints)} waypoints for a {model.name}" + (
        ", rod axis estimated with the pose" if request.estimate_axis else ""
    )
    table = Table("axis", "predicted std", "gate", title=title)
    for axis, value in zip("xyz", result.std_translation_mm, strict=True):
        table.add_row(f"translation {axis}", f"{value:.2f} mm", f"{gate_mm:g} mm")
    for axis, value in zip("xyz", result.std_rotation_deg, strict=True):
        table.add_row(f"rotation about {axis}", f"{value:.3f} deg", f"{gate_deg:g} deg")
    console.print(table)
    for note in result.notes:
        console.print(f"[yellow]note:[/] {note}", markup=True)
    if result.weak_direction is not None:
        console.print(f"[yellow]weak:[/] {result.weak_direction}")
    console.print(
        f"wrote {out}; every waypoint passes "
        f"`lasercal trajectory check --file {out} --robot-model {model.name}`. Use it with {job_lines}.",
        markup=False,
    )


trajectory_app.command("list")(list_presets)
trajectory_app.command("show")(show)
trajectory_app.command("check")(check)
trajectory_app.command("design")(design)
