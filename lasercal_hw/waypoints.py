"""The waypoints of a job: from a waypoint file (CSV of UR poses) or a named preset."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from lasercal_hw.config import JobConfig
from lasercal_hw.errors import ConfigError
from lasercal_hw.models import FloatArray

WAYPOINT_COLUMNS = ("x", "y", "z", "rx", "ry", "rz")


def load_waypoints_csv(path: Path) -> FloatArray:
    """Waypoints (N, 6) from a CSV file of UR poses ``x,y,z,rx,ry,rz`` (m, rotation vector).

    A first row of column names is allowed; blank lines and lines starting with ``#`` are
    ignored. Errors name the file and the line.
    """
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"cannot read waypoint file {path}: {exc.strerror or exc}") from None
    poses: list[list[float]] = []
    for line_number, row in enumerate(csv.reader(text.splitlines()), start=1):
        cells = [cell.strip() for cell in row]
        if not cells or not any(cells) or cells[0].startswith("#"):
            continue
        if not poses and tuple(c.lower() for c in cells) == WAYPOINT_COLUMNS:
            continue
        if len(cells) != 6:
            raise ConfigError(f"{path}:{line_number}: expected 6 values x,y,z,rx,ry,rz, got {len(cells)}")
        try:
            pose = [float(cell) for cell in cells]
        except ValueError:
            raise ConfigError(f"{path}:{line_number}: not a number in {','.join(cells)!r}") from None
        if not np.all(np.isfinite(pose)):
            raise ConfigError(f"{path}:{line_number}: values must be finite")
        poses.append(pose)
    if not poses:
        raise ConfigError(f"{path}: no waypoints in the file")
    return np.asarray(poses, dtype=float)


def job_waypoints(job: JobConfig) -> FloatArray:
    """The waypoints the job visits, in order."""
    if job.trajectory.waypoints_file is not None:
        return load_waypoints_csv(job.trajectory.waypoints_file)
    raise ConfigError(
        f"trajectory preset {job.trajectory.preset!r} is not available in this build; "
        "give trajectory.waypoints_file (CSV of x,y,z,rx,ry,rz per line) in the job file"
    )
