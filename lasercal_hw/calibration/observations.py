"""Reading and writing ``observations.csv``, and loading observations from any input file.

Format: a header line, then one row per waypoint with the columns
``index,tcp_x,tcp_y,tcp_z,tcp_rx,tcp_ry,tcp_rz,u,v`` and optionally ``sigma_u,sigma_v``
and then ``rho_uv`` (metres; TCP pose as a UR pose vector, rotation vector in radians;
(u, v) the rod centre in the scanner plane; ``rho_uv`` the correlation of u and v). Extra
columns are ignored; lines starting with ``#`` are comments.

A run writes one comment line ``# lasercal-solve: {json}`` first: the rod line, the solver
settings and the quality gates of its final solve, so that ``lasercal solve
observations.csv`` solves exactly as the run did (``SolveSettings``).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ValidationError

from lasercal_hw.calibration.solver import SolverOptions
from lasercal_hw.config import QualityConfig
from lasercal_hw.errors import ConfigError
from lasercal_hw.models import FloatArray, Observation, RodLine

POSE_COLUMNS = ("tcp_x", "tcp_y", "tcp_z", "tcp_rx", "tcp_ry", "tcp_rz")
REQUIRED_COLUMNS = ("index", *POSE_COLUMNS, "u", "v")
SIGMA_COLUMNS = ("sigma_u", "sigma_v")
CORRELATION_COLUMN = "rho_uv"
SETTINGS_PREFIX = "# lasercal-solve: "


class _RodDocument(BaseModel):
    origin_m: list[float]
    direction: list[float]
    radius_m: float
    length_m: float


class _SettingsDocument(BaseModel):
    rod: _RodDocument
    solver: SolverOptions
    quality: QualityConfig


@dataclass(frozen=True)
class SolveSettings:
    """What a solve of these observations needs besides them: the rod line in the TCP frame
    (the nominal one when the solve estimates it), the solver's settings and the gates."""

    rod: RodLine
    solver: SolverOptions
    quality: QualityConfig

    def comment_line(self) -> str:
        """The settings as the CSV's ``# lasercal-solve:`` line."""
        rod = _RodDocument(
            origin_m=[float(v) for v in self.rod.origin_m],
            direction=[float(v) for v in self.rod.direction],
            radius_m=self.rod.radius_m,
            length_m=self.rod.length_m,
        )
        document = _SettingsDocument(rod=rod, solver=self.solver, quality=self.quality)
        return SETTINGS_PREFIX + document.model_dump_json()


def read_solve_settings(path: str | Path) -> SolveSettings | None:
    """The ``# lasercal-solve:`` settings of an ``observations.csv``, or None when it has none
    (a file written by hand or by another tool)."""
    with Path(path).open(encoding="utf-8") as stream:
        for number, line in enumerate(stream, start=1):
            if not line.startswith(SETTINGS_PREFIX):
                continue
            try:
                document = _SettingsDocument.model_validate_json(line[len(SETTINGS_PREFIX):])
            except ValidationError as exc:
                problem = exc.errors()[0]
                where = ".".join(str(part) for part in problem["loc"])
                raise ConfigError(
                    f"{Path(path).name} line {number}: the lasercal-solve settings are damaged "
                    f"({where}: {problem['msg']}); delete that line to solve with the defaults"
                ) from None
            rod = RodLine(
                origin_m=np.array(document.rod.origin_m), direction=np.array(document.rod.direction),
                radius_m=document.rod.radius_m, length_m=document.rod.length_m,
            )
            return SolveSettings(rod, document.solver, document.quality)
    return None


