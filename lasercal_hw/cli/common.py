"""Helpers shared by the CLI commands: one console, JSON output, option parsing."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console

from lasercal_hw.errors import ConfigError

# soft_wrap: a message is never broken at the console's width (80 columns when the output is a
# file or a pipe), so a path or a URL stays whole and can be pasted.
console = Console(stderr=False, highlight=False, soft_wrap=True)
err_console = Console(stderr=True, highlight=False, soft_wrap=True)

# Options that mean the same in every command that takes them (each command's own live there).
RobotOption = Annotated[str | None, typer.Option("--robot", help="Robot controller host, e.g. 192.168.1.10.")]
ScannerOption = Annotated[
    str | None, typer.Option("--scanner", help="Scanner URL (default: the job's scanner.url).")
]
YesOption = Annotated[bool, typer.Option("--yes", "-y", help="Do not ask before moving the robot.")]
JsonOption = Annotated[bool, typer.Option("--json", help="Print one JSON document (progress on stderr).")]
DryRunOption = Annotated[
    bool, typer.Option("--dry-run", help="Use a fake cell started on a free loopback address, not hardware.")
]
SceneOption = Annotated[
    Path | None,
    typer.Option("--scene", help="Scene file for the --dry-run fake cell (e.g. a moved scanner)."),
]
FoxgloveOption = Annotated[bool, typer.Option(
    "--foxglove", help="Serve runs live to the Foxglove app on 127.0.0.1 (needs the foxglove extra).")]
FoxglovePortOption = Annotated[int, typer.Option("--foxglove-port", help="Port of the --foxglove server.")]


def foxglove_line(url: str) -> str:
    """The one line saying where the ``--foxglove`` view is served, to paste into the app."""
    return f"Foxglove live view on {url} (in the Foxglove app: Open connection, Foxglove WebSocket)"


def print_json(document: Any) -> None:
    """Write one JSON document to standard output (nothing else goes there with --json)."""
    sys.stdout.write(json.dumps(document, indent=2, sort_keys=False, allow_nan=False) + "\n")
    sys.stdout.flush()


def parse_vector(text: str, length: int, option: str) -> list[float]:
    """Parse ``"x,y,z"`` into floats, with an error naming the option on failure."""
    parts = [p for p in text.replace(" ", "").split(",") if p]
    try:
        values = [float(p) for p in parts]
    except ValueError as exc:
        raise ConfigError(f"{option} must be {length} comma-separated numbers, got {text!r}") from exc
    if len(values) != length:
        raise ConfigError(f"{option} must have {length} numbers, got {len(values)} in {text!r}")
    return values


def check_scene(scene: Path | None, dry_run: bool) -> None:
    """``--scene`` only with ``--dry-run``, naming a scene file that exists and is valid: a bad
    one is exit 2 naming it, before any fake cell starts."""
    if scene is None:
        return
    if not dry_run:
        raise ConfigError("--scene only applies to --dry-run")
    if not scene.is_file():
        raise ConfigError(f"--scene {scene} does not exist; give a scene file (docs/extraction.md)")
    from fakes.scene import load_scene

    try:
        load_scene(scene)
    except ConfigError as exc:
        raise ConfigError(f"--scene: {exc}") from None
