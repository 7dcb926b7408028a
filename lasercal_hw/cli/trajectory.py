"""``lasercal trajectory ...``: list presets, show waypoints, check them offline."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import typer
from pydantic import ValidationError
from rich.table import Table

from lasercal_hw.cli.common import console, parse_vector, print_json
from lasercal_hw.config import WorkspaceConfig
from lasercal_hw.errors import ConfigError, ExitCode
from lasercal_hw.models import RodLine
from lasercal_hw.ur5_kinematics import inverse_kinematics_pose
from trajectories.checks import check_waypoints
from trajectories.presets import DEFAULT_PRESET, PRESETS, get_preset, preset_names
from trajectories.waypoint import Waypoint
from trajectories.waypoint_file import load_waypoints

trajectory_app = typer.Typer(
    help="List trajectory presets, show their waypoints, check waypoints offline.", no_args_is_help=True
)

_PRESET_ARG = typer.Argument(DEFAULT_PRESET, help=f"Preset name ({', '.join(preset_names())}).")
_FILE_OPT = typer.Option(None, "--file", "-f", help="A waypoint file (.csv or .toml) instead of a preset.")
_JSON_OPT = typer.Option(False, "--json", help="Print one JSON document instead of a table.")


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
    json_output: bool = _JSON_OPT,
) -> None:
    """Check waypoints offline against a UR5 (CB3) model and the workspace box.

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
    report = check_waypoints(waypoints, inverse_kinematics=inverse_kinematics_pose, workspace=box, rod=rod)
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


trajectory_app.command("list")(list_presets)
trajectory_app.command("show")(show)
trajectory_app.command("check")(check)