def load_observations(path: str | Path) -> list[Observation]:
    """Observations from an input file, chosen by its suffix (``.csv``)."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{str(path)!r} is a directory; pass the observations.csv file inside it")
    loader = _LOADERS.get(path.suffix.lower())
    if loader is None:
        supported = ", ".join(sorted(_LOADERS))
        raise ConfigError(
            f"cannot read {path.name!r}: unsupported file type {path.suffix!r} (supported: {supported})"
        )
    return loader(path)


def read_observations_csv(path: str | Path) -> list[Observation]:
    """Parse ``observations.csv``; errors name the file, line and column.

    A well-formed file is read by ``np.loadtxt`` and checked as a whole, as fast as numpy reads
    it; a file that fails that is read again row by row, which names the first problem's line
    and column (or accepts what only Python's ``float`` parses, like quoted cells).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError as exc:
        raise ConfigError(f"observations file {str(path)!r} does not exist; check the path") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(
            f"cannot read observations file {str(path)!r}: {exc}; pass a UTF-8 CSV file"
        ) from exc
    lines = [(number, line) for number, line in enumerate(text.splitlines(), start=1)
             if line.strip() and not line.lstrip().startswith("#")]
    if not lines:
        raise ConfigError(f"{path.name}: empty file, expected a header line {','.join(REQUIRED_COLUMNS)}")
    header = [name.strip().lower() for name in next(csv.reader([lines[0][1]]))]
    missing = [name for name in REQUIRED_COLUMNS if name not in header]
    if missing:
        raise ConfigError(
            f"{path.name}: missing column(s) {', '.join(missing)} (header line {lines[0][0]}); "
            f"expected {','.join(REQUIRED_COLUMNS)}[,{','.join(SIGMA_COLUMNS)}]"
        )
    has_sigma = [name in header for name in SIGMA_COLUMNS]
    if any(has_sigma) and not all(has_sigma):
        absent = SIGMA_COLUMNS[has_sigma.index(False)]
        raise ConfigError(
            f"{path.name}: column {absent} is missing (give both sigma_u and sigma_v or neither)"
        )
    if CORRELATION_COLUMN in header and not all(has_sigma):
        raise ConfigError(f"{path.name}: column {CORRELATION_COLUMN} needs sigma_u and sigma_v")
    names = [*REQUIRED_COLUMNS, *(SIGMA_COLUMNS if all(has_sigma) else ())]
    if CORRELATION_COLUMN in header:
        names.append(CORRELATION_COLUMN)
    columns = [header.index(name) for name in names]
    table = None if '"' in text else _plain_table([line for _, line in lines[1:]], columns, len(header))
    if table is None:
        table = _table_row_by_row(path.name, header, lines[1:], names)
    return _observations(table)


def _plain_table(lines: list[str], columns: list[int], width: int) -> FloatArray | None:
    """The ``columns`` of every line (none quoted) as one array when all lines are plainly valid
    (at least ``width`` cells, finite numbers, integer and unique indices, positive sigmas),
    else None."""
    if not lines:
        return np.empty((0, len(columns)))
    if any(line.count(",") < width - 1 for line in lines):
        return None
    try:
        table = np.loadtxt(lines, delimiter=",", usecols=columns, comments=None, ndmin=2)
    except ValueError:
        return None
    index = table[:, 0]
    sigmas = table[:, len(REQUIRED_COLUMNS):len(REQUIRED_COLUMNS) + len(SIGMA_COLUMNS)]
    correlation = table[:, len(REQUIRED_COLUMNS) + len(SIGMA_COLUMNS):]
    valid = (
        np.isfinite(table).all()
        and (index == np.trunc(index)).all()
        and np.unique(index).size == index.size
        and (sigmas > 0).all()
        and (np.abs(correlation) < 1).all()
    )
    return table if valid else None


def _table_row_by_row(file_name: str, header: list[str], lines: list[tuple[int, str]],
                      names: list[str]) -> FloatArray:
    """The ``names`` columns of every line (``(line number, text)``), parsed one row at a time:
    the first bad value raises a ConfigError naming its line and column."""
    column = {name: header.index(name) for name in header}
    table: list[list[float]] = []
    first_line: dict[float, int] = {}
    for (line_number, _), cells in zip(lines, csv.reader(line for _, line in lines), strict=True):
        if len(cells) < len(header):
            raise ConfigError(
                f"{file_name} line {line_number}: {len(cells)} values, header has {len(header)}"
            )
        values = _parse_row(_Row(file_name, line_number, cells, column), names)
        if values[0] in first_line:
            raise ConfigError(
                f"{file_name} line {line_number}: index {int(values[0])} repeats line {first_line[values[0]]}"
            )
        first_line[values[0]] = line_number
        table.append(values)
    return np.array(table, dtype=float).reshape(len(table), len(names))


@dataclass(frozen=True)
class _Row:
    """One data line of the CSV, with what an error message needs to point at it."""

    file_name: str
    line_number: int
    cells: list[str]
    column: dict[str, int]

    def number(self, name: str) -> float:
        """The finite number in column ``name``."""
        text = self.cells[self.column[name]].strip()
        try:
            value = float(text)
        except ValueError:
            raise ConfigError(
                f"{self.file_name} line {self.line_number}, column {name}: {text!r} is not a number"
            ) from None
        if not math.isfinite(value):
            raise ConfigError(
                f"{self.file_name} line {self.line_number}, column {name}: {text!r} is not finite"
            )
        return value


def _parse_row(row: _Row, names: list[str]) -> list[float]:
    """The values of ``names`` in one row, checked: integer index, positive sigmas."""
    index_value = row.number("index")
    if index_value != int(index_value):
        raise ConfigError(
            f"{row.file_name} line {row.line_number}, column index: {index_value!r} is not an integer"
        )
    sigmas = [row.number(name) for name in names[len(REQUIRED_COLUMNS):] if name in SIGMA_COLUMNS]
    if sigmas and min(sigmas) <= 0:
        raise ConfigError(f"{row.file_name} line {row.line_number}: sigma_u and sigma_v must be positive")
    correlation = [row.number(CORRELATION_COLUMN)] if CORRELATION_COLUMN in names else []
    if correlation and abs(correlation[0]) >= 1:
        raise ConfigError(
            f"{row.file_name} line {row.line_number}, column {CORRELATION_COLUMN}: a correlation lies "
            "strictly between -1 and 1"
        )
    values = [row.number(name) for name in names[1:len(REQUIRED_COLUMNS)]]
    return [index_value, *values, *sigmas, *correlation]


def _observations(table: FloatArray) -> list[Observation]:
    """One observation per row of ``index, tcp pose (6), u, v[, sigma_u, sigma_v[, rho_uv]]``."""
    count = len(table)
    poses = table[:, 1:7].copy()
    centres = table[:, 7:9].copy()
    covariances: list[FloatArray | None] | FloatArray = [None] * count
    if table.shape[1] > len(REQUIRED_COLUMNS):
        covariances = np.zeros((count, 2, 2))
        covariances[:, [0, 1], [0, 1]] = np.square(table[:, 9:11])
        if table.shape[1] > 11:
            covariances[:, 0, 1] = covariances[:, 1, 0] = table[:, 11] * table[:, 9] * table[:, 10]
    rows = zip(table[:, 0].tolist(), poses, centres, covariances, strict=True)
    return [Observation(int(index), pose, centre, covariance) for index, pose, centre, covariance in rows]


def write_observations_csv(
    path: str | Path, observations: Sequence[Observation], settings: SolveSettings | None = None
) -> None:
    """Write ``observations.csv``: the ``settings`` line when given, and the sigma and
    correlation columns when every observation has a covariance."""
    with_sigma = bool(observations) and all(o.covariance_uv_m2 is not None for o in observations)
    with Path(path).open("w", newline="", encoding="utf-8") as stream:
        if settings is not None:
            stream.write(settings.comment_line() + "\n")
        writer = csv.writer(stream, lineterminator="\n")
        writer.writerow([*REQUIRED_COLUMNS, *((*SIGMA_COLUMNS, CORRELATION_COLUMN) if with_sigma else ())])
        for o in observations:
            row = [str(o.index), *(repr(float(v)) for v in (*o.tcp_pose, *o.centre_uv_m))]
            if with_sigma:
                covariance = np.asarray(o.covariance_uv_m2, dtype=float)
                sigma_u, sigma_v = np.sqrt(np.diag(covariance))
                rho_uv = covariance[0, 1] / (sigma_u * sigma_v)
                row += [repr(float(sigma_u)), repr(float(sigma_v)), repr(float(rho_uv))]
            writer.writerow(row)


_LOADERS: dict[str, Callable[[Path], list[Observation]]] = {".csv": read_observations_csv}
