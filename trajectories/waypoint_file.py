"""Custom waypoint files: CSV (``index,x,y,z,rx,ry,rz[,label]``) or TOML.

CSV: a header line naming the columns (order free, ``label`` optional), then one
waypoint per row; blank lines and lines starting with ``#`` are ignored. Poses are UR
pose vectors in the robot base frame: metres and a rotation vector in radians.

TOML: an array of tables, each with ``pose = [x, y, z, rx, ry, rz]`` and optionally
``index`` (defaults to the position in the file) and ``label``::

    [[waypoints]]
    index = 0
    pose = [0.45, -0.2, 0.35, 3.1416, 0.0, 0.0]
    label = "first"

Every error names the file, the row (CSV) or entry (TOML) and the field.
"""

from __future__ import annotations

import csv
import io
import math
import tomllib
from collections.abc import Sequence
from pathlib import Path

from lasercal_hw.errors import ConfigError
from trajectories.waypoint import Waypoint

CSV_COLUMNS = ("index", "x", "y", "z", "rx", "ry", "rz")
POSE_FIELDS = CSV_COLUMNS[1:]
_OPTIONAL_COLUMNS = ("label",)
# Positions beyond this are typos (millimetres for metres), not robot poses.
_MAX_POSITION_M = 10.0


def load_waypoints(path: str | Path) -> list[Waypoint]:
    """Read a waypoint file; the format follows the suffix (.csv or .toml)."""
    file = Path(path)
    try:
        text = file.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"waypoint file {file} does not exist") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"waypoint file {file} cannot be read: {exc}") from None
    suffix = file.suffix.lower()
    if suffix == ".csv":
        waypoints = parse_waypoints_csv(text, source=str(file))
    elif suffix == ".toml":
        waypoints = parse_waypoints_toml(text, source=str(file))
    else:
        raise ConfigError(f"waypoint file {file}: unknown format {suffix!r}; use a .csv or .toml file")
    return waypoints


