"""Reading and writing ``observations.csv``, and loading observations from any input file.

Format: a header line, then one row per waypoint with the columns
``index,tcp_x,tcp_y,tcp_z,tcp_rx,tcp_ry,tcp_rz,u,v`` and optionally ``sigma_u,sigma_v``
(metres; TCP pose as a UR pose vector, rotation vector in radians; (u, v) the rod centre
in the scanner plane).  Extra columns are ignored; lines starting with ``#`` are comments.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lasercal_hw.errors import ConfigError
from lasercal_hw.models import Observation

POSE_COLUMNS = ("tcp_x", "tcp_y", "tcp_z", "tcp_rx", "tcp_ry", "tcp_rz")
REQUIRED_COLUMNS = ("index", *POSE_COLUMNS, "u", "v")
SIGMA_COLUMNS = ("sigma_u", "sigma_v")


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
    """Parse ``observations.csv``; errors name the file, line and column."""
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
    rows = list(csv.reader(line for _, line in lines))
    header = [name.strip().lower() for name in rows[0]]
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
    column = {name: header.index(name) for name in header}
    observations: list[Observation] = []
    first_line: dict[int, int] = {}
    for (line_number, _), row in zip(lines[1:], rows[1:], strict=True):
        if len(row) < len(header):
            raise ConfigError(f"{path.name} line {line_number}: {len(row)} values, header has {len(header)}")
        observation = _parse_row(_Row(path.name, line_number, row, column), with_sigma=all(has_sigma))
        if observation.index in first_line:
            raise ConfigError(
                f"{path.name} line {line_number}: index {observation.index} repeats line "
                f"{first_line[observation.index]}"
            )
        first_line[observation.index] = line_number
        observations.append(observation)
    return observations


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


def _parse_row(row: _Row, *, with_sigma: bool) -> Observation:
    index_value = row.number("index")
    if index_value != int(index_value):
        raise ConfigError(
            f"{row.file_name} line {row.line_number}, column index: {index_value!r} is not an integer"
        )
    covariance = None
    if with_sigma:
        sigmas = [row.number(name) for name in SIGMA_COLUMNS]
        if min(sigmas) <= 0:
            raise ConfigError(f"{row.file_name} line {row.line_number}: sigma_u and sigma_v must be positive")
        covariance = np.diag(np.square(sigmas))
    return Observation(
        index=int(index_value),
        tcp_pose=np.array([row.number(name) for name in POSE_COLUMNS]),
        centre_uv_m=np.array([row.number("u"), row.number("v")]),
        covariance_uv_m2=covariance,
    )


def write_observations_csv(path: str | Path, observations: Sequence[Observation]) -> None:
    """Write ``observations.csv``; sigma columns are written when every observation has a
    covariance (its diagonal; a correlation between u and v is not representable)."""
    with_sigma = bool(observations) and all(o.covariance_uv_m2 is not None for o in observations)
    with Path(path).open("w", newline="", encoding="utf-8") as stream:
        writer = csv.writer(stream, lineterminator="\n")
        writer.writerow([*REQUIRED_COLUMNS, *(SIGMA_COLUMNS if with_sigma else ())])
        for o in observations:
            row = [str(o.index), *(repr(float(v)) for v in (*o.tcp_pose, *o.centre_uv_m))]
            if with_sigma:
                row += [repr(float(v)) for v in np.sqrt(np.diag(np.asarray(o.covariance_uv_m2)))]
            writer.writerow(row)


_LOADERS: dict[str, Callable[[Path], list[Observation]]] = {".csv": read_observations_csv}