def _number(value: object, where: str, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        raise ConfigError(f"{where}: field {name!r} must be a number, got {value!r}")
    try:
        number = float(value)
    except ValueError:
        raise ConfigError(f"{where}: field {name!r} is not a number: {value!r}") from None
    if not math.isfinite(number):
        raise ConfigError(f"{where}: field {name!r} must be finite, got {value!r}")
    if name in ("x", "y", "z") and abs(number) > _MAX_POSITION_M:
        raise ConfigError(f"{where}: field {name!r} = {number} m is implausibly far; positions are in metres")
    return number


def _index(value: object, where: str) -> int:
    if isinstance(value, bool):
        raise ConfigError(f"{where}: field 'index' must be a whole number, got {value!r}")
    try:
        number = float(value) if isinstance(value, str) else value
    except ValueError:
        raise ConfigError(f"{where}: field 'index' is not a whole number: {value!r}") from None
    if not isinstance(number, int | float) or not float(number).is_integer() or number < 0:
        raise ConfigError(f"{where}: field 'index' must be a whole number >= 0, got {value!r}")
    return int(number)


def _finish(waypoints: list[tuple[str, Waypoint]], source: str) -> list[Waypoint]:
    if not waypoints:
        raise ConfigError(f"{source}: no waypoints found")
    first_at: dict[int, str] = {}
    for where, waypoint in waypoints:
        if waypoint.index in first_at:
            raise ConfigError(
                f"{where}: index {waypoint.index} is already used by {first_at[waypoint.index]}"
            )
        first_at[waypoint.index] = where
    return [w for _, w in waypoints]


def parse_waypoints_csv(text: str, source: str = "waypoints.csv") -> list[Waypoint]:
    """Parse CSV text; ``source`` names the file in error messages."""
    rows = [
        (number, row)
        for number, row in enumerate(csv.reader(io.StringIO(text)), start=1)
        if row and any(cell.strip() for cell in row) and not row[0].lstrip().startswith("#")
    ]
    if not rows:
        raise ConfigError(f"{source}: the file is empty; expected a header {','.join(CSV_COLUMNS)}")
    header_line, header = rows[0]
    columns = [cell.strip().lower() for cell in header]
    missing = [c for c in CSV_COLUMNS if c not in columns]
    unknown = [c for c in columns if c not in CSV_COLUMNS + _OPTIONAL_COLUMNS]
    if missing or unknown or len(set(columns)) != len(columns):
        raise ConfigError(
            f"{source} line {header_line}: header must name the columns {','.join(CSV_COLUMNS)}[,label]"
            + (f"; missing {', '.join(missing)}" if missing else "")
            + (f"; unknown {', '.join(unknown)}" if unknown else "")
            + ("; a column appears twice" if len(set(columns)) != len(columns) else "")
        )
    parsed: list[tuple[str, Waypoint]] = []
    for line, row in rows[1:]:
        where = f"{source} line {line}"
        if len(row) != len(columns):
            raise ConfigError(
                f"{where}: expected {len(columns)} fields ({','.join(columns)}), got {len(row)}"
            )
        cells = {name: cell.strip() for name, cell in zip(columns, row, strict=True)}
        pose = tuple(_number(cells[name], where, name) for name in POSE_FIELDS)
        parsed.append(
            (
                where,
                Waypoint(index=_index(cells["index"], where), tcp_pose=pose, label=cells.get("label", "")),
            )
        )
    return _finish(parsed, source)


def parse_waypoints_toml(text: str, source: str = "waypoints.toml") -> list[Waypoint]:
    """Parse TOML text with a ``[[waypoints]]`` array; ``source`` names the file in errors."""
    try:
        document = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML: {exc}") from None
    unknown_keys = sorted(set(document) - {"waypoints"})
    if unknown_keys:
        raise ConfigError(
            f"{source}: unknown top-level key(s) {', '.join(unknown_keys)}; expected [[waypoints]]"
        )
    entries = document.get("waypoints")
    if not isinstance(entries, list):
        raise ConfigError(
            f"{source}: expected an array of tables [[waypoints]] with pose = [x, y, z, rx, ry, rz]"
        )
    parsed: list[tuple[str, Waypoint]] = []
    for position, entry in enumerate(entries):
        where = f"{source} waypoints[{position}]"
        if not isinstance(entry, dict):
            raise ConfigError(f"{where}: expected a table with a pose, got {entry!r}")
        extra = sorted(set(entry) - {"index", "pose", "label"})
        if extra:
            raise ConfigError(f"{where}: unknown field(s) {', '.join(extra)}; allowed: index, pose, label")
        if "pose" not in entry:
            raise ConfigError(f"{where}: field 'pose' is missing; give pose = [x, y, z, rx, ry, rz]")
        raw_pose = entry["pose"]
        if not isinstance(raw_pose, list) or len(raw_pose) != 6:
            raise ConfigError(f"{where}: field 'pose' must be a list of 6 numbers [x, y, z, rx, ry, rz]")
        pose = tuple(_number(v, where, f"pose.{name}") for v, name in zip(raw_pose, POSE_FIELDS, strict=True))
        label = entry.get("label", "")
        if not isinstance(label, str):
            raise ConfigError(f"{where}: field 'label' must be a string, got {label!r}")
        index = _index(entry.get("index", position), where)
        parsed.append((where, Waypoint(index=index, tcp_pose=pose, label=label)))
    return _finish(parsed, source)


def waypoints_to_csv(waypoints: Sequence[Waypoint]) -> str:
    """CSV text (with header and labels) that :func:`parse_waypoints_csv` reads back exactly."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow((*CSV_COLUMNS, "label"))
    for w in waypoints:
        writer.writerow((w.index, *(repr(float(v)) for v in w.tcp_pose), w.label))
    return buffer.getvalue()
